"""`htm diagnose` on a 60 s `machine_position` record at 1 kHz (a machine that closes its own
loop: command, position and load cell), timed as the command a user runs (a subprocess: read
the CSV, fit, search, write report, model.json and plots). The record is the loop proving
ground's (the valve-level plant in a position loop, u and pressures dropped) with a specimen
and a slow valve (`valve_dynamics`, tau 15 ms).

Goal: <= 30 s wall on a 2-core machine. Printed next to it, from the same run: the simulations
the search spent, the wall time of one 60 s simulation and of a batch of 16, and the effect found
vs the true one.

Run: .venv/bin/python benchmarks/diagnose_loop.py   (prints one JSON object)
"""
from __future__ import annotations

import json
import time

from diagnose import run_cli  # benchmarks/diagnose.py, beside this file

from htm.ident import loop
from htm.ident.loop_proving import make_loop_record

BUDGET_S = 30.0
EFFECT = {"valve_dynamics": {"tau_s": 0.015}}


def main() -> None:
    rec, truth = make_loop_record(EFFECT, seed=7, duration_s=60.0, rate_hz=1000, specimen=True)
    p = loop.params_from_meta(rec.meta)
    t0 = time.perf_counter()
    loop.simulate([p], rec, threads=1)
    one = time.perf_counter() - t0
    t0 = time.perf_counter()
    loop.simulate([p] * 16, rec)
    batch = time.perf_counter() - t0
    wall, simulations, report = run_cli(rec)  # the CLI as a user runs it, as benchmarks/diagnose.py does
    print(json.dumps({
        "benchmark": "htm diagnose, 60 s machine_position record at 1 kHz (y_ref, y, f), one effect",
        "seconds": round(wall, 2),
        "budget_s": BUDGET_S,
        "within_budget": wall <= BUDGET_S,
        "simulations": simulations,
        "one_60s_simulation_s": round(one, 4),
        "batch_of_16_60s_simulations_s": round(batch, 4),
        "found": [{"effect": f["effect"], "channel": f["channel"], "params": f["params"]} for f in report["findings"]],
        "true": [{"effect": k, "channel": v["channel"], "params": v["params"]} for k, v in truth["effects"].items()],
        "unexplained": report["unexplained"],
        "rmse_y_before_after_m": [report["baseline"]["rmse"]["y"], report["final"]["rmse"]["y"]],
    }, indent=2))


if __name__ == "__main__":
    main()
