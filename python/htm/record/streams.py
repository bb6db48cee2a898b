"""rerun streams of a test (rerun-sdk 0.41): entity layout, timelines and the blueprint saved with it.

Timelines: `time` (duration, test time [s]; a per-cycle row sits at cycle/f, the end of its cycle)
and `cycle` (sequence, the per-cycle table's cycle number). Entities, all SI:

| entity | series |
|---|---|
| `signals/position_m` | piston position y |
| `signals/force_n` | load-cell force, force setpoint |
| `signals/pressure_pa` | chamber pressures A, B |
| `signals/valve_v` | valve command |
| `signals/velocity_m_s` | piston velocity (a rig's transducer; the simulator records none) |
| `signals/supply_pressure_pa` | supply pressure (a rig's sensor; the simulator records none) |
| `cycle/force_n` | measured peak, valley; target peak, valley |
| `cycle/force_error_pct` | peak error, ΔF error of the judged cycles |
| `cycle/ramp_force_error_pct` | the same of the ramp cycles (in at the start and after a hold, out at the stop) |
| `cycle/crack_length_m` | a |
| `cycle/stress_intensity_pa_sqrt_m` | ΔK, ΔK target, Kmax |
| `cycle/dadn_m_per_cycle` | da/dN |
| `cycle/specimen_stiffness_n_m` | K_sp |
| `cycle/controller_v` | amplitude-loop u1, mean-loop u2 |
| `cycle/crack_vs_law_m` | a (the crack the test runs on: measured with a `[measurement]`), the growth law's a |
| `cycle/opening_force_n` | opening force (2 % compliance offset; NaN without a compliance reading) |
| `cycle/delta_k_eff_pa_sqrt_m` | ΔK_eff |
| `crack/dadn_vs_delta_k` | points (log10 ΔK [MPa·√m], log10 da/dN [m/cycle]) |
| `events` | text log: limit trips, mode changes, operator actions, where each ramp-in ends |

The ramps' errors (−100 % at cycle 1, the amplitude still rising; the same at the stop) would swamp
the error plot's scale: they go to an entity of their own, out of the default view, and the event
log marks where each ramp-in ends.

`htm run` and a test run from the console (`htm.control.recorder`) write through this one
layout: their columns are named as the engine's per-cycle table and raw capture name them
(`htm._core.RAW_COLUMNS`), and an entity is written when all its columns are there.

The recording is for visual review: it holds every cycle of the first `full_cycles` and then one
in `stride` plus every cycle that carries an event (the store's Parquet table holds every cycle).
"""
from __future__ import annotations

import os
import select
import threading
from pathlib import Path
from typing import Any

import numpy as np

from htm import core

APP_ID = "htm"
START_BIT = core.EVENTS["start"]
# the cycles whose force error is not judged: the start's ramp-in, the ramp back in after a hold,
# the ramp out at the stop
UNJUDGED_BITS = core.EVENTS["start"] | core.EVENTS["ramp"] | core.EVENTS["stop"]

