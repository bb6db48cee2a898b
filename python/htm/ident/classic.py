"""Classic identification (thesis chapter 3) from a measurement record.

Constant-velocity segments; friction fits on F_h - F_g at those speeds (linear, quadratic, Stribeck
with sign or smoothed sign, C_s by scan; linear LS and bounded nonlinear LS) with a constant offset
term as in eq. 3.16 — the term that exposed the thesis rig's 4 bar transducer offset; velocity gain
with null offset (eq. 3.21); moving mass from acceleration (eq. 3.10). The friction basis functions
are the core's own friction model evaluated with unit parameters.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import maximum_filter1d, minimum_filter1d, uniform_filter1d
from scipy.optimize import least_squares

from htm.core import Params, friction_force
from htm.errors import RecordError
from htm.ident.records import Record, clean_record, validate_record

G = 9.80665
SMOOTHING_M_S = 1e-3  # eps of the smoothed sign, as the thesis fitted it (section 3.4.4)


@dataclass
class Segment:
    start: int
    stop: int
    v: float  # mean velocity [m/s]
    u: float  # mean command [V]
    f: float  # mean A_a p_a - A_b p_b - M g [N] (nan without pressures)


def _fill_nan(x: np.ndarray) -> np.ndarray:
    bad = ~np.isfinite(x)
    if not bad.any():
        return x
    idx = np.arange(len(x))
    return np.interp(idx, idx[~bad], x[~bad])


def velocity(rec: Record) -> np.ndarray:
    """Measured velocity, or the smoothed derivative of position when the record has none."""
    t = rec.columns["t"]
    if "v" in rec.columns:
        return _fill_nan(np.asarray(rec.columns["v"], dtype=float))
    y = _fill_nan(np.asarray(rec.columns["y"], dtype=float))
    return uniform_filter1d(np.gradient(y, t), size=5)


def constant_velocity_segments(t: np.ndarray, v: np.ndarray, *, min_duration_s: float = 0.08,
                               rel_tol: float = 0.03, abs_tol_m_s: float = 5e-4, v_min_m_s: float = 1e-3) -> list[tuple[int, int]]:
    """Index ranges where |v| > v_min and v stays within max(rel_tol*|v|, abs_tol) for at least
    `min_duration_s` (the thesis's y'' ~ 0 condition)."""
    dt = float(np.median(np.diff(t)))
    w = max(3, int(round(min_duration_s / dt)))
    hi, lo = maximum_filter1d(v, w), minimum_filter1d(v, w)
    mean = uniform_filter1d(v, w)
    steady = (hi - lo <= np.maximum(rel_tol * np.abs(mean), abs_tol_m_s)) & (np.abs(mean) > v_min_m_s) & (np.sign(hi) == np.sign(lo))
    # a window centred on a steady sample covers its neighbours too
    covered = maximum_filter1d(steady.astype(np.uint8), w).astype(bool)
    segs = []
    i, n = 0, len(v)
    while i < n:
        if covered[i]:
            j = i
            while j < n and covered[j]:
                j += 1
            trim = (j - i) // 10  # drop the edges where the window only partly fits
            if j - i - 2 * trim >= w:
                segs.append((i + trim, j - trim))
            i = j
        else:
            i += 1
    return segs


def _rig(rec: Record) -> dict:
    rig = rec.meta.get("rig") or {}
    for key in ("area_a_m2", "area_b_m2", "moving_mass_kg"):
        if not isinstance(rig.get(key), (int, float)) or rig[key] <= 0:
            raise RecordError(f"record `{rec.name}`: metadata rig.{key} is needed for identification")
    return rig


def segments(rec: Record) -> list[Segment]:
    t = rec.columns["t"]
    v = velocity(rec)
    u = _fill_nan(np.asarray(rec.columns["u"], dtype=float))
    rig = _rig(rec)
    g = G if rig.get("orientation", "vertical") == "vertical" else 0.0
    if "p_a" in rec.columns and "p_b" in rec.columns:
        f = rig["area_a_m2"] * _fill_nan(rec.columns["p_a"]) - rig["area_b_m2"] * _fill_nan(rec.columns["p_b"]) - rig["moving_mass_kg"] * g
    else:
        f = np.full(len(t), np.nan)
    return [Segment(i, j, float(v[i:j].mean()), float(u[i:j].mean()), float(f[i:j].mean())) for i, j in constant_velocity_segments(t, v)]


def _unit(**kw: float) -> Params:
    """Friction parameters all zero but the given ones (for basis functions)."""
    p = Params("base")
    for name in ("friction_viscous_n_s_m", "friction_coulomb_pos_n", "friction_coulomb_neg_n", "friction_static_n",
                 "friction_pressure_coeff_n_per_pa"):
        p[name] = 0.0
    for k, val in kw.items():
        p[k] = val
    return p


def stribeck_basis(v: np.ndarray, c_s: float, eps: float) -> np.ndarray:
    """Columns [v, sig(v), sig(v) exp(-|v|/C_s)] from the core's friction model (eq. 3.2, 3.19)."""
    v = np.ascontiguousarray(v, dtype=float)
    z = np.zeros_like(v)
    cols = [
        friction_force(_unit(friction_viscous_n_s_m=1.0, friction_smoothing_m_s=eps), v, z),
        friction_force(_unit(friction_coulomb_pos_n=1.0, friction_coulomb_neg_n=1.0, friction_smoothing_m_s=eps), v, z),
        friction_force(_unit(friction_static_n=1.0, friction_stribeck_m_s=c_s, friction_smoothing_m_s=eps), v, z),
    ]
    return np.column_stack(cols)


def _r2(y: np.ndarray, yhat: np.ndarray) -> float:
    ss = float(np.sum((y - y.mean()) ** 2))
    return 1.0 - float(np.sum((y - yhat) ** 2)) / ss if ss > 0 else float("nan")


def fit_friction(v: np.ndarray, f: np.ndarray, *, offset: bool = True) -> dict:
    """Fit every friction model of thesis 3.4 to (v*, F*) with an optional constant offset term."""
    if len(v) < 5:
        raise RecordError(f"only {len(v)} constant-velocity segments with pressures; at least 5 are needed to fit friction")
    one = np.ones((len(v), 1)) if offset else np.zeros((len(v), 0))
    out: dict[str, dict] = {}

    def ls(name: str, basis: np.ndarray, names: list[str], extra: dict | None = None) -> np.ndarray:
        a = np.hstack([basis, one])
        theta, *_ = np.linalg.lstsq(a, f, rcond=None)
        params = dict(zip(names + (["offset_n"] if offset else []), map(float, theta)))
        out[name] = {"params": {**params, **(extra or {})}, "r2": _r2(f, a @ theta), "method": "LS"}
        return theta

    ls("linear", v[:, None], ["viscous_n_s_m"])
    ls("poly2", np.column_stack([v, v * np.abs(v)]), ["viscous_n_s_m", "quadratic_n_s2_m2"])
    for name, eps in (("stribeck_sign", 1e-9), ("stribeck_sig", SMOOTHING_M_S)):
        best = None
        for c_s in np.geomspace(1e-4, 0.2, 60):  # C_s by scan (thesis: chosen by inspection)
            a = np.hstack([stribeck_basis(v, c_s, eps), one])
            theta, *_ = np.linalg.lstsq(a, f, rcond=None)
            sse = float(np.sum((a @ theta - f) ** 2))
            if best is None or sse < best[0]:
                best = (sse, c_s, theta)
        _, c_s, theta = best
        names = ["viscous_n_s_m", "coulomb_n", "static_n"] + (["offset_n"] if offset else [])
        a = np.hstack([stribeck_basis(v, c_s, eps), one])
        out[name] = {"params": {**dict(zip(names, map(float, theta))), "stribeck_m_s": float(c_s)}, "r2": _r2(f, a @ theta), "method": "LS"}

        # bounded nonlinear LS over all terms including C_s (thesis: lsqnonlin with bounds)
        def resid(x: np.ndarray) -> np.ndarray:
            basis = stribeck_basis(v, x[3], eps)
            pred = basis @ x[:3] + (x[4] if offset else 0.0)
            return pred - f

        x0 = np.r_[np.maximum(theta[:3], 1e-6), c_s, theta[3] if offset else 0.0]
        lo = [0.0, 0.0, 0.0, 1e-4, -np.inf if offset else -1e-12]
        hi = [np.inf, np.inf, np.inf, 0.2, np.inf if offset else 1e-12]
        r = least_squares(resid, np.clip(x0, lo, hi), bounds=(lo, hi), x_scale="jac")
        params = dict(zip(["viscous_n_s_m", "coulomb_n", "static_n", "stribeck_m_s"], map(float, r.x[:4])))
        if offset:
            params["offset_n"] = float(r.x[4])
        out[name + "_nls"] = {"params": params, "r2": _r2(f, resid(r.x) + f), "method": "bounded NLS"}
    return out


def fit_velocity_gain(segs: list[Segment]) -> dict:
    """v* = K (u* - u0): velocity gain K [m/s per V] and the valve's hydraulic null u0 [V]."""
    u = np.array([s.u for s in segs])
    v = np.array([s.v for s in segs])
    if len(segs) < 3 or np.ptp(u) <= 0:
        raise RecordError("fewer than 3 constant-velocity segments at different commands: cannot identify the velocity gain")
    k, b = np.polyfit(u, v, 1)
    return {"gain_m_s_per_v": float(k), "null_command_v": float(-b / k), "r2": _r2(v, k * u + b)}


def fit_mass(rec: Record, friction: dict) -> dict:
    """M from M a = F_h - F_g - F_f(v) - offset (eq. 3.10) with the identified friction, over the
    smoothly accelerating samples. Needs smooth motion resolved by the sampling (sines of a few Hz
    at 1 kHz); the zero-order-hold transient inside each sample biases it at coarse rates."""
    if "p_a" not in rec.columns or "p_b" not in rec.columns:
        raise RecordError("mass identification needs chamber pressures p_a and p_b")
    rig = _rig(rec)
    t = rec.columns["t"]
    v = velocity(rec)
    # The oil column rings at 100-300 Hz, near the sampling rate: low-pass every term of the
    # (linear) equation with the same 20 ms window so that they stay consistent.
    w = max(3, int(round(0.02 / float(np.median(np.diff(t))))))
    a = uniform_filter1d(np.gradient(v, t), w)
    g = G if rig.get("orientation", "vertical") == "vertical" else 0.0
    f_h = uniform_filter1d(rig["area_a_m2"] * _fill_nan(rec.columns["p_a"]) - rig["area_b_m2"] * _fill_nan(rec.columns["p_b"]), w)
    basis = uniform_filter1d(stribeck_basis(v, friction["stribeck_m_s"], SMOOTHING_M_S), w, axis=0)
    # Only accelerations that are smooth on the sampling grid: a velocity step is too fast to
    # resolve and aliases; smooth motion such as sines is what identifies M.
    smooth = np.abs(a - uniform_filter1d(a, 3 * w)) < 0.1 * np.abs(a)
    if smooth.sum() < 10:
        raise RecordError("no smooth accelerating motion in the record (add sines): cannot identify the moving mass")
    sel = smooth & (np.abs(a) > 0.2 * np.percentile(np.abs(a[smooth]), 99))
    if sel.sum() < 10:
        raise RecordError("no smooth accelerating motion in the record (add sines): cannot identify the moving mass")
    # The static part (gravity with the nominal mass, plus any sensor offset) is what the
    # constant-velocity fit's offset term already measured; the mass comes from the dynamics.
    rhs = f_h[sel] - rig["moving_mass_kg"] * g - friction["offset_n"]
    rhs = rhs - basis[sel] @ np.array([friction["viscous_n_s_m"], friction["coulomb_n"], friction["static_n"]])
    m = float(np.sum(a[sel] * rhs) / np.sum(a[sel] ** 2))
    return {"moving_mass_kg": m, "r2": _r2(rhs, m * a[sel]), "samples": int(sel.sum())}


def identify(rec: Record) -> dict:
    """Run the thesis's chapter-3 identification on `rec`; returns a JSON-ready dict."""
    rec, warnings = clean_record(rec)
    warnings += validate_record(rec)
    if "u" not in rec.columns:
        raise RecordError(f"record `{rec.name}` is of a machine that closes its own loop (no valve command `u`): the "
                          "chapter-3 identification fits the valve's velocity gain and needs `u`; `htm diagnose` "
                          "identifies such a record")
    segs = segments(rec)
    out: dict = {"record": rec.name, "warnings": warnings, "segments": len(segs)}
    out["velocity_gain"] = fit_velocity_gain(segs)
    with_p = [s for s in segs if np.isfinite(s.f)]
    if with_p:
        v = np.array([s.v for s in with_p])
        f = np.array([s.f for s in with_p])
        fits = fit_friction(v, f, offset=True)
        no_offset = fit_friction(v, f, offset=False)
        best = fits["stribeck_sig"]["params"]
        area_a = _rig(rec)["area_a_m2"]
        out["friction"] = fits
        out["friction_without_offset"] = no_offset
        out["offset"] = {
            "offset_n": best["offset_n"],
            "as_chamber_a_pressure_pa": best["offset_n"] / area_a,
            "r2_with": fits["stribeck_sig"]["r2"],
            "r2_without": no_offset["stribeck_sig"]["r2"],
        }
        out["mass"] = fit_mass(rec, best)
        out["points"] = {"v_m_s": v.tolist(), "f_n": f.tolist(), "u_v": [s.u for s in with_p]}
    return out

