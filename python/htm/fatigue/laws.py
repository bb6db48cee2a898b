"""Crack-growth laws fitted to measured data: Paris, Forman, NASGRO, in log-rate space (on reduced
da/dN–ΔK points) and by life (integrating the law and matching N(a)), per specimen and pooled.

Parameters are held in engineering units for conditioning and reading: C in (m/cycle) per
(MPa·√m)^m (Forman: per (MPa·√m)^(m−1)), K-like parameters in MPa·√m. `core_law()` converts to the
SI dictionary the Rust core evaluates (every rate and life in this module comes from the core).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from htm import core
from htm.errors import SpecError
from htm.fatigue.data import CrackData, Setup
from htm.fatigue.e647 import Reduced, fit_paris_points
from htm.inputs import missing, read_text

LAWS = ("paris", "forman", "nasgro")
PARAMS = {
    "paris": ("log10_c", "m"),
    "forman": ("log10_c", "m", "kc_mpa"),
    "nasgro": ("log10_c", "n", "dk_th_mpa", "k_crit_mpa", "p", "q"),
}
#: NASGRO terms a fit holds fixed when it does not fit them: the shape exponents p, q are the
#: fit's prior (typical of aluminium alloys in the NASGRO database); ΔK_th and K_crit are the
#: core's defaults (`htm.core.NASGRO_DEFAULTS`, SI) in MPa·√m.
NASGRO_DEFAULTS = {"p": 0.5, "q": 1.0, "dk_th_mpa": core.NASGRO_DEFAULTS["dk_th"] / 1e6,
                   "k_crit_mpa": core.NASGRO_DEFAULTS["k_crit"] / 1e6}
PENALTY = 5.0  # log10 residual given to a point the law cannot grow (below threshold / beyond fracture)


@dataclass
class Points:
    """Reduced rate points, SI: ΔK and Kmax [Pa·√m], da/dN [m/cycle], crack size [m], specimen label."""

    delta_k: np.ndarray
    kmax: np.ndarray
    dadn: np.ndarray
    a_m: np.ndarray
    specimen: np.ndarray

    @classmethod
    def from_reduced(cls, reds: list[Reduced], only_valid: bool = False) -> Points:
        parts = []
        for rd in reds:
            m = rd.mask(only_valid)
            parts.append((rd.delta_k_pa_sqrt_m[m], rd.kmax_pa_sqrt_m[m], rd.dadn_m_per_cycle[m], rd.a_fit_m[m],
                          np.full(int(m.sum()), rd.specimen, dtype=object)))
        if not parts or sum(len(p[0]) for p in parts) == 0:
            raise SpecError("no usable da/dN points (all rows lack a rate or lie outside the ΔK range)")
        return cls(*(np.concatenate([p[i] for p in parts]) for i in range(5)))

    def __len__(self) -> int:
        return len(self.dadn)


@dataclass
class Model:
    """A growth law with parameter values (engineering units, see module doc)."""

    law: str
    params: dict[str, float]
    se: dict[str, float] = field(default_factory=dict)
    free: tuple[str, ...] = ()
    fit: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.law not in LAWS:
            raise SpecError(f"law `{self.law}` is unknown: use {', '.join(LAWS)}")
        full = dict(NASGRO_DEFAULTS) if self.law == "nasgro" else {}
        full.update(self.params)
        missing = [k for k in PARAMS[self.law] if k not in full]
        if missing:
            raise SpecError(f"{self.law} model lacks parameter(s) {', '.join(missing)}")
        self.params = {k: float(full[k]) for k in PARAMS[self.law]}

    def core_law(self, r_ratio: float) -> dict:
        """SI parameter dict for htm.core (ΔK in Pa·√m)."""
        p = self.params
        c = 10.0 ** p["log10_c"]
        if self.law == "paris":
            return {"law": "paris", "c": c * 1e-6 ** p["m"], "m": p["m"]}
        if self.law == "forman":
            return {"law": "forman", "c": c * 1e6 ** (1 - p["m"]), "m": p["m"], "kc": p["kc_mpa"] * 1e6}
        return {"law": "nasgro", "c": c * 1e-6 ** p["n"], "n": p["n"], "p": p["p"], "q": p["q"],
                "dk_th": p["dk_th_mpa"] * 1e6, "k_crit": p["k_crit_mpa"] * 1e6, "f_open": r_ratio}

    def rate(self, delta_k: np.ndarray, kmax: np.ndarray, r_ratio: float) -> np.ndarray:
        """da/dN [m/cycle] at ΔK, Kmax [Pa·√m]."""
        return core.growth_rate(self.core_law(r_ratio), np.ascontiguousarray(delta_k, float), r_ratio,
                                 np.ascontiguousarray(kmax, float))

    def life_curve(self, setup: Setup, a_m: np.ndarray) -> np.ndarray:
        """N(a_i) − N(a_0) [cycles] for nondecreasing a [m] (inf beyond fracture)."""
        return core.life_curve(self.core_law(setup.r_ratio), setup.geometry, setup.width_m, setup.thickness_m,
                                setup.pmax_n, setup.r_ratio, np.ascontiguousarray(a_m, float))

    def life(self, setup: Setup, a0_m: float, af_m: float) -> dict:
        """Cycles from a0 to af [m]: {"cycles", "a_end_m", "fractured"}."""
        return core.life(self.core_law(setup.r_ratio), setup.geometry, setup.width_m, setup.thickness_m,
                          setup.pmax_n, setup.r_ratio, a0_m, af_m)

    def to_dict(self) -> dict:
        units = {"log10_c": _c_unit(self.law), "m": "-", "n": "-", "p": "-", "q": "-",
                 "kc_mpa": "MPa·√m", "dk_th_mpa": "MPa·√m", "k_crit_mpa": "MPa·√m"}
        return {"law": self.law,
                "parameters": {k: {"value": v, "stderr": self.se.get(k), "unit": units[k], "fitted": k in self.free}
                               for k, v in self.params.items()},
                "fit": self.fit}

    @classmethod
    def from_dict(cls, d: dict, source: str = "model JSON") -> Model:
        """The model of `htm crack fit`'s model.json (`source` names it in errors)."""
        if not isinstance(d, dict):
            raise SpecError(f"{source}: a JSON object with `law` and `parameters` is expected")
        if "family" in d and "params" in d:
            raise SpecError(f"{source} is an identified rig model (`htm diagnose`'s model.json, for `htm predict`), "
                            "not a crack-growth model (`htm crack fit`'s)")
        for key in ("law", "parameters"):
            if key not in d:
                raise SpecError(f"{source}: `{key}` is missing{missing(key, d)}; a crack-growth model.json "
                                "(`htm crack fit`) has `law` and `parameters`")
        if not isinstance(d["parameters"], dict):
            raise SpecError(f"{source}: `parameters` must be an object of parameter values")
        params = {}
        for k, v in d["parameters"].items():
            x = v.get("value") if isinstance(v, dict) else v
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
                raise SpecError(f"{source}: parameter `{k}` = {x!r} is not a finite number")
            params[k] = x
        try:
            return cls(d["law"], params)
        except SpecError as e:
            raise SpecError(f"{source}: {e}") from None