SIGNAL_GROUPS = {  # entity -> (series names, signal column names)
    "signals/position_m": (["y"], ["y_m"]),
    "signals/force_n": (["force", "setpoint"], ["f_n", "f_ref_n"]),
    "signals/pressure_pa": (["p_A", "p_B"], ["p_a_pa", "p_b_pa"]),
    "signals/valve_v": (["u"], ["u_v"]),
    "signals/velocity_m_s": (["v"], ["v_m_s"]),
    "signals/supply_pressure_pa": (["p_S"], ["p_s_pa"]),
}
ERROR_GROUP = "cycle/force_error_pct"
RAMP_ERRORS = "cycle/ramp_force_error_pct"
CYCLE_GROUPS = {
    "cycle/force_n": (["peak", "valley", "target peak", "target valley"], ["fmax_n", "fmin_n", "fmax_target_n", "fmin_target_n"]),
    "cycle/force_error_pct": (["peak", "ΔF"], ["peak_err_pct", "df_err_pct"]),
    "cycle/crack_length_m": (["a"], ["a_m"]),
    "cycle/stress_intensity_pa_sqrt_m": (["ΔK", "ΔK target", "Kmax"], ["delta_k_pa_sqrt_m", "delta_k_target_pa_sqrt_m", "kmax_pa_sqrt_m"]),
    "cycle/dadn_m_per_cycle": (["da/dN"], ["dadn_m_per_cycle"]),
    "cycle/specimen_stiffness_n_m": (["K_sp"], ["k_sp_n_m"]),
    "cycle/controller_v": (["u1 amplitude", "u2 mean"], ["ctrl_u1_v", "ctrl_u2_v"]),
    # the crack the test runs on beside the growth law's, and closure (a `[measurement]`)
    "cycle/crack_vs_law_m": (["a", "a law"], ["a_m", "a_law_m"]),
    "cycle/opening_force_n": (["F_op"], ["opening_force_n"]),
    "cycle/delta_k_eff_pa_sqrt_m": (["ΔK_eff"], ["delta_k_eff_pa_sqrt_m"]),
}


def blueprint() -> Any:
    """The layout a recording opens with: per-cycle plots, signals, da/dN–ΔK, events."""
    import rerun as rr
    import rerun.blueprint as rrb

    everything = rr.VisibleTimeRange("cycle", start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.infinite())
    per_cycle = [rrb.TimeSeriesView(origin=e, name=e.split("/", 1)[1]) for e in CYCLE_GROUPS]
    signals = [rrb.TimeSeriesView(origin=e, name=e.split("/", 1)[1]) for e in SIGNAL_GROUPS]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Tabs(rrb.Grid(*per_cycle, name="per cycle"), rrb.Grid(*signals, name="signals")),
            rrb.Vertical(
                rrb.Spatial2DView(origin="crack/dadn_vs_delta_k", name="log da/dN vs log ΔK", time_ranges=everything),
                rrb.TextLogView(origin="events", name="events"),
            ),
            column_shares=[3, 1],
        ),
        collapse_panels=True,
    )


class _Spool:
    """The recording file, written by this process rather than by rerun: rerun's `FileSink` writes
    into a pipe (`/dev/fd/N`) and a thread copies the bytes to `path`.

    rerun-sdk 0.41's file writer thread ends at its first failed write (a full disk: ENOSPC,
    EFBIG), and a flush queued behind that write is never answered: the recording stream's own
    thread then waits forever, and with it every later flush, `disconnect` and the SDK's atexit
    shutdown (the process would never exit). A pipe does not fail, so rerun's writer never meets the
    disk; the error is this thread's, reported by `sync`, and past it the pipe is still drained
    (the bytes discarded) so rerun never blocks."""

    def __init__(self, path: Path):
        self.path = path
        self.file = open(path, "wb", buffering=0)
        self.r, self.w = os.pipe()
        self.error: OSError | None = None
        self.eof = False
        self.cond = threading.Condition()
        self.readable, self.pending = select.poll(), select.poll()  # one per thread (a poll object is not shared)
        for q in (self.readable, self.pending):
            q.register(self.r, select.POLLIN)
        self.thread = threading.Thread(target=self._copy, name="htm-rrd-spool", daemon=True)
        self.thread.start()

    @property
    def sink_path(self) -> str:
        return f"/dev/fd/{self.w}"

    def sink_opened(self) -> None:
        """rerun holds its own descriptor of the pipe: drop ours, so its close is our end of file."""
        os.close(self.w)

    def _copy(self) -> None:
        while True:
            self.readable.poll()
            with self.cond:
                data = os.read(self.r, 1 << 16)
                if not data:
                    self.eof = True
                    self.cond.notify_all()
                    return
                view = memoryview(data)
                while view and self.error is None:
                    try:
                        view = view[self.file.write(view):]
                    except OSError as e:  # full disk: keep what landed, drain the rest
                        self.error = e
                self.cond.notify_all()

    def _pending(self) -> bool:
        return not self.eof and bool(self.pending.poll(0))

    def sync(self, timeout_s: float = 30.0) -> None:
        """Wait until every byte rerun has put in the pipe is written (or dropped after an error);
        raise `OSError` if the file could not be written."""
        with self.cond:
            if not self.cond.wait_for(lambda: not self._pending(), timeout_s):
                raise TimeoutError(f"the recording file took over {timeout_s:g} s to write")
            if self.error is not None:
                raise self.error

    def close(self, timeout_s: float = 30.0) -> None:
        """After rerun closed its end (the footer written): copy to the end, fsync, close."""
        try:
            with self.cond:
                if not self.cond.wait_for(lambda: self.eof, timeout_s):
                    raise TimeoutError(f"the recording file took over {timeout_s:g} s to finish")
                if self.error is not None:
                    raise self.error
                os.fsync(self.file.fileno())
        finally:
            if self.eof:
                os.close(self.r)
                self.file.close()


