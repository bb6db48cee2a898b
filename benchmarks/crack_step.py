"""The crack reading's cost per control period: the worst per-period controller step with the
crack measured by compliance (each interval's reduction — closure grid search, open compliance,
crack size — spread over the periods of the next interval) against the same test on the law
(no measurement), through `htm.Session` on the in-process virtual rig. Beside them, the peer:
one interval reduced at once (what one period did before the reduction was spread). Prints JSON.

    .venv/bin/python benchmarks/crack_step.py [--cycles 300] [--geometry mt|ct] [--samples-per-cycle 50 200]

The controller's `step` is timed by the thread's CPU time (time.thread_time_ns around the call the
loop makes each period: the work done, not the waits of a machine shared with other processes);
the Python call itself costs a few µs of every figure.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from crack_rig import spec_doc  # noqa: E402

from htm import core  # noqa: E402
from htm.spec import parse  # noqa: E402


class Timed:
    """The loop's controller with its `step` timed; everything else passes through."""

    def __init__(self, ctrl):
        object.__setattr__(self, "_c", ctrl)
        object.__setattr__(self, "ns", [])

    def step(self, f, y, m):
        t0 = time.thread_time_ns()
        u = self._c.step(f, y, m)
        self.ns.append(time.thread_time_ns() - t0)
        return u

    def __getattr__(self, k):
        return getattr(self._c, k)

    def __setattr__(self, k, v):
        setattr(self._c, k, v)


def run(geometry: str, crack: str, cycles: int, spc: int, seed: int = 1) -> dict:
    from htm.control.session import Session, specimen_of
    from htm.devices.config import virtual_config

    dk = (6e6, 3e6) if geometry == "mt" else (14e6, 7e6)
    doc = spec_doc(geometry, 1.0, 0.3 if geometry == "mt" else 0.1, crack, *dk)
    doc["loading"].update(control_rate_hz=500.0, frequency_hz=500.0 / spc)
    spec = parse(doc, "crack_step", check=False)
    gy = doc["measurement"].get("gauge_y_m", 0.004)
    rig = virtual_config("lockstep", analog={"channels": {"cod": "ai4", "dcpd": "ai5", "dcpd_current": "ai6"}},
                         virtual={"specimen": {"seed": seed}, "gauges": {"cod": {"noise_m": 0.2e-6, "closure_opening_fraction": 0.3},
                                                                        "dcpd": {"probe_y_m": gy}}})
    if geometry == "mt":
        rig.virtual_gauges["cod"]["gauge_y_m"] = gy
    ses = Session().open(rig, virtual=True, specimen=specimen_of(spec), thread=False)
    try:
        ses.step(5)
        ses.start(spec, record=False)
        ses.step(1)
        t = Timed(ses.loop.ctrl)
        ses.loop.ctrl = t
        while t.cycle < 30 + 20:  # the start and the ramp-in, then readings under way
            ses.step(spc)
        t.ns.clear()
        c0 = t.cycle
        while t.cycle < c0 + cycles and t.state == "running":
            ses.step(spc)
        ns = np.array(t.ns, dtype=float)
        rows = [r for r in ses.cycles_since(c0)]
    finally:
        ses.close()
    us = ns / 1e3
    return {"crack": crack, "geometry": geometry, "samples_per_cycle": spc, "periods": int(len(us)), "cycles": len(rows),
            "step_us_max": round(float(us.max()), 1), "step_us_p999": round(float(np.quantile(us, 0.999)), 1),
            "step_us_p99": round(float(np.quantile(us, 0.99)), 1), "step_us_median": round(float(np.median(us)), 2),
            "readings": int(sum(1 for r in rows if r["events"] & 1024)) if rows else 0}


def at_once_ms(geometry: str, spc: int, repeat: int = 5) -> float:
    """The peer: one 5-cycle interval reduced at once (`htm.core.crack_reduce`, the same code)."""
    w, b, y = (0.1524, 0.00254, 0.01) if geometry == "mt" else (0.0508, 0.00635, None)
    n = 5 * spc
    k = np.arange(n)
    cyc = 1.0 + k // spc
    f = 2000.0 + 9000.0 * (1 + np.sin(2 * np.pi * (k % spc) / spc))
    cod = 2e-9 * f + np.random.default_rng(1).normal(0, 0.2e-6, n)
    kw = {"cod_y_m": y, "modulus_pa": 72e9} if geometry == "mt" else {"modulus_pa": 200e9}
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        core.crack_reduce("MT" if geometry == "mt" else "CT", w, b, "compliance", cyc, cod, f, **kw)
        best = min(best, time.perf_counter() - t0)
    return round(best * 1e3, 3)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cycles", type=int, default=300)
    ap.add_argument("--geometry", default="mt", choices=("ct", "mt"))
    ap.add_argument("--samples-per-cycle", type=int, nargs="+", default=[50, 200])
    a = ap.parse_args(argv)
    runs = []
    for spc in a.samples_per_cycle:
        m = run(a.geometry, "compliance", a.cycles, spc)
        law = run(a.geometry, "model", a.cycles, spc)
        runs.append({"samples_per_cycle": spc, "compliance": m, "law": law,
                     "peer_interval_reduced_at_once_ms": at_once_ms(a.geometry, spc),
                     "worst_step_compliance_over_law": round(m["step_us_max"] / law["step_us_max"], 2)})
    json.dump({"benchmark": "crack_step", "runs": runs}, sys.stdout, indent=1)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