def load_model(path: str | Path) -> Model:
    """Read `htm crack fit`'s model.json (SpecError naming the file and what is wrong)."""
    import json

    text = read_text(path, "crack-growth model (JSON)", SpecError)
    try:
        d = json.loads(text)
    except json.JSONDecodeError as e:
        raise SpecError(f"{path} is not valid JSON: {e}") from None
    return Model.from_dict(d, str(path))


def _c_unit(law: str) -> str:
    return "log10 of (m/cycle)/(MPa·√m)^(m-1)" if law == "forman" else "log10 of (m/cycle)/(MPa·√m)^exponent"


def rms_log_rate(model: Model, pts: Points, r_ratio: float) -> float:
    """RMS of log10(model/measured) da/dN over the points (cannot-grow points get PENALTY)."""
    return float(np.sqrt(np.mean(log_residual(model, pts, r_ratio) ** 2)))


def log_residual(model: Model, pts: Points, r_ratio: float) -> np.ndarray:
    """log10(measured da/dN) − log10(model da/dN) per point."""
    rate = model.rate(pts.delta_k, pts.kmax, r_ratio)
    with np.errstate(divide="ignore", invalid="ignore"):
        res = np.log10(pts.dadn) - np.log10(rate)
    return np.where(np.isfinite(res), res, np.sign(np.nan_to_num(res, nan=1.0)) * PENALTY)


