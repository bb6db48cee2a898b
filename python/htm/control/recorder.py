"""Recording a live test from the device loop into the test store (`htm.record.TestWriter`).

One recorder per test: a thread beside the loop (never in it) drains what the loop publishes for
that test — its per-cycle rows (tagged with the test's number), the decimated signal feed, the
event log — every `PERIOD_S` and hands it to the writer, which journals it first. When the test
ends (the controller stops, a trip powers off, another test starts, the session closes) the writer
is closed with the matching status and end reason and the test's report is written beside it, so
the Results screen and `htm db` see it.
"""
from __future__ import annotations

import math
import threading
from typing import Any

import numpy as np

from htm.errors import HtmError

PERIOD_S = 0.25
# loop feed keys → the signal names of the store's raw table and of the recording, as the engine's
# raw capture names them (`htm._core.RAW_COLUMNS`), so a live test and `htm run` read back alike;
# the velocity and the supply pressure are a rig's own (htm.record.streams)
SIGNALS = {"t_s": "t_s", "cycle": "cycle", "y": "y_m", "f": "f_n", "f_ref": "f_ref_n", "p_a": "p_a_pa", "p_b": "p_b_pa",
           "u": "u_v", "v": "v_m_s", "p_s": "p_s_pa"}


def _columns(rows: list[dict[str, Any]], keys: dict[str, str] | None = None) -> dict[str, np.ndarray]:
    """Rows of numbers → columns (bools and numbers only; other values are left out)."""
    if not rows:
        return {}
    if keys is not None:
        return {out: np.array([float(r.get(k, math.nan)) for r in rows]) for k, out in keys.items()}
    names = [k for k, v in rows[0].items() if isinstance(v, (int, float, bool)) and k not in ("period", "test")]
    cols = {k: np.asarray([r[k] for r in rows]) for k in names}
    cols.setdefault("events", np.zeros(len(rows), np.uint32))  # the engine table's event bits (none here)
    return cols



def cfg_for_store(spec) -> dict[str, Any]:
    """The spec as plain data for the store's catalogue (its fields as the spec names them, the
    rig parameters by name)."""
    import dataclasses

    d = {f.name: getattr(spec, f.name) for f in dataclasses.fields(spec) if f.name not in ("config", "_feasibility")}
    return {**d, "phases": [dataclasses.asdict(p) for p in spec.phases], "params": spec.params().to_dict()}


def stop_reason(lp: Any) -> str:
    """Why a test ended that its controller did not end: the e-stop, a stop or power-off
    interlock (by detector), else the operator (an indicate-only trip stops nothing)."""
    if lp.safety.estop:
        return "estop"
    if lp.safety.interlocked():
        names = [d["name"] for d in lp.safety.describe() if d["latched"] and d["action"] != "indicate"]
        return f"interlock {lp.safety.latched()} ({', '.join(names)})"
    return "operator stop"


class Follower:
    """A recorder's thread loop, one copy for every kind of test: drain what the loop published
    every `period_s` until the test ends — its controller stopped (finished with its end reason,
    else stopped with `stop_reason`), a trip powered off, another test replaced it, the session
    closed — then close the test with the matching status. Subclasses give `s` (the session),
    `test_no`, `_stop` (an Event), `_drain()` and `_close(status, reason)`."""

    s: Any
    test_no: int
    _stop: threading.Event

    def _drain(self) -> None:
        raise NotImplementedError

    def _close(self, status: str, reason: str | None) -> None:
        raise NotImplementedError

    def _follow(self, period_s: float) -> None:
        while True:
            stopping = self._stop.wait(period_s)
            self._drain()
            lp = self.s.loop
            if lp is None or lp.test_no != self.test_no:  # the session closed or another test replaced this one
                self._close("stopped", "replaced by a new test" if lp is not None else "session closed")
                return
            c = lp.ctrl
            ended = c.state in ("stopped", "idle") and not lp.powered
            tripped = not lp.powered and lp.safety.latched() == "power_off"
            if ended or tripped:  # checked first: a session closed right after an e-stop keeps its reason
                self._drain()
                end = c.end_reason
                self._close("finished" if end else "stopped", end or stop_reason(lp))
                return
            if stopping:
                self._close("stopped", "session closed")
                return


