"""Speed of record re-simulation, the inner loop of `htm diagnose`'s model fit.

A 60 s closed-loop position record at 500 Hz from the proving ground (rich reference, noise),
re-simulated with `htm.ident.sim.predict`: one simulation alone at the fit's tolerance
(sim.RTOL) and at the core's default 1e-6, the accuracy lost against rtol 1e-8, and a batch of
32 parameter sets on all cores versus the same batch on one thread (the GIL is released).
Peer: the speed target of the fit, one 60 s simulation well under 0.1 s.

Run: .venv/bin/python benchmarks/replay_speed.py   (prints one JSON object)
"""
from __future__ import annotations

import json
import os
import time

import numpy as np

from htm.ident import proving, sim


def best_of(fn, n=3):
    """Best wall time of n runs, and the CPU time of that run (the machine may be shared)."""
    best, cpu = np.inf, np.inf
    for _ in range(n):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        wall = time.perf_counter() - t0
        if wall < best:
            best, cpu = wall, time.process_time() - c0
    return best, cpu, out


def main() -> None:
    rec, truth = proving.make_record({}, seed=1, duration_s=60, rate_hz=500)
    p = sim.params_from_meta(rec.meta)
    for k, v in truth["params"].items():
        p[k] = v
    t_fit, cpu_fit, pred = best_of(lambda: sim.predict(p, rec))
    t_default, cpu_default, _ = best_of(lambda: sim.predict(p, rec, rtol=1e-6))
    exact = sim.predict(p, rec, rtol=1e-8)
    err = {c: float(np.max(np.abs(pred[c] - exact[c]))) for c in pred}
    rng = np.random.default_rng(0)
    batch = []
    for _ in range(32):
        q = p.copy()
        for f in ("moving_mass_kg", "bulk_modulus_pa", "valve_rated_flow_m3_s", "friction_coulomb_pos_n"):
            q[f] = q[f] * rng.uniform(0.8, 1.2)
        batch.append(q)
    t_one_thread, _, _ = best_of(lambda: sim.predict(batch, rec, threads=1), n=1)
    t_all, cpu_all, _ = best_of(lambda: sim.predict(batch, rec), n=1)
    print(json.dumps({
        "record_s": 60.0, "rate_hz": 500, "rtol": sim.RTOL,
        "seconds_per_simulation": round(t_fit, 4),
        "cpu_seconds_per_simulation": round(cpu_fit, 4),
        "seconds_per_simulation_rtol_1e-6": round(t_default, 4),
        "cpu_seconds_per_simulation_rtol_1e-6": round(cpu_default, 4),
        "real_time_factor": round(60.0 / t_fit, 1),
        "max_abs_error_vs_rtol_1e-8": {c: float(f"{e:.3g}") for c, e in err.items()},
        "noise_std": {c: proving.NOISE_STD[c] for c in pred},
        "batch_32_seconds_one_thread": round(t_one_thread, 3),
        "batch_32_seconds_all_cores": round(t_all, 3),
        "batch_32_cpu_seconds_all_cores": round(cpu_all, 3),
        "load_average_1min": round(os.getloadavg()[0], 2),
        "cores": os.cpu_count(),
        "peer": {"target_seconds_per_simulation": 0.1},
    }, indent=2))


if __name__ == "__main__":
    main()