def _bounds(name: str, pts: Points | None, setup_kmax_max: float | None) -> tuple[float, float]:
    dk_min = float(pts.delta_k.min()) / 1e6 if pts is not None else 1.0
    km_max = float(pts.kmax.max()) / 1e6 if pts is not None else (setup_kmax_max or 1.0)
    if setup_kmax_max is not None:
        km_max = max(km_max, setup_kmax_max)
    return {
        "log10_c": (-30.0, 5.0), "m": (0.5, 15.0), "n": (0.5, 15.0), "p": (0.0, 5.0), "q": (0.0, 5.0),
        "kc_mpa": (1.0005 * km_max, 1e4), "k_crit_mpa": (1.0005 * km_max, 1e4), "dk_th_mpa": (0.0, 0.995 * dk_min),
    }[name]


def start_model(law: str, pts: Points, r_ratio: float, free: tuple[str, ...] | None = None,
                fixed: dict | None = None) -> Model:
    """Initial values from a Paris line through the points."""
    pf = fit_paris_points(pts.delta_k, pts.dadn)
    lc, m = np.log10(pf.c_mpa), pf.m
    km_max = float(pts.kmax.max()) / 1e6
    dk_mid = float(np.median(pts.delta_k)) / 1e6
    if law == "paris":
        p = {"log10_c": lc, "m": m}
    elif law == "forman":
        kc = 1.5 * km_max
        p = {"log10_c": lc + np.log10((1 - r_ratio) * kc - dk_mid), "m": m, "kc_mpa": kc}
    else:
        p = dict(NASGRO_DEFAULTS)
        p.update(fixed or {})
        free = free or default_free(law)
        if "dk_th_mpa" in free:
            p["dk_th_mpa"] = 0.3 * float(pts.delta_k.min()) / 1e6
        if "k_crit_mpa" in free:
            p["k_crit_mpa"] = 2.0 * km_max
        th = (1 - p["dk_th_mpa"] / dk_mid) ** p["p"] if p["dk_th_mpa"] > 0 else 1.0
        fr = (1 - dk_mid / (1 - r_ratio) / p["k_crit_mpa"]) ** p["q"]
        p.update({"log10_c": lc - np.log10(th / fr), "n": m})
    if fixed:
        p.update(fixed)
    return Model(law, p)


def default_free(law: str) -> tuple[str, ...]:
    return {"paris": ("log10_c", "m"), "forman": ("log10_c", "m", "kc_mpa"),
            "nasgro": ("log10_c", "n", "dk_th_mpa", "k_crit_mpa")}[law]


def _solve(model: Model, free: tuple[str, ...], residual, pts: Points | None, kmax_max: float | None) -> tuple[Model, np.ndarray, object]:
    lo, hi = zip(*(_bounds(k, pts, kmax_max) for k in free))
    x0 = np.clip([model.params[k] for k in free], np.array(lo) + 1e-9 * np.abs(lo), np.array(hi) - 1e-9 * np.abs(hi))

    def make(x: np.ndarray) -> Model:
        p = dict(model.params)
        p.update(dict(zip(free, x)))
        return Model(model.law, p)

    sol = least_squares(lambda x: residual(make(x)), x0, bounds=(lo, hi), x_scale="jac", method="trf",
                        xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=400)
    return make(sol.x), sol.x, sol


def _stderr(sol, nres: int, nfree: int, free: tuple[str, ...], inflate: float = 1.0) -> dict[str, float]:
    dof = max(nres - nfree, 1)
    s2 = 2 * sol.cost / dof
    try:
        cov = np.linalg.pinv(sol.jac.T @ sol.jac) * s2 * inflate
        return {k: float(np.sqrt(max(cov[i, i], 0.0))) for i, k in enumerate(free)}
    except np.linalg.LinAlgError:
        return {k: float("nan") for k in free}


def fit_rate(law: str, pts: Points, r_ratio: float, free: tuple[str, ...] | None = None,
             fixed: dict | None = None, start: Model | None = None, window_points: int = 1) -> Model:
    """Least squares in log10 da/dN over the points. `free` names the fitted parameters (defaults:
    Paris C, m; Forman C, m, K_c; NASGRO C, n, ΔK_th, K_crit with p, q fixed); `fixed` sets others.
    `window_points` (2n+1 of the incremental polynomial) inflates the standard errors for the
    correlation between neighbouring reduced points."""
    free = tuple(free or default_free(law))
    model = start or start_model(law, pts, r_ratio, free, fixed)
    if fixed:
        model = Model(law, {**model.params, **fixed})
    bad = [k for k in free if k not in PARAMS[law]]
    if bad:
        raise SpecError(f"{law} has no parameter(s) {', '.join(bad)}: choose from {', '.join(PARAMS[law])}")
    if len(pts) <= len(free):
        raise SpecError(f"fitting {law} needs more than {len(free)} da/dN points, got {len(pts)}")
    fitted, x, sol = _solve(model, free, lambda m: log_residual(m, pts, r_ratio), pts, None)
    res = log_residual(fitted, pts, r_ratio)
    rss = float(res @ res)
    npts = len(pts)
    fitted.se = _stderr(sol, npts, len(free), free, inflate=window_points)
    fitted.free = free
    fitted.fit = {"method": "log_rate", "npoints": npts, "rms_log10_rate": float(np.sqrt(rss / npts)),
                  "bic": float(npts * np.log(rss / npts) + len(free) * np.log(npts))}
    return fitted


