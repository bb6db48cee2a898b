"""The shared external benchmark's thirteen cases (`shared/benchmarks/diagnose_external/generator/
cases.py`, copied), made with any seed shift: `shift = 0` gives the shipped records, any other
shift the same cases on other rigs (`rig_variant`), references and noise.

    python benchmarks/external_rig/cases.py --shift 1000 --out DIR   (writes DIR/records, DIR/truth)
"""
from __future__ import annotations

import argparse
import copy
import math
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rig import Case, write  # noqa: E402


def rig_variant(seed):
    r = np.random.default_rng(seed)
    return dict(
        mass=float(r.uniform(48, 62)), bv=float(r.uniform(3800, 6200)), fc=float(r.uniform(600, 900)),
        fs=float(r.uniform(80, 200)), beta=float(r.uniform(1.0e9, 1.6e9)),
        kv=float(r.uniform(0.85, 1.0)) * 1.25e-3 / (10.0 * math.sqrt(3.5e6)),
        v0a=float(r.uniform(4e-5, 8e-5)), v0b=float(r.uniform(4e-5, 8e-5)), underlap=float(r.uniform(0.02, 0.05)),
    )


CASES = [
    Case("rec_a1", None, seed=11),
    Case("rec_b7", "sensor_offset", "p_b", {"offset_pa": -2.6e5}, seed=12),
    Case("rec_c3", "valve_dynamics", None, {"tau_s": 0.009}, seed=13),
    Case("rec_d9", "valve_null_bias", None, {"bias_v": 0.09}, seed=14),
    Case("rec_e2", "friction_asymmetry", None, {"coulomb_pos_n": 980.0, "coulomb_neg_n": 560.0}, seed=15),
    Case("rec_f5", "sensor_delay", "y", {"delay_s": 0.006}, seed=16),
    Case("rec_g4", "valve_deadband", None, {"half_width_v": 0.12}, seed=17),
    Case("rec_h8", "pressure_dependent_friction", None, {"coeff_n_per_pa": 2.0e-5}, seed=18),
    Case("rec_i6", "supply_pressure_sag", None, {"resistance_pa_s_per_m3": 2.0e9}, seed=19, measure_ps=False),
    Case("rec_j0", "oov_position_friction", None, {"extra_n": 700.0, "y0": 0.115, "y1": 0.135}, seed=20,
         notes="out of vocabulary: friction bump over part of the stroke"),
    Case("rec_k2", "sensor_gain", "p_a", {"gain": 0.965}, seed=21, fs_hz=1000.0),
    Case("rec_l1", "valve_hysteresis", None, {"half_width_v": 0.08}, seed=22),
    Case("rec_m3", None, seed=23, fs_hz=1000.0),
]


def cases(shift: int = 0, names: list[str] | None = None) -> list[Case]:
    """The cases with every seed moved by `shift` (their rig variants drawn from the moved seed)."""
    out = []
    for c in CASES:
        if names and c.name not in names:
            continue
        c = copy.deepcopy(c)
        c.seed += shift
        c.rig_overrides = {**rig_variant(c.seed), **c.rig_overrides}
        out.append(c)
    return out


def generate(out: str, shift: int = 0, names: list[str] | None = None) -> list[str]:
    """Write the records and truths of the (shifted) cases under `out`; returns their names."""
    records, truth = os.path.join(out, "records"), os.path.join(out, "truth")
    os.makedirs(records, exist_ok=True)
    os.makedirs(truth, exist_ok=True)
    done = []
    for c in cases(shift, names):
        write(c, records, truth)
        done.append(c.name)
    return done


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shift", type=int, default=0, help="added to every case's seed (0: the shipped records)")
    ap.add_argument("--out", required=True)
    ap.add_argument("names", nargs="*")
    a = ap.parse_args()
    for name in generate(a.out, a.shift, a.names or None):
        print("wrote", name)


if __name__ == "__main__":
    main()
