"""Reference scenario: the plant in a fixed-gain force P loop, Rust core vs SciPy LSODA.

Default rig, C(T) specimen spring 1.04e8 N/m, force P loop sampled at 1 kHz (zero-order hold),
force reference 20 kN + 2 kN sin(2 pi 10 t), 10 s simulated. Both integrators run the same model
(SciPy calls the core's right-hand side), each compared with a tight-tolerance reference solution
(RODAS4 at rtol 1e-10; its own self-consistency against rtol 1e-11 is printed too).

Run: .venv/bin/python benchmarks/plant_throughput.py   (prints one JSON object)
"""
from __future__ import annotations

import json
import time

import numpy as np
from scipy.integrate import solve_ivp

import htm
from htm.params import thesis_rig

K_SPECIMEN = 1.04e8
KP = -1.0e-4  # V/N; negative: the thesis valve's polarity is negative
DT = 1e-3
T_END = 10.0
RUST_RTOL = 1e-4
# SciPy's absolute tolerances, per state in the core's order (htm._core.Machine.state):
# pressures A, B [Pa], position [m], velocity [m/s], spool [V], spool velocity [V/s], lagged
# command [V]. The spool states only move on a rig with valve dynamics (the thesis rig's spool
# follows its command at once); their scales are the core's own error weights (1 V, 1e3 V/s, 1 V).
ATOL = {"p_a": 1.0, "p_b": 1.0, "y": 1e-10, "v": 1e-8, "spool": 1e-6, "spool_velocity": 1e-3, "lag": 1e-6}


def state_atol(n: int) -> np.ndarray:
    """`ATOL` for a state of length `n`; a state that grew past the table is an error, not a guess."""
    if n != len(ATOL):
        raise SystemExit(f"the plant state has {n} entries, the benchmark's tolerances know {len(ATOL)} "
                         f"({', '.join(ATOL)}): give the new states a tolerance in ATOL")
    return np.array(list(ATOL.values()))


def scenario():
    p = thesis_rig(specimen_stiffness_n_m=K_SPECIMEN)
    t = np.arange(int(round(T_END / DT))) * DT
    ref = 20e3 + 2e3 * np.sin(2 * np.pi * 10 * t)
    y_start = p["specimen_zero_force_position_m"] + 20e3 / K_SPECIMEN
    return p, ref, y_start


def rust_run(p, ref, y_start, rtol):
    m = htm.Machine(p, rtol)
    m.state = m.rest_state(y_start)
    t0 = time.perf_counter()
    tr = m.track(ref, DT, {"type": "force_p", "kp_v_per_n": KP, "u_max_v": 10.0})
    return tr, time.perf_counter() - t0


def scipy_run(p, ref, y_start):
    m = htm.Machine(p)
    x = m.rest_state(y_start)
    y0 = p["specimen_zero_force_position_m"]
    atol = state_atol(len(x))
    f = np.empty(len(ref))
    t0 = time.perf_counter()
    for k, r in enumerate(ref):
        f[k] = K_SPECIMEN * (x[2] - y0)
        u = float(np.clip(KP * (r - f[k]), -10.0, 10.0))
        sol = solve_ivp(lambda _t, s, u=u: m.rhs(s, u), (0.0, DT), x, method="LSODA", rtol=1e-6, atol=atol)
        x = sol.y[:, -1]
    return f, time.perf_counter() - t0


def rms(a):
    return float(np.sqrt(np.mean(np.square(a))))


def main() -> None:
    p, ref, y_start = scenario()
    reference, _ = rust_run(p, ref, y_start, 1e-10)
    reference_check, _ = rust_run(p, ref, y_start, 1e-11)
    runs = [rust_run(p, ref, y_start, RUST_RTOL) for _ in range(3)]
    tr = runs[0][0]
    rust_wall = min(w for _, w in runs)
    f_scipy, scipy_wall = scipy_run(p, ref, y_start)
    out = {
        "scenario": "thesis rig, K_sp 1.04e8 N/m, force P (kp -1e-4 V/N) at 1 kHz ZOH, 20 kN + 2 kN sin(2 pi 10 t), 10 s",
        "rust_realtime_factor": round(T_END / rust_wall, 1),
        "rust_rms_force_error_n": rms(tr["f"] - reference["f"]),
        "scipy_realtime_factor": round(T_END / scipy_wall, 3),
        "scipy_rms_force_error_n": rms(f_scipy - reference["f"]),
        "speedup_vs_scipy": round(scipy_wall / rust_wall, 1),
        "rust_wall_s": rust_wall,
        "scipy_wall_s": scipy_wall,
        "rust_rtol": RUST_RTOL,
        "rust_steps": tr["stats"],
        "scipy_method": "LSODA restarted every sample, rtol 1e-6, atol [1 Pa, 1 Pa, 1e-10 m, 1e-8 m/s, 1e-6 V, 1e-3 V/s, 1e-6 V]",
        "reference_self_check_rms_n": rms(reference["f"] - reference_check["f"]),
        "loop_rms_tracking_error_n": rms(ref - tr["f"]),
    }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
