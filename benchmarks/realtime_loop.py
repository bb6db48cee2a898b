"""The control loop against the virtual rig: lock-step throughput of the whole device path
(SYNC → TPDO → loop → valve command → plant, canopen + python-can virtual bus + simulated DAQ)
and real-time jitter at 500 Hz and 1 kHz on a dedicated thread, running the thesis C(T) test
under the demodulation controller. Prints JSON next to the acceptance figures it is judged by.
Each test is recorded, as the console records it, into a temporary store that is removed at
the end (the user's store never sees a benchmark).

    .venv/bin/python benchmarks/realtime_loop.py [--seconds 60] [--lockstep-periods 20000]
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

from htm.control import Session
from htm.control.session import specimen_of
from htm.devices.config import virtual_config
from htm.spec import load

SPEC = Path(__file__).resolve().parents[1] / "examples" / "ct_constant_force.toml"


def lockstep(periods: int, store: Path) -> float:
    spec = load(SPEC)
    s = Session().open(virtual_config("lockstep"), virtual=True, specimen=specimen_of(spec), thread=False)
    try:
        s.start(spec, store=store)
        s.step(500)
        t0 = time.perf_counter()
        s.step(periods)
        wall = time.perf_counter() - t0
        assert s.snapshot()["interlock"] is None
        return periods / wall
    finally:
        s.close()


def realtime(rate_hz: float, seconds: float, priority: int, store: Path) -> dict:
    spec = load(SPEC)
    cfg = virtual_config("realtime", rate_hz=rate_hz, loop={"priority": priority})
    s = Session().open(cfg, virtual=True, specimen=specimen_of(spec))
    try:
        s.start(spec, store=store)
        time.sleep(seconds)
        snap = s.snapshot()
        trips = [e["message"] for e in s.events_since(0) if e["kind"] == "trip"]
        return {**snap["timing"], "cycles": snap["cycles"], "interlock": snap["interlock"], "trips": trips[:5]}
    finally:
        s.close()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--lockstep-periods", type=int, default=20_000)
    ap.add_argument("--priority", type=int, default=10, help="SCHED_FIFO priority of the loop thread (0 = normal)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="htm-bench-store-") as tmp:
        store = Path(tmp)
        ls = lockstep(a.lockstep_periods, store)
        r500 = realtime(500.0, a.seconds, a.priority, store)
        r1000 = realtime(1000.0, a.seconds, a.priority, store)
    print(json.dumps({
        "lockstep_periods_per_s": round(ls, 1),
        "rt500_p99_ms": round(r500["p99_ms"], 4),
        "rt500_overrun_pct": round(r500["overrun_pct"], 4),
        "rt1000_p99_ms": round(r1000["p99_ms"], 4),
        "rt1000_overrun_pct": round(r1000["overrun_pct"], 4),
        "rt500": r500, "rt1000": r1000, "seconds_each": a.seconds, "priority": a.priority,
        "compared_to": {"lockstep_periods_per_s": ">= 2000 (issue 6)", "rt500_p99_ms": "<= 0.5", "rt500_overrun_pct": "<= 0.1"},
        "load_average_at_end": os.getloadavg(),
    }, indent=1))


if __name__ == "__main__":
    main()
