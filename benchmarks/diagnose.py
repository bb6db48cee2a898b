"""`htm diagnose` on a 60 s, 500 Hz proving-ground record with one effect (valve_dynamics), timed
as the command a user runs (a subprocess: read the CSV, fit, search, write report and plots).
A second 60 s record with valve play (`hunting`) times the slowest path: the closed loop hunts
on its sensor noise, so the search runs twice (free run, then on the recorded command).

Goal: <= 60 s wall on a 2-core machine. Printed next to it: the number of simulations and the
wall time of one whole-record simulation (the unit the search spends), from the same run, and
the effect found vs the true one.

Run: .venv/bin/python benchmarks/diagnose.py   (prints one JSON object)
"""
from __future__ import annotations

import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from htm.ident import proving, sim
from htm.ident.records import write_record

BUDGET_S = 60.0
EFFECT = {"valve_dynamics": {"tau_s": 0.015}}
HUNTING = {"valve_hysteresis": {"half_width_v": 0.25}}


def run_cli(rec) -> tuple[float, int, dict]:
    """Wall time, simulations and report of `htm diagnose` on `rec` written as CSV."""
    with tempfile.TemporaryDirectory() as tmp:
        table, _ = write_record(rec, Path(tmp) / "bench60")
        out = Path(tmp) / "out"
        t0 = time.perf_counter()
        res = subprocess.run([sys.executable, "-m", "htm.cli", "diagnose", str(table), "--out", str(out)],
                             capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if res.returncode != 0:
            raise SystemExit(f"htm diagnose failed after {wall:.1f} s: {res.stderr.strip()}")
        report = json.loads((out / "report.json").read_text())
    return wall, int(re.search(r"(\d+) simulations", res.stdout).group(1)), report


def found_and_true(report: dict, truth: dict) -> dict:
    return {"found": [{"effect": f["effect"], "channel": f["channel"], "params": f["params"]} for f in report["findings"]],
            "true": [{"effect": k, "channel": v["channel"], "params": v["params"]} for k, v in truth["effects"].items()],
            "unexplained": report["unexplained"]}


def main() -> None:
    rec, truth = proving.make_record(EFFECT, seed=7, duration_s=60.0, rate_hz=500)
    p = sim.params_from_meta(rec.meta)
    t0 = time.perf_counter()
    sim.predict([p], rec)
    one_sim = time.perf_counter() - t0
    wall, sims, report = run_cli(rec)
    hrec, htruth = proving.make_record(HUNTING, seed=3, duration_s=60.0, rate_hz=500)
    hwall, hsims, hreport = run_cli(hrec)
    print(json.dumps({
        "benchmark": "htm diagnose, 60 s record at 500 Hz, one effect",
        "seconds": round(wall, 2),
        "budget_s": BUDGET_S,
        "within_budget": wall <= BUDGET_S,
        "simulations": sims,
        "one_60s_simulation_s": round(one_sim, 4),
        **found_and_true(report, truth),
        "rmse_y_before_after_m": [report["baseline"]["rmse"]["y"], report["final"]["rmse"]["y"]],
        "hunting": {"seconds": round(hwall, 2), "within_budget": hwall <= BUDGET_S, "simulations": hsims,
                    **found_and_true(hreport, htruth)},
    }, indent=2))


if __name__ == "__main__":
    main()
