"""`htm diagnose` on 60 s, 500 Hz proving-ground records, timed as the command a user runs (a
subprocess: read the CSV, fit, search, write report and plots), along its paths: one effect
(valve_dynamics); two effects at once with valve play, whose loop hunts on its sensor noise
(two findings, each polished); and a friction bump outside EFFECTS.md (the search finds nothing,
then the probes for structure outside the vocabulary run). The slowest of them is the figure.

Goal: slowest <= 60 s wall on a 2-core machine. Printed next to it: the number of simulations and
the wall time of one whole-record simulation (the unit the search spends), from the same run,
and the effects found vs the true ones.

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
PATHS = {
    "one_effect": ({"valve_dynamics": {"tau_s": 0.015}}, {}),
    "two_effects_hunting": ({"valve_hysteresis": {"half_width_v": 0.25}, "sensor_offset": {"channel": "p_a", "offset_pa": 4e5}}, {}),
    "outside_the_table": ({}, {"effect_outside_table": "friction_bump"}),
}


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
    out: dict = {"benchmark": "htm diagnose, 60 s records at 500 Hz", "budget_s": BUDGET_S}
    for i, (name, (effects, kw)) in enumerate(PATHS.items()):
        rec, truth = proving.make_record(effects, seed=7 + i, duration_s=60.0, rate_hz=500, **kw)
        if i == 0:
            p = sim.params_from_meta(rec.meta)
            t0 = time.perf_counter()
            sim.predict([p], rec)
            out["one_60s_simulation_s"] = round(time.perf_counter() - t0, 4)
        wall, sims, report = run_cli(rec)
        out[name] = {"seconds": round(wall, 2), "simulations": sims, **found_and_true(report, truth),
                     "rmse_y_before_after_m": [report["baseline"]["rmse"]["y"], report["final"]["rmse"]["y"]]}
    slowest = max(PATHS, key=lambda k: out[k]["seconds"])
    out |= {"slowest_path": slowest, "seconds": out[slowest]["seconds"], "within_budget": out[slowest]["seconds"] <= BUDGET_S}
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