def _life_residual(model: Model, datas: list[CrackData], setup: Setup) -> np.ndarray:
    """Per point (N_model(a) + offset − N)/span with each specimen's offset solved in closed form."""
    out = []
    for d in datas:
        curve = model.life_curve(setup, d.a_m)
        span = float(d.cycles[-1] - d.cycles[0]) or 1.0
        if not np.all(np.isfinite(curve)):
            fin = np.isfinite(curve)
            curve = np.where(fin, curve, (curve[fin].max() if fin.any() else 0.0) + 10 * span)
        off = float(np.mean(d.cycles - curve))
        out.append((curve + off - d.cycles) / span)
    return np.concatenate(out)


def fit_life(law: str, datas: list[CrackData], setup: Setup, start: Model,
             free: tuple[str, ...] | None = None) -> Model:
    """Fit by life: integrate the law over each specimen's measured a and match N(a) (relative to
    each specimen's span, with a free cycle offset per specimen); pooled over `datas`."""
    free = tuple(free or start.free or default_free(law))
    a_all = np.concatenate([d.a_m for d in datas])
    kmax_max = float(setup.kmax(np.array([a_all.max()]))[0]) / 1e6
    dk_min = float(setup.delta_k(np.array([a_all.min()]))[0]) / 1e6
    pts = Points(np.array([dk_min * 1e6]), np.array([kmax_max * 1e6]), np.array([1.0]), np.array([0.0]), np.array([""]))
    fitted, x, sol = _solve(start, free, lambda m: _life_residual(m, datas, setup), pts, kmax_max)
    res = _life_residual(fitted, datas, setup)
    fitted.se = _stderr(sol, len(res), len(free), free)
    fitted.free = free
    fitted.fit = {"method": "life", "npoints": int(len(res)), "rms_life_rel": float(np.sqrt(np.mean(res ** 2))),
                  "max_life_rel": float(np.max(np.abs(res)))}
    return fitted


def life_errors(model: Model, data: CrackData, setup: Setup) -> dict:
    """Life prediction from the first point: N_pred(a_i) = N_0 + ∫ dN; errors relative to the
    measured span N_last − N_0 (RMS over points, and at the last point)."""
    curve = model.life_curve(setup, data.a_m)
    span = float(data.cycles[-1] - data.cycles[0])
    pred = data.cycles[0] + curve
    rel = (pred - data.cycles) / span
    rel = np.where(np.isfinite(rel), rel, np.nan)
    return {"rms_rel": float(np.sqrt(np.nanmean(rel ** 2))), "final_rel": float(rel[-1]),
            "predicted_final_cycles": float(pred[-1]), "measured_final_cycles": float(data.cycles[-1])}


def scatter(models: list[Model]) -> dict:
    """Mean, standard deviation and coefficient of variation of each parameter across specimens;
    plus the correlation of log10 C with the exponent (the known C–m coupling)."""
    out: dict = {}
    keys = models[0].params.keys()
    for k in keys:
        v = np.array([m.params[k] for m in models])
        out[k] = {"mean": float(v.mean()), "std": float(v.std(ddof=1)) if len(v) > 1 else 0.0,
                  "cv": float(v.std(ddof=1) / abs(v.mean())) if len(v) > 1 and v.mean() != 0 else float("nan"),
                  "min": float(v.min()), "max": float(v.max())}
    expo = "m" if "m" in keys else "n"
    if len(models) > 2:
        c = np.array([m.params["log10_c"] for m in models])
        e = np.array([m.params[expo] for m in models])
        out["corr_log10_c_exponent"] = float(np.corrcoef(c, e)[0, 1])
    return out
