"""Speed of record re-simulation, the inner loop of `htm diagnose`'s model fit.

A 60 s closed-loop position record at 500 Hz from the proving ground (rich reference, noise),
re-simulated with `htm.ident.sim.predict`: one simulation alone at the fit's tolerance
(sim.RTOL) and at the core's default 1e-6, the accuracy lost against rtol 1e-8, and a batch of
32 parameter sets on all cores versus the same batch on one thread (the GIL is released).
Peer: the speed target of the fit, one 60 s simulation well under 0.1 s.

`jacobian`: what the fit spends on one Jacobian — the point and its 18 neighbours (a step of
each base parameter of the valve family), simulated as the fit does on the recorded command over
its fit horizons — simulated alone (each with its own step-size control) and in lockstep with
the point (on its step sizes, `lockstep=True`), one thread: CPU seconds, the integrator's
accepted and rejected steps and right-hand sides, and each way's column error against columns
simulated alone at rtol 1e-7 (median and worst over the columns, relative, channel y and p_a).

`spool_block`: one 60 s simulation on the recorded command (open loop, one thread, the base
model's second-order spool at 150 Hz as a diagnosis fits it), its integrator stages solved with the
spool's decoupled block apart (`OdeSystem::DECOUPLED_TAIL`, the default) against one dense solve
of the coupled 7-state system (`dense_stages=True`, the form before): CPU and wall seconds (best of
5, interleaved), steps, and the largest difference of the readings between the two.

`main_peer`: the fit's batches on the recorded command with this build and with main's (the
extension module built from branch main, loaded beside this one from `--peer` or
$HTM_PEER_CORE, default /work/main/python/htm/_core*.so; left out when there is none),
interleaved in the same run, best of 5: one 60 s simulation on one thread (CPU), the fit's
point and two neighbours on its fit samples on 2 threads (a step of the fit: wall and CPU), and
the point with 18 neighbours (a Jacobian) on 2 threads; the integrator's steps and the largest
difference of the readings between the two builds. Beside the wall time, which on a shared
machine measures the load as much as the batch, `busiest_thread_cpu_seconds`: the CPU time of
the batch's busiest worker thread (read from /proc while the call runs, best of 5) — what the
batch's wall time is on idle cores, and how evenly it spreads its work, whatever the load.

Run: .venv/bin/python benchmarks/replay_speed.py [--peer PATH]   (prints one JSON object)
"""
from __future__ import annotations

import argparse
import glob
import importlib.machinery
import importlib.util
import json
import os
import threading
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
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--peer", help="main's build of htm._core (a .so file) for `main_peer`")
    a = ap.parse_args()
    peer_path = a.peer or os.environ.get("HTM_PEER_CORE") or next(iter(glob.glob("/work/main/python/htm/_core*.so")), None)
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
    jac = jacobian_peer(rec, p)
    block = spool_block(rec, p)
    peer = main_peer(rec, p, peer_path) if peer_path and os.path.exists(peer_path) else None
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
        "jacobian": jac,
        "spool_block": block,
        "main_peer": peer,
    }, indent=2))


def load_peer(path: str):
    """main's build of the extension module, loaded beside this one (its own module object)."""
    loader = importlib.machinery.ExtensionFileLoader("_core", path)
    spec = importlib.util.spec_from_file_location("_core", path, loader=loader)
    assert spec is not None
    mod = importlib.util.module_from_spec(spec)
    loader.exec_module(mod)
    return mod


def busiest_thread_cpu(fn) -> float:
    """CPU seconds of the busiest thread that `fn` starts (its worker threads, polled from
    /proc/self/task every half millisecond while it runs; a thread's last reading is taken at
    most that long before it ends)."""
    before = set(os.listdir("/proc/self/task"))
    seen: dict[str, int] = {}
    stop = threading.Event()

    def poll() -> None:
        me = str(threading.get_native_id())
        while not stop.is_set():
            for tid in os.listdir("/proc/self/task"):
                if tid in before or tid == me:
                    continue
                try:
                    with open(f"/proc/self/task/{tid}/schedstat") as f:
                        seen[tid] = int(f.read().split()[0])
                except (OSError, ValueError, IndexError):
                    pass
            time.sleep(5e-4)

    th = threading.Thread(target=poll)
    th.start()
    try:
        fn()
    finally:
        stop.set()
        th.join()
    return max(seen.values()) * 1e-9 if seen else float("nan")


