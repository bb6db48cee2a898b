"""Key handling latency of htm-tui while the control loop runs a test at 500 Hz on the virtual rig.

Each sample is one key press (alternating tabs, the heaviest key: the new tab renders its plots and
live numbers). Key handling latency = from sending the key until its action has run; the time until
the console is idle again (the new screen drawn, Textual's tab underline animation done) is given
beside it. The peer, from the same run: the same presses with no rig attached. Prints JSON.

    .venv/bin/python benchmarks/tui_latency.py [--presses 200]
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import tempfile
import time

import numpy as np

from htm.tui.app import HtmApp


async def measure(app: HtmApp, presses: int, start_test: bool) -> dict:
    lat, idle = [], []
    handled: list[float] = []
    orig = app.action_tab

    def timed(tab: str) -> None:
        orig(tab)
        handled.append(time.perf_counter())

    app.action_tab = timed  # type: ignore[method-assign]
    async with app.run_test(size=(160, 50)) as pilot:
        if start_test:
            while app.session is None:
                await pilot.pause(0.1)
            await pilot.press("f4", "s")
            while app.session.snapshot()["cycles"] < 30:  # past the ramp-in: the test is cycling
                await pilot.pause(0.2)
        t_run = time.perf_counter()
        for i in range(presses):
            key = "f3" if i % 2 else "f4"
            n = len(handled)
            t0 = time.perf_counter()
            await pilot.press(key)
            idle.append((time.perf_counter() - t0) * 1e3)
            lat.append((handled[n] - t0) * 1e3 if len(handled) > n else float("nan"))
            await pilot.pause(0.05)  # the poller and the plots keep running between presses
        out = {"key_ms_p50": float(np.percentile(lat, 50)), "key_ms_p99": float(np.percentile(lat, 99)),
               "key_ms_max": float(np.max(lat)), "idle_ms_p50": float(np.percentile(idle, 50)),
               "idle_ms_p99": float(np.percentile(idle, 99)), "presses": presses, "seconds": time.perf_counter() - t_run}
        if start_test:
            snap = app.session.snapshot()
            tm = snap["timing"]
            out.update({"loop_rate_hz": snap["rate_hz"], "loop_state": snap["state"], "cycles": snap["cycles"],
                        "loop_p99_ms": tm.get("p99_ms"), "loop_overrun_pct": tm.get("overrun_pct"),
                        "loop_periods": snap["period"]})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--presses", type=int, default=200)
    args = ap.parse_args()
    os.environ.setdefault("HTM_STORE", tempfile.mkdtemp(prefix="htm-bench-store-"))
    with_loop = asyncio.run(measure(HtmApp(), args.presses, True))
    idle = asyncio.run(measure(HtmApp(session_factory=lambda: None), args.presses, False))
    print(json.dumps({"key_latency_ms_p99_with_loop": with_loop["key_ms_p99"], "key_latency_ms_max_with_loop": with_loop["key_ms_max"],
                      "with_loop_500hz": with_loop, "peer_without_rig": idle, "target_ms": 100.0}, indent=2))


if __name__ == "__main__":
    main()
