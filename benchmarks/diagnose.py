"""`htm diagnose` on 60 s, 500 Hz proving-ground records, timed as the command a user runs (a
subprocess: read the CSV, fit, search, write report and plots), along its paths: one effect
(valve_dynamics); two effects at once with valve play, whose loop hunts on its sensor noise
(two findings, each polished); and a friction bump outside EFFECTS.md (the search finds nothing,
then the probes for structure outside the vocabulary run). The slowest of them is the figure.

Goal (issue 31): slowest <= 15 s and median <= 8 s wall on a 2-core machine. Printed next to it:
the number of simulations and the wall time of one whole-record simulation (the unit the search
spends), from the same run, the effects found vs the true ones, and the wall time, CPU
seconds and simulations per stage of each path (from the progress lines `htm diagnose` prints on
stderr as each stage begins, each with the CPU seconds and simulations so far: a stage lasts until
the next line; the last until the command ends, so it includes writing the files and the
interpreter's exit). Beside each wall time, the CPU seconds the command spent (user +
system, all its threads): on a machine shared with other work the wall time measures the load
as much as the diagnosis, the CPU time much less so; the load average is printed at the start
and the end of the run.

With `--peer N`, each path is also diagnosed in this process twice, with the settings as they
are and with the Jacobian differenced afresh every N iterations instead (`jacobian_every`; 2 was
the schedule before issue 31), and the simulations and CPU seconds of both are printed side by
side (`peer`): the same record, the same machine, the same minute.

With `--lockstep`, each path is also diagnosed in this process twice, with the Jacobians'
neighbours simulated alone (each with its own step-size control, as before issue 31 item 4) and
in lockstep with their point (on its step sizes: `htm.ident.fit.LOCKSTEP`, off by default), with
the simulations, CPU seconds, the integrator's steps and the findings side by side (`lockstep`).

Run: .venv/bin/python benchmarks/diagnose.py [--peer 2] [--lockstep]   (prints one JSON object)
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from htm.ident import fit, proving, sim
from htm.ident.diagnose import diagnose
from htm.ident.records import write_record
from htm.ident.settings import DEFAULT

BUDGET_S = 15.0
MEDIAN_BUDGET_S = 8.0
STAGE_LINE = re.compile(r"^\[\s*([0-9.]+) s\] ([^:]+?)(?::|$)")
SO_FAR = re.compile(r"\(cpu ([0-9.]+) s, (\d+) simulations so far\)$")
PATHS = {
    "one_effect": ({"valve_dynamics": {"tau_s": 0.015}}, {}),
    "two_effects_hunting": ({"valve_hysteresis": {"half_width_v": 0.25}, "sensor_offset": {"channel": "p_a", "offset_pa": 4e5}}, {}),
    "outside_the_table": ({}, {"effect_outside_table": "friction_bump"}),
}


def stage_seconds(stderr: str, wall: float, cpu: float = 0.0, sims: int = 0) -> dict[str, dict[str, float]]:
    """Per stage, from the progress lines (a stage lasts until the next line begins; the last
    until the command ends): wall seconds, CPU seconds and simulations (each line carries the
    command's CPU seconds and simulations so far; `cpu`, `sims`: its totals at the end)."""
    lines = [ln for ln in stderr.splitlines() if STAGE_LINE.match(ln)]
    starts = []
    for ln in lines:
        m, so = STAGE_LINE.match(ln), SO_FAR.search(ln)
        assert m is not None
        starts.append((float(m.group(1)), m.group(2).strip(), float(so.group(1)) if so else 0.0, int(so.group(2)) if so else 0))
    out: dict[str, dict[str, float]] = {"wall": {}, "cpu": {}, "simulations": {}}
    ends = [(t, c, n) for t, _, c, n in starts[1:]] + [(wall, cpu, sims)]
    for (t, stage, c, n), (t1, c1, n1) in zip(starts, ends):
        for key, d in (("wall", t1 - t), ("cpu", c1 - c), ("simulations", n1 - n)):
            out[key][stage] = round(out[key].get(stage, 0.0) + d, 2)
    out["simulations"] = {k: int(v) for k, v in out["simulations"].items()}
    return out


def children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run_cli(rec) -> tuple[float, float, int, dict, dict]:
    """Wall time, CPU time, simulations, report and seconds per stage of `htm diagnose` on `rec`
    written as CSV."""
    with tempfile.TemporaryDirectory() as tmp:
        table, _ = write_record(rec, Path(tmp) / "bench60")
        out = Path(tmp) / "out"
        t0, c0 = time.perf_counter(), children_cpu()
        res = subprocess.run([sys.executable, "-m", "htm.cli", "diagnose", str(table), "--out", str(out)],
                             capture_output=True, text=True)
        wall, cpu = time.perf_counter() - t0, children_cpu() - c0
        if res.returncode != 0:
            raise SystemExit(f"htm diagnose failed after {wall:.1f} s: {res.stderr.strip()}")
        report = json.loads((out / "report.json").read_text())
    sims = int(re.search(r"([\d,]+) simulations", res.stdout).group(1).replace(",", ""))
    return wall, cpu, sims, report, stage_seconds(res.stderr, wall, cpu, sims)


def in_process(rec, settings, lockstep: bool = fit.LOCKSTEP) -> dict:
    """Simulations, CPU seconds (this process, all its threads), integrator steps and findings
    of `diagnose` on `rec` with `settings` (and Jacobians in lockstep or not), run in this process
    (no files written)."""
    stats: dict = {}
    steps = {"accepted": 0, "rejected": 0, "rhs_evals": 0}
    replay = sim.replay

    def counted(*a, **kw):
        out = replay(*a, **kw)
        for r in out:
            if isinstance(r, dict):
                for k, key in (("accepted", "steps"), ("rejected", "rejected"), ("rhs_evals", "rhs_evals")):
                    steps[k] += r[key]
        return out

    before, fit.LOCKSTEP, sim.replay = fit.LOCKSTEP, lockstep, counted
    try:
        r0 = resource.getrusage(resource.RUSAGE_SELF)
        report = diagnose(rec, settings=settings, stats=stats)
        r1 = resource.getrusage(resource.RUSAGE_SELF)
    finally:
        fit.LOCKSTEP, sim.replay = before, replay
    cpu = (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)
    return {"jacobian_every": settings.jacobian_every, "lockstep": lockstep, "simulations": stats["simulations"],
            "cpu_seconds": round(cpu, 2), "integrator": steps,
            "found": [{"effect": f["effect"], "channel": f["channel"], "params": f["params"]} for f in report["findings"]],
            "unexplained": report["unexplained"]}


def found_and_true(report: dict, truth: dict) -> dict:
    return {"found": [{"effect": f["effect"], "channel": f["channel"], "params": f["params"]} for f in report["findings"]],
            "true": [{"effect": k, "channel": v["channel"], "params": v["params"]} for k, v in truth["effects"].items()],
            "unexplained": report["unexplained"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--peer", type=int, metavar="N", help="also diagnose each path in process with jacobian_every = N")
    ap.add_argument("--lockstep", action="store_true", help="also diagnose each path in process with the Jacobians' "
                                                             "neighbours simulated alone and in lockstep")
    a = ap.parse_args()
    out: dict = {"benchmark": "htm diagnose, 60 s records at 500 Hz", "budget_s": BUDGET_S,
                 "load_average_1min_start": round(os.getloadavg()[0], 2)}
    for i, (name, (effects, kw)) in enumerate(PATHS.items()):
        rec, truth = proving.make_record(effects, seed=7 + i, duration_s=60.0, rate_hz=500, **kw)
        if i == 0:
            p = sim.params_from_meta(rec.meta)
            t0 = time.perf_counter()
            sim.predict([p], rec)
            out["one_60s_simulation_s"] = round(time.perf_counter() - t0, 4)
        wall, cpu, sims, report, stages = run_cli(rec)
        out[name] = {"seconds": round(wall, 2), "cpu_seconds": round(cpu, 2), "simulations": sims,
                     "stage_seconds": stages["wall"], "stage_cpu_seconds": stages["cpu"],
                     "stage_simulations": stages["simulations"],
                     **found_and_true(report, truth),
                     "rmse_y_before_after_m": [report["baseline"]["rmse"]["y"], report["final"]["rmse"]["y"]]}
        if a.peer:
            out[name]["peer"] = [in_process(rec, DEFAULT), in_process(rec, dataclasses.replace(DEFAULT, jacobian_every=a.peer))]
        if a.lockstep:
            out[name]["lockstep"] = [in_process(rec, DEFAULT, lockstep=False), in_process(rec, DEFAULT, lockstep=True)]
    slowest = max(PATHS, key=lambda k: out[k]["seconds"])
    median = float(statistics.median(out[k]["seconds"] for k in PATHS))
    out |= {"slowest_path": slowest, "seconds": out[slowest]["seconds"], "median_seconds": round(median, 2),
            "median_budget_s": MEDIAN_BUDGET_S, "within_budget": out[slowest]["seconds"] <= BUDGET_S and median <= MEDIAN_BUDGET_S,
            "load_average_1min": round(os.getloadavg()[0], 2), "cpus": os.cpu_count()}
    # what the slowest path's wall time would be on 2 idle cores, by its CPU time: a lower bound
    # (every second of it spread over both cores), beside the measured one
    out["slowest_cpu_seconds_over_cpus"] = round(out[slowest]["cpu_seconds"] / max(1, os.cpu_count() or 1), 2)
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
