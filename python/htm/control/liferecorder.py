"""Recording a life test run through the device loop into the test store, as `htm run` writes a
simulated one (`htm.lifestore`): the catalogue row (spec, status, end reason, cycles), the
per-cycle table ``cycles.parquet`` with the simulator's columns, ``loops.parquet`` (every sample
of the loops the core kept at logarithmic intervals), the results (failed, life, 10 % / 50 %
drops, the stabilised loop), the events, and a rerun recording (``recording.rrd``).

A thread beside the loop (never in it) drains the test's rows every `PERIOD_S` and rewrites the
two tables, so a test cut short keeps what it measured; at the end the results, the recording
and the status are written."""
from __future__ import annotations

import json
import math
import threading
import time
from typing import Any

import numpy as np

from htm.control.recorder import Follower
from htm.errors import HtmError

PERIOD_S = 0.5
# the simulator's per-cycle table (`core.run_life`'s `table`), column for column
TABLE = ("cycle", "fmax_n", "fmin_n", "stress_max_pa", "stress_min_pa", "strain_max", "strain_min", "plastic_strain_range",
         "modulus_t_pa", "modulus_c_pa", "stiffness_n_m", "trend", "events")


class LifeRecorder(Follower):
    """Drains a `Session`'s loop for life test `test_no` into a new test of the store."""

    def __init__(self, session: Any, store_root: Any, spec: Any, test_no: int, first_event: int, *, recording: bool = True) -> None:
        self.s = session
        self.spec = spec
        self.test_no = test_no
        self.root = store_root
        self.recording = recording
        self.rows: list[dict[str, Any]] = []
        self.periods: list[int] = []  # the loop period each row closed at
        self.loops: dict[str, list] = {"cycle": [], "strain": [], "stress_pa": []}
        self.event = first_event
        self.period0 = session.loop.k
        self.t0 = time.perf_counter()
        self.status: str | None = None
        self.error: str | None = None
        self.id: str | None = None
        self.ready = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="htm-life-recorder", daemon=True)
        self._thread.start()

    @property
    def test_id(self) -> str | None:
        self.ready.wait(5.0)
        return self.id

    def _run(self) -> None:
        from htm.record import Store

        try:
            self.st = Store(self.root)
            self.id = self.st.create_test(self.spec.name, self.spec.mode, "device", "json", json.dumps(self.spec.config, default=float),
                                          self.spec.config.get("frequency_hz"))
            self.dir = self.st.test_dir(self.id)
        except (HtmError, OSError) as e:
            self.error = str(e)
            self.s.log.add(self.period0, "error", f"life test not recorded: {e}")
            return
        finally:
            self.ready.set()
        try:
            self._follow(PERIOD_S)
        except (HtmError, OSError) as e:  # the store failed: say so; the loop runs on safely
            self.error = str(e)
            self.s.log.add(self.period0, "error", f"life recording stopped: {e}")

    def _drain(self) -> None:
        lp = self.s.loop
        if lp is None:
            return
        last = self.rows[-1]["cycle"] if self.rows else 0
        new = [r for r in list(lp.cycles) if r["test"] == self.test_no and r["cycle"] > last]
        for r in new:
            self.rows.append({k: r[k] for k in TABLE})
            self.periods.append(r.get("period", 0))
            if "loop_strain" in r:
                n = len(r["loop_strain"])
                self.loops["cycle"] += [r["cycle"]] * n
                self.loops["strain"] += list(map(float, r["loop_strain"]))
                self.loops["stress_pa"] += list(map(float, r["loop_stress_pa"]))
        events = self.s.log.since(self.event)
        for e in events:  # dated by the last cycle of this test that closed before it
            c = max((r["cycle"] for r, k in zip(self.rows, self.periods) if k <= e["period"]), default=None)
            self.st.add_event(self.id, e["kind"], e["message"], cycle=c, time_s=max((e["period"] - self.period0) * lp.dt, 0.0),
                              source="device")
        self.event += len(events)
        if new:
            self._tables()

    def _tables(self) -> None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        t = self.table()
        pq.write_table(pa.table(t), self.dir / "cycles.parquet", compression="zstd")
        pq.write_table(pa.table({"cycle": np.asarray(self.loops["cycle"], np.uint64), "strain": np.asarray(self.loops["strain"], float),
                                 "stress_pa": np.asarray(self.loops["stress_pa"], float)}), self.dir / "loops.parquet", compression="zstd")
        self.st.add_file(self.id, "loops", self.dir / "loops.parquet")

    def table(self) -> dict[str, np.ndarray]:
        """The per-cycle table so far (the simulator's columns)."""
        out = {k: np.asarray([r[k] for r in self.rows], float) for k in TABLE}
        out["cycle"] = out["cycle"].astype(np.uint64)
        out["events"] = out["events"].astype(np.uint32)
        return out

    def outcome(self, end_reason: str | None) -> dict[str, Any]:
        """The test as `core.run_life` returns a simulated one (no hidden truth on a rig)."""
        lp = self.s.loop
        c = lp.ctrl if lp is not None and lp.test_no == self.test_no else None
        nan = math.nan
        failed = end_reason in ("separation", "load_drop", "modulus_ratio")
        return {"table": self.table(), "loops": {k: np.asarray(v, np.uint64 if k == "cycle" else float) for k, v in self.loops.items()},
                "end_reason": end_reason or "cancelled", "failed": failed, "cycles": int(self.rows[-1]["cycle"]) if self.rows else 0,
                "n_drop10": getattr(c, "n_drop10", None), "n_drop50": getattr(c, "n_drop50", None), "n_modulus": None,
                "cycles_simulated": 0, "truth": {k: nan for k in ("life_factor", "n_init", "n_phi10", "n_phi50", "n_sep")}}

    def _close(self, status: str, reason: str | None) -> None:
        if self.status is not None:
            return
        self.status = status
        from htm import lifestore
        from htm.fatigue import lifetest

        out = self.outcome(reason)
        wall = time.perf_counter() - self.t0
        if self.rows:
            self._tables()
        s = lifetest.summary(self.spec, out, wall)
        self.st.set_results(self.id, {"failed": int(s["failed"]), "life_cycles": s["cycles"], "n_drop10": s["n_drop10"],
                                      "n_drop50": s["n_drop50"], "wall_time_s": wall, "stabilised": s["stabilised"]})
        (self.dir / "summary.json").write_text(json.dumps(s, indent=2, default=float) + "\n", encoding="utf-8")
        (self.dir / "summary.txt").write_text(lifetest.summary_text(s) + "\n", encoding="utf-8")
        if self.recording and self.rows:
            rrd = self.dir / "recording.rrd"
            lifestore.write_recording(rrd, self.id, self.spec, out)
            self.st.add_file(self.id, "recording", rrd)
        self.st.set_status(self.id, status, reason, out["cycles"])

    def stop(self) -> None:
        """Flush what is left and close the test as stopped (the session is closing)."""
        self._stop.set()
        self._thread.join(20.0)
