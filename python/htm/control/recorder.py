"""Recording a live test from the device loop into the test store (`htm.record.TestWriter`).

A thread beside the loop (never in it) drains what the loop publishes — per-cycle results, the
decimated signal feed, the event log — every `PERIOD_S` and hands it to the writer, which
journals it first. When the test ends (the controller stops, a trip powers off, the session
closes) the writer is closed with the matching status, so the Results screen and `htm db` see it.
"""
from __future__ import annotations

import math
import threading
from typing import Any

import numpy as np

from htm.errors import HtmError

PERIOD_S = 0.25
# loop feed keys → the recording's signal names (see htm.record)
SIGNALS = {"t_s": "t_s", "y": "y_m", "f": "f_n", "p_a": "p_a_pa", "p_b": "p_b_pa", "p_s": "p_s_pa", "u": "u_v"}


def _columns(rows: list[dict[str, Any]], keys: dict[str, str] | None = None) -> dict[str, np.ndarray]:
    """Rows of numbers → columns (bools and numbers only; other values are left out)."""
    if not rows:
        return {}
    if keys is not None:
        return {out: np.array([float(r.get(k, math.nan)) for r in rows]) for k, out in keys.items()}
    names = [k for k, v in rows[0].items() if isinstance(v, (int, float, bool)) and k != "period"]
    cols = {k: np.asarray([r[k] for r in rows]) for k in names}
    cols.setdefault("events", np.zeros(len(rows), np.uint32))  # the engine table's event bits (none here)
    return cols


class LiveRecorder:
    """Drains a `Session`'s loop into a new test of the store at `store_root` until the test ends
    or `stop()`. The store and its writer live on the recorder's own thread (SQLite connections
    stay with the thread that made them)."""

    def __init__(self, session: Any, store_root: Any, name: str, spec_body: str, frequency_hz: float,
                 first_event: int, *, recording: bool = True) -> None:
        from htm.record import Store, TestWriter

        self.s = session
        self.w: Any = None
        self.ready = threading.Event()
        self._open = lambda: TestWriter.create(Store(store_root), name, "device", session.cfg.loop.mode, "json",
                                               spec_body, frequency_hz, recording=recording)
        self.period = session.loop.k
        self.cycle = 0
        self.event = first_event
        self.status: str | None = None
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
        rows = [r for r in list(lp.cycles) if r["cycle"] > self.cycle and r.get("period", 0) > 0]
        events = self.s.log.since(self.event)
        if feed:
            self.period = feed[-1]["period"]
            self.w.signals(_columns(feed, SIGNALS))
        if rows:
            self.cycle = rows[-1]["cycle"]
            self.w.cycles(_columns(rows))
        for e in events:
            self.w.event(e["kind"], e["message"], cycle=self.cycle, time_s=e["period"] * lp.dt,
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
            while True:
                stopping = self._stop.wait(PERIOD_S)
                self._drain()
                if stopping:
                    self._close("stopped", "session closed")
                    return
                lp = self.s.loop
                c = lp.ctrl if lp is not None else None
                ended = c is None or (c.state in ("stopped", "idle") and not lp.powered)
                tripped = lp is not None and not lp.powered and lp.safety.latched() == "power_off"
                if ended or tripped:
                    self._drain()
                    end = getattr(c, "end_reason", None)
                    reason = end or (f"interlock {lp.safety.latched()}" if lp is not None and lp.safety.latched() else "stopped")
                    self._close("finished" if end else "stopped", reason)
                    return
        except (HtmError, OSError) as e:  # the store failed: say so; the loop runs on safely
            self.error = str(e)
            self.s.log.add(self.period, "error", f"recording stopped: {e}")
            try:
                self.w.interrupt("error", str(e))
            except (HtmError, OSError):
                pass

    def _close(self, status: str, reason: str | None) -> None:
        if self.status is None:
            self.status = status
            self.w.close(status, reason, {"cycles": self.cycle})

    def stop(self) -> None:
        """Flush what is left and close the test as stopped (the session is closing)."""
        self._stop.set()
        self._thread.join(10.0)