def main_peer(rec, p, path: str) -> dict:
    """The fit's batches with this build and main's, interleaved: wall and CPU seconds (best of
    5), steps, and the largest reading difference between the two builds."""
    from htm import _core as this
    from htm.ident.fit import spread_blocks

    peer = load_peer(path)
    n = len(rec.columns["t"])
    fit_mask, _ = spread_blocks(n, 500.0, sim.DEFAULT_HORIZON_S, 20.0)
    args = sim._setup(rec, True) | {"supply": np.ascontiguousarray(sim.supply_schedule(rec), dtype=float),
                                    "horizon_s": sim.DEFAULT_HORIZON_S, "preroll_s": sim.PREROLL_S, "rtol": sim.RTOL}
    rng = np.random.default_rng(1)
    sets = [p.copy()]
    for _ in range(18):
        q = p.copy()
        for f in ("moving_mass_kg", "bulk_modulus_pa", "valve_rated_flow_m3_s", "friction_coulomb_pos_n"):
            q[f] = q[f] * (1.0 + 1e-3 * rng.standard_normal())
        sets.append(q)

    def as_peer(q):
        r = peer.Params("base")
        for k, v in q.to_dict().items():
            r[k] = v
        r.valve_map = q.valve_map
        return r

    cases = {"one_simulation_1_thread": (sets[:1], None, 1), "fit_step_3_sets_2_threads": (sets[:3], fit_mask, 2),
             "jacobian_19_sets_2_threads": (sets, fit_mask, 2)}
    out: dict = {"peer": path}
    for name, (qs, active, threads) in cases.items():
        kw = args | {"threads": threads} | ({"active": np.ascontiguousarray(active)} if active is not None else {})
        qs_peer = [as_peer(q) for q in qs]
        best = {"this": [np.inf, np.inf], "main": [np.inf, np.inf]}
        res = {}
        for _ in range(5):
            for who, mod, ps in (("main", peer, qs_peer), ("this", this, qs)):
                t0, c0 = time.perf_counter(), time.process_time()
                res[who] = mod.replay(ps, **kw)
                wall, cpu = time.perf_counter() - t0, time.process_time() - c0
                best[who] = [min(best[who][0], wall), min(best[who][1], cpu)]
        busiest = {"this": np.inf, "main": np.inf}
        if threads > 1:
            for _ in range(5):
                for who, mod, ps in (("main", peer, qs_peer), ("this", this, qs)):
                    busiest[who] = min(busiest[who], busiest_thread_cpu(lambda mod=mod, ps=ps, kw=kw: mod.replay(ps, **kw)))
        diff = max(float(np.nanmax(np.abs(a[c] - b[c]))) if np.isfinite(a[c]).any() else 0.0
                   for a, b in zip(res["this"], res["main"]) for c in ("y", "p_a", "p_b"))
        out[name] = {"sets": len(qs), "threads": threads,
                     "seconds": {w: round(best[w][0], 4) for w in best}, "cpu_seconds": {w: round(best[w][1], 4) for w in best},
                     "wall_ratio_this_over_main": round(best["this"][0] / best["main"][0], 3),
                     **({"busiest_thread_cpu_seconds": {w: round(v, 4) for w, v in busiest.items()},
                         "busiest_thread_ratio_this_over_main": round(busiest["this"] / busiest["main"], 3)} if threads > 1 else {}),
                     "steps": {w: [sum(r["steps"] for r in res[w]), sum(r["rejected"] for r in res[w])] for w in res},
                     "max_abs_difference_y_p": diff}
    return out