class LiveRecorder(Follower):
    """Drains a `Session`'s loop into a new test of the store at `store_root` until the test ends
    or `stop()`. The store and its writer live on the recorder's own thread (SQLite connections
    stay with the thread that made them)."""

    def __init__(self, session: Any, store_root: Any, spec: Any, test_no: int, first_event: int, *,
                 recording: bool = True) -> None:
        from htm.record import Store, TestWriter
        from htm.record.writer import spec_json

        self.s = session
        self.spec = spec
        self.test_no = test_no
        self.w: Any = None
        self.ready = threading.Event()
        body = spec_json(cfg_for_store(spec))
        self._open = lambda: TestWriter.create(Store(store_root), spec.name, "device", session.cfg.loop.mode, "json",
                                               body, spec.frequency_hz, recording=recording)
        self.period = session.loop.k
        self.t0_s = self.period * session.loop.dt  # test time [s] starts at the start command
        self.cycle = 0
        self.event = first_event
        self.status: str | None = None
        self._last_a = spec.a0_m
        self.error: str | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="htm-recorder", daemon=True)
        self._thread.start()

    @property
    def test_id(self) -> str | None:
        self.ready.wait(5.0)
        return None if self.w is None else self.w.id

    def _drain(self) -> None:
        lp = self.s.loop
        if lp is None:
            return
        feed = [x for x in list(lp.feed) if x["period"] > self.period]
        rows = [r for r in list(lp.cycles) if r["test"] == self.test_no and r["cycle"] > self.cycle]
        events = self.s.log.since(self.event)
        if feed:
            self.period = feed[-1]["period"]
            cols = _columns(feed, SIGNALS)
            cols["t_s"] = cols["t_s"] - self.t0_s
            self.w.signals(cols)
        prev = self.cycle
        if rows:
            self.cycle = rows[-1]["cycle"]
            self._last_a = rows[-1]["a_m"]
            self.w.cycles(_columns(rows))
        for e in events:  # dated by the last cycle of this test that closed before it
            c = max((r["cycle"] for r in rows if r["period"] <= e["period"]), default=prev)
            self.w.event(e["kind"], e["message"], cycle=c, time_s=max(e["period"] * lp.dt - self.t0_s, 0.0),
                         level="WARN" if e["kind"] in ("trip", "estop", "error") else "INFO")
        self.event += len(events)

    def _run(self) -> None:
        try:
            self.w = self._open()
        except (HtmError, OSError) as e:
            self.error = str(e)
            self.s.log.add(self.period, "error", f"test not recorded: {e}")
            return
        finally:
            self.ready.set()
        try:
            self._follow(PERIOD_S)
        except (HtmError, OSError) as e:  # the store failed: say so; the loop runs on safely
            self.error = str(e)
            self.s.log.add(self.period, "error", f"recording stopped: {e}")
            try:
                self.w.interrupt("error", str(e))
            except (HtmError, OSError):
                pass

    def _close(self, status: str, reason: str | None) -> None:
        if self.status is not None:
            return
        self.status = status
        results: dict[str, Any] = {"cycles": self.cycle}
        if self.cycle:
            results["final_a_m"] = float(self._last_a)
        lp = self.s.loop
        if lp is not None and lp.test_no == self.test_no:  # this test's controller: its convergence
            from htm.record import convergence

            episodes = lp.ctrl.convergence()
            convergence.log(self.w, episodes, self.spec.frequency_hz)
            results.update(convergence.results(episodes))
        self.w.close(status, reason, results)
        self._report(reason)

    def _report(self, reason: str | None) -> None:
        """The test's report beside its tables (the E647 one when the crack grew enough, else a
        summary that says why not); a report that cannot be written is an event, not a failure."""
        from htm.fatigue.report import spec_test_report

        st, d = self.w.store, self.w.dir
        try:
            table = st.cycles(self.w.id)
            e647 = spec_test_report(d, self.spec, table, f"Test {self.spec.name} on the rig ({self.w.id})")
            if e647 is None or e647.startswith("not written"):
                (d / "report.md").write_text(summary_markdown(self.spec, st.get(self.w.id), table, e647))
            st.add_file(self.w.id, "report", d / "report.md")
        except (HtmError, OSError, KeyError, ValueError) as e:
            self.s.log.add(self.period, "error", f"test {self.w.id}: report not written: {e}")

    def stop(self) -> None:
        """Flush what is left and close the test as stopped (the session is closing)."""
        self._stop.set()
        self._thread.join(10.0)


def summary_markdown(spec: Any, row: dict[str, Any], table: dict[str, np.ndarray], why: str | None) -> str:
    """A live test's short report: what ran, how it ended, the force errors and the events."""
    n = len(table.get("cycle", []))
    lines = [f"# Test {spec.name} on the rig ({row['id']})", "",
             f"- status: **{row['status']}**, end reason: {row['end_reason'] or '-'}",
             f"- {spec.geometry.upper()} W = {spec.width_m * 1e3:.1f} mm, B = {spec.thickness_m * 1e3:.2f} mm, "
             f"{spec.waveform} {spec.frequency_hz:g} Hz",
             f"- cycles recorded: {n:,}"]
    if n:
        # judged cycles: not the ramp-in, nor the ramp back in after a hold
        test = np.asarray(table["judged"], dtype=bool) if "judged" in table else ~np.asarray(table.get("starting", np.zeros(n, bool)), dtype=bool)
        a = table["a_m"]
        lines.append(f"- crack: a = {spec.a0_m * 1e3:.3f} → {float(a[-1]) * 1e3:.3f} mm")
        if test.any():
            df, pk = np.nanmax(np.abs(table["df_err_pct"][test])), np.nanmax(np.abs(table["peak_err_pct"][test]))
            tol = 100 * spec.phases[-1].tolerance
            lines.append(f"- force error after the ramp-in: max |ΔF| {df:.3f} %, max |peak| {pk:.3f} %: "
                         f"{'inside' if max(df, pk) <= tol else 'OUTSIDE'} the ISO 12108 band ±{tol:g} %")
    lines.append(f"- E647 reduction: {why or 'not applicable to this test'}")
    lines += ["", "## Events", ""]
    for e in row["events"]:
        at = "" if e["cycle"] is None else f"cycle {e['cycle']:,}: "
        lines.append(f"- {at}{e['kind']} {e['detail'] or ''}")
    return "\n".join(lines) + "\n"
