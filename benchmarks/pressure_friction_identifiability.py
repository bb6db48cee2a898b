"""Is pressure-dependent friction identifiable from a record of one supply level? The shared
external case `rec_h8` (a friction force `coeff * (p_a + p_b)` added to the Coulomb level) and its
seed-shifted variants, re-simulated by the external rig's own generator (`external_rig/rig.py`,
not this project's model) twice: with the effect as generated, and without it but with the
Coulomb level raised by `coeff * mean(p_a + p_b)` of the first run (the constant friction any
one-supply record offers in its place). Both noise-free, same reference, same controller.

Printed per record (one JSON line each, then a summary): the RMS difference of each measured
channel between the two runs, in units of that channel's measurement noise (the generator's own
noise and quantization), and `chi2`: the sum over all samples and channels of the squared
difference over the noise variance — the most any estimator could gain in fit by telling the two
apart. Against it, `bic_one_parameter` = ln(number of readings), the least gain for which one more
parameter pays (BIC). Then `chi2_refit`: the same after the effect-free run's Coulomb, Stribeck,
static and viscous friction are refitted to the first run (SciPy least squares, the generator's own
model structure: the best any model of that exact form can do without the effect), and where the
difference lies (`chi2_share_by_speed`: shares of chi2 by |v| band, m/s). Beside it `chi2_floor`:
the same sum between the run with the effect and itself with a perturbation no estimator should
see (mass x (1 + 1e-6); Coulomb + 1 mN): the generator's loop, fed a 5 um position quantum, takes
another path at standstill for any difference, so a chi2 of that size tells nothing apart.

Run: .venv/bin/python benchmarks/pressure_friction_identifiability.py [--shift 0 --shift 1000 ...] [--no-refit]
"""
from __future__ import annotations

import argparse
import copy
import json
import math
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "external_rig"))

import cases as external  # noqa: E402
import rig as extrig  # noqa: E402
from external_form import NOISE as GENERATOR_NOISE  # noqa: E402

# The generator's measurement noise of the channels compared here (external_form.py: y quantized
# to 5 um; pressures with 3 kPa noise on a 16-bit 400 bar range).
NOISE = {c: GENERATOR_NOISE[c] for c in ("y", "p_a", "p_b")}


def twin_of(case: extrig.Case, keep_effect: bool = False, **rig: float) -> dict:
    """The generator's noise-free run of `case` with its rig changed by `rig`, without its hidden
    effect (or with it, `keep_effect`)."""
    alt = copy.deepcopy(case)
    if not keep_effect:
        alt.effect, alt.true_params = None, {}
    alt.rig_overrides = {**case.rig_overrides, **rig}
    return extrig.simulate(alt)[1]


def chi2_of(truth: dict, twin: dict) -> np.ndarray:
    return np.concatenate([(truth[ch] - twin[ch]) / sd for ch, sd in NOISE.items()])


def compare(case: extrig.Case, refit: bool) -> dict:
    _, truth, _ = extrig.simulate(case)
    coeff = case.true_params["coeff_n_per_pa"]
    psum = truth["p_a"] + truth["p_b"]
    fc = extrig.Rig(**case.rig_overrides).fc
    level = fc + coeff * float(np.mean(psum))
    twin = twin_of(case, fc=level)
    out = {"seed": case.seed, "coeff_n_per_pa": coeff, "p_sum_mean_bar": round(float(np.mean(psum)) / 1e5, 2),
           "p_sum_sd_bar": round(float(np.std(psum)) / 1e5, 3),
           "friction_variation_sd_n": round(coeff * float(np.std(psum)), 2),
           "coulomb_level_n": round(fc + coeff * float(np.mean(psum)), 1)}
    chi2, n = 0.0, 0
    for ch, sd in NOISE.items():
        d = truth[ch] - twin[ch]
        out[f"rms_{ch}_over_noise"] = round(float(np.sqrt(np.mean(d * d))) / sd, 4)
        chi2 += float(np.sum((d / sd) ** 2))
        n += len(d)
    out["chi2"] = round(chi2, 2)
    out["bic_one_parameter"] = round(math.log(n), 2)
    # What no simulator but the generator itself can reproduce: the same run with the effect and a
    # perturbation no estimator should see (the mass one part in a million heavier; the Coulomb
    # level 1 mN higher). The loop feeds back a position quantized to 5 um, so at standstill the
    # command steps on a quantum's edge and tiny differences grow into a different path.
    rig0 = extrig.Rig(**case.rig_overrides)
    floor = {"mass_1e-6": twin_of(case, True, mass=rig0.mass * (1 + 1e-6)), "coulomb_1mN": twin_of(case, True, fc=rig0.fc + 1e-3)}
    out["chi2_floor"] = {k: round(float(np.sum(chi2_of(truth, tw) ** 2)), 1) for k, tw in floor.items()}
    out["identifiable"] = chi2 > math.log(n)
    speed = np.abs(truth["v"])
    z = chi2_of(truth, twin).reshape(len(NOISE), -1)
    z2 = np.sum(z * z, axis=0)
    out["chi2_share_by_speed"] = {f"{lo:g}-{hi:g}": round(float(np.sum(z2[(speed >= lo) & (speed < hi)]) / max(np.sum(z2), 1e-300)), 3)
                                  for lo, hi in ((0, 1e-3), (1e-3, 1e-2), (1e-2, math.inf))}
    if refit:
        from scipy.optimize import least_squares
        rig = extrig.Rig(**case.rig_overrides)

        def res(x: np.ndarray) -> np.ndarray:
            return chi2_of(truth, twin_of(case, fc=x[0], fs=x[1], bv=x[2], cs=x[3] * 1e-3))

        sol = least_squares(res, [level, rig.fs, rig.bv, rig.cs * 1e3], x_scale=[50.0, 20.0, 300.0, 3.0], diff_step=1e-3, max_nfev=60)
        out["chi2_refit"] = round(float(sol.fun @ sol.fun), 1)
        out["refit"] = {"fc_n": round(float(sol.x[0]), 1), "fs_n": round(float(sol.x[1]), 1), "bv_n_s_m": round(float(sol.x[2]), 1),
                        "cs_m_s": round(float(sol.x[3]) * 1e-3, 5)}
        out["identifiable_after_refit"] = out["chi2_refit"] > math.log(n)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shift", type=int, action="append", help="seed shift (repeatable; default 0 1000)")
    ap.add_argument("--no-refit", action="store_true", help="skip the friction refit (seconds instead of a minute per record)")
    a = ap.parse_args()
    rows = []
    for shift in a.shift or [0, 1000]:
        for case in external.cases(shift, ["rec_h8"]):
            r = {"shift": shift, **compare(case, not a.no_refit)}
            rows.append(r)
            print(json.dumps(r), flush=True)
    print(json.dumps({"records": len(rows), "identifiable": sum(r["identifiable"] for r in rows),
                      "max_chi2": max(r["chi2"] for r in rows),
                      "max_chi2_floor": max(max(r["chi2_floor"].values()) for r in rows),
                      "min_chi2_refit": min((r["chi2_refit"] for r in rows if "chi2_refit" in r), default=None),
                      "bic_one_parameter": rows[0]["bic_one_parameter"]}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