def spool_block(rec, p) -> dict:
    """One 60 s open-loop simulation with the spool's block solved apart vs one dense solve."""
    from htm.core import CHANNELS, replay

    q = p.copy()
    q["valve_natural_hz"], q["valve_damping"] = 150.0, 0.7
    t = np.asarray(rec.columns["t"], dtype=float)
    args = {"dt": float(np.median(np.diff(t))), "u": np.ascontiguousarray(rec.columns["u"], dtype=float),
            "measured": {c: np.ascontiguousarray(rec.columns[c], dtype=float) for c in CHANNELS if c in rec.columns},
            "rtol": sim.RTOL, "threads": 1}
    best = {False: (np.inf, np.inf), True: (np.inf, np.inf)}
    out = {}
    for _ in range(5):
        for dense in (True, False):
            t0, c0 = time.perf_counter(), time.process_time()
            out[dense] = replay([q], dense_stages=dense, **args)[0]
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            best[dense] = (min(best[dense][0], wall), min(best[dense][1], cpu))
    diff = {c: float(f"{np.nanmax(np.abs(out[True][c] - out[False][c])):.3g}") for c in ("y", "v", "p_a", "p_b")}
    return {"cpu_seconds": {"block": round(best[False][1], 4), "dense_coupled": round(best[True][1], 4)},
            "seconds": {"block": round(best[False][0], 4), "dense_coupled": round(best[True][0], 4)},
            "cpu_ratio_block_over_dense": round(best[False][1] / best[True][1], 3),
            "steps": {"block": [out[False]["steps"], out[False]["rejected"]], "dense_coupled": [out[True]["steps"], out[True]["rejected"]]},
            "max_abs_difference": diff}


def jacobian_peer(rec, p) -> dict:
    """One Jacobian of the fit (the point and its neighbours over the fit horizons on the recorded
    command), alone and in lockstep: CPU, integrator work and column error against rtol 1e-7."""
    from htm.ident.fit import spread_blocks
    from htm.ident.model import Model, get_value, has_key
    from htm.ident.valve import OTHER_FREES, RIG_FREES

    n = len(rec.columns["t"])
    fit_mask, _ = spread_blocks(n, 500.0, sim.DEFAULT_HORIZON_S, 20.0)
    frees = [f for f in RIG_FREES + OTHER_FREES if has_key(p, f.key) and (not f.log or get_value(p, f.key) > 0)]
    model = Model(p, frees, np.zeros(len(frees)))
    x = model.start()
    plist = [model.at(x).params()] + [model.at(x + f.step * np.eye(len(x))[i]).params() for i, f in enumerate(frees)]
    kw = {"command": True, "active": fit_mask, "supply": sim.supply_schedule(rec), "threads": 1}
    steps_of = sim.replay
    work: dict = {}

    def counted(*a, **k):
        out = steps_of(*a, **k)
        work.update(accepted=sum(r["steps"] for r in out), rejected=sum(r["rejected"] for r in out),
                    rhs_evals=sum(r["rhs_evals"] for r in out))
        return out

    sim.replay = counted
    try:
        runs = {}
        for name, lock in (("alone", False), ("lockstep", True)):
            t, cpu, pred = best_of(lambda lock=lock: sim.predict(plist, rec, lockstep=lock, **kw), n=2)
            runs[name] = {"cpu_seconds": round(cpu, 3), "seconds": round(t, 3), **work, "pred": pred}
    finally:
        sim.replay = steps_of
    tight = sim.predict(plist, rec, rtol=1e-7, **kw)
    for r in runs.values():
        pred = r.pop("pred")
        for c in ("y", "p_a"):
            errs = []
            for i in range(1, len(plist)):
                ref = (tight[i][c] - tight[0][c])[fit_mask]
                col = (pred[i][c] - pred[0][c])[fit_mask]
                if np.linalg.norm(ref) > 0:
                    errs.append(float(np.linalg.norm(col - ref) / np.linalg.norm(ref)))
            r[f"column_error_{c}"] = {"median": float(f"{np.median(errs):.3g}"), "worst": float(f"{np.max(errs):.3g}")}
    return {"columns": len(plist) - 1, **runs}


if __name__ == "__main__":
    main()