class Recording:
    """A rerun recording of one test, saved to `path`; `spawn` starts a viewer, `connect` (a
    rerun+http URL) streams to a running one. `recording_id` is the test's, so the segments of
    a resumed test are one recording."""

    def __init__(self, path: Path, recording_id: str, name: str, frequency_hz: float, *, spawn: bool = False,
                 connect: str | None = None, full_cycles: int = 10_000, stride: int = 10):
        import rerun as rr

        self.rr = rr
        self.f = float(frequency_hz)
        self.full_cycles, self.stride = full_cycles, stride
        self.rec = rr.RecordingStream(APP_ID, recording_id=recording_id)
        self.spool = _Spool(path)
        sinks: list[Any] = [rr.FileSink(self.spool.sink_path)]
        if not (spawn or connect):
            from htm.record.web import live_url

            connect = live_url()  # a live web viewer of this process (`htm.record.web.serve_live`)
        if spawn:
            self.rec.spawn(connect=False)
            sinks.append(rr.GrpcSink())
        elif connect:
            sinks.append(rr.GrpcSink(connect))
        try:
            self.rec.set_sinks(*sinks, default_blueprint=blueprint())
        finally:
            self.spool.sink_opened()
        self.rec.send_recording_name(name)
        for e, (names, _) in {**CYCLE_GROUPS, RAMP_ERRORS: CYCLE_GROUPS[ERROR_GROUP], **SIGNAL_GROUPS}.items():
            self.rec.log(e, rr.SeriesLines(names=names), static=True)
        self._ramp_from: int | None = None  # first cycle of the ramp-in under way, if any
        self._last_cycle = 0
        self.rec.log("crack/dadn_vs_delta_k", rr.Points2D([[0.0, 0.0]], radii=[0.0]), static=True)

    def _index(self, cycle: np.ndarray, t_s: np.ndarray) -> list[Any]:
        rr = self.rr
        return [rr.TimeColumn("cycle", sequence=cycle.astype(np.int64)), rr.TimeColumn("time", duration=t_s)]

    def cycles(self, table: dict[str, np.ndarray]) -> None:
        """Per-cycle rows (the engine's table columns) in bulk, decimated as the module says."""
        rr = self.rr
        c = np.asarray(table["cycle"])
        if len(c) == 0:
            return
        ev = np.asarray(table.get("events", np.zeros(len(c), np.uint32))).astype(np.uint32)
        ramp = (ev & np.uint32(UNJUDGED_BITS)) != 0
        self._mark_ramps(c, ramp)
        keep = (c <= self.full_cycles) | (c % self.stride == 0) | ((ev & ~np.uint32(START_BIT)) != 0)
        c, ramp = c[keep], ramp[keep]
        idx = self._index(c, c / self.f)
        for e, (_, cols) in CYCLE_GROUPS.items():
            if all(k in table for k in cols):
                v = np.column_stack([np.asarray(table[k], dtype=np.float64)[keep] for k in cols])
                if e == ERROR_GROUP:  # the ramp-in's errors to an entity of their own (see the module)
                    for ent, rows in ((ERROR_GROUP, ~ramp), (RAMP_ERRORS, ramp)):
                        if rows.any():
                            self.rec.send_columns(ent, indexes=self._index(c[rows], c[rows] / self.f),
                                                  columns=rr.Scalars.columns(scalars=v[rows]))
                    continue
                self.rec.send_columns(e, indexes=idx, columns=rr.Scalars.columns(scalars=v))
        dk, dadn = (np.asarray(table.get(k, []), dtype=np.float64)[keep] for k in ("delta_k_pa_sqrt_m", "dadn_m_per_cycle"))
        ok = np.flatnonzero((dk > 0) & (dadn > 0))
        if len(ok):
            ok = ok[:: max(1, len(ok) // 20)]  # ≤ ~20 points per block keep the scatter light
            pts = np.column_stack([np.log10(dk[ok] / 1e6), np.log10(dadn[ok])])
            self.rec.send_columns("crack/dadn_vs_delta_k", indexes=self._index(c[ok], c[ok] / self.f),
                                  columns=rr.Points2D.columns(positions=pts).partition(np.ones(len(ok), dtype=np.int64)))

    def _mark_ramps(self, c: np.ndarray, ramp: np.ndarray) -> None:
        """An event where each ramp-in ends (it may span blocks): its cycles, not judged."""
        was = np.concatenate([[self._ramp_from is not None], ramp[:-1]])
        for i in np.flatnonzero(ramp != was):  # the few rows where a ramp begins or ends
            if ramp[i]:
                self._ramp_from = int(c[i])
            else:
                last = self._last_cycle if i == 0 else int(c[i - 1])
                self.event("ramp-in", f"cycles {self._ramp_from:,}–{last:,}: amplitude ramping in, force error not judged "
                           f"(in {RAMP_ERRORS})", last, last / self.f)
                self._ramp_from = None
        self._last_cycle = int(c[-1])

    def signals(self, cols: dict[str, np.ndarray]) -> None:
        """Samples with `t_s` [s] (and `cycle` when known) and the layout's signal columns; an
        entity is written when all its columns are there, other columns stay in the store's
        raw table only."""
        rr = self.rr
        t = np.asarray(cols["t_s"], dtype=np.float64)
        if len(t) == 0:
            return
        idx = [rr.TimeColumn("time", duration=t)]
        if "cycle" in cols:
            idx.append(rr.TimeColumn("cycle", sequence=np.asarray(cols["cycle"]).astype(np.int64)))
        for e, (_, names) in SIGNAL_GROUPS.items():
            if all(k in cols for k in names):
                v = np.column_stack([np.asarray(cols[k], dtype=np.float64) for k in names])
                self.rec.send_columns(e, indexes=idx, columns=rr.Scalars.columns(scalars=v))

    def event(self, kind: str, detail: str, cycle: int | None, time_s: float | None, level: str = "INFO") -> None:
        if cycle is not None:
            self.rec.set_time("cycle", sequence=int(cycle))
        if time_s is not None:
            self.rec.set_time("time", duration=float(time_s))
        self.rec.log("events", self.rr.TextLog(f"{kind}: {detail}" if detail else kind, level=level))

    def flush(self) -> None:
        """Push what was logged to the sinks and into the file; a file that cannot be written
        (full disk) raises `RecordError`."""
        from htm.errors import RecordError

        try:
            self.rec.flush(timeout_sec=30.0)
            self.spool.sync()
        except (RuntimeError, OSError) as e:
            raise RecordError(f"cannot write the recording: {e}") from None

    def close(self) -> None:
        """Flush everything and write the file's footer; the sinks are closed even when the file
        failed (the error is raised after)."""
        from htm.errors import RecordError

        try:
            self.flush()
        finally:
            self.rec.disconnect()
            try:
                self.spool.close()
            except OSError as e:
                raise RecordError(f"cannot write the recording: {e}") from None
