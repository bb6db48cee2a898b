"""Closing the loop on measured crack growth: fit Paris, look at the residual against ΔK, Kmax and a,
trace systematic structure to the term the law lacks (threshold bend at low ΔK, toughness upturn at
high Kmax), add it, refit, and measure log-rate and life-prediction errors before and after."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from htm.fatigue.data import CrackData, Setup
from htm.fatigue.e647 import Reduced, reduce
from htm.fatigue.laws import Model, Points, fit_life, fit_rate, log_residual, scatter

THRESHOLD_TERM = ("dk_th_mpa",)
TOUGHNESS_TERM = ("k_crit_mpa",)


def binned(x: np.ndarray, r: np.ndarray, bins: int = 10) -> list[dict]:
    """Mean residual in equal-count bins of x."""
    edges = np.quantile(x, np.linspace(0, 1, bins + 1))
    out = []
    for i in range(bins):
        m = (x >= edges[i]) & ((x < edges[i + 1]) if i < bins - 1 else (x <= edges[i + 1]))
        if m.any():
            out.append({"x_mean": float(x[m].mean()), "residual_mean": float(r[m].mean()),
                        "residual_se": float(r[m].std(ddof=1) / math.sqrt(m.sum())) if m.sum() > 1 else float("nan"),
                        "count": int(m.sum())})
    return out


def structure(x: np.ndarray, r: np.ndarray, groups: np.ndarray, window_points: int = 7) -> dict:
    """Systematic structure of residual r against x: F-test of a cubic in standardised x against a
    constant (degrees of freedom deflated by the 2n+1-point window correlation), plus the sign of the
    residual at the low and high ends (outer 10 % of x)."""
    z = (x - x.mean()) / (x.std() or 1.0)
    A = np.column_stack([np.ones_like(z), z, z ** 2, z ** 3])
    coef, *_ = np.linalg.lstsq(A, r, rcond=None)
    rss1 = float(np.sum((r - A @ coef) ** 2))
    rss0 = float(np.sum((r - r.mean()) ** 2))
    n_eff = max(len(r) / window_points, 10)
    f = ((rss0 - rss1) / 3) / (rss1 / (n_eff - 4))
    lo, hi = np.quantile(x, [0.1, 0.9])
    # residual relative to the specimen's own mean removes specimen-to-specimen offsets (scatter in C)
    rc = r.copy()
    for g in np.unique(groups):
        m = groups == g
        rc[m] -= r[m].mean()
    low = float(rc[x <= lo].mean())
    high = float(rc[x >= hi].mean())
    mid = float(rc[(x > lo) & (x < hi)].mean())
    return {"f_statistic": float(f), "effective_points": float(n_eff), "significant": bool(f > 10.0),
            "low_end_mean": low, "mid_mean": mid, "high_end_mean": high,
            "explained_fraction": float(1 - rss1 / rss0) if rss0 > 0 else 0.0,
            "bins": binned(x, r)}


@dataclass
class LoopResult:
    setup: Setup
    reduced: list[Reduced]
    before: Model
    after: Model
    diagnosis: dict
    candidates: list[dict]
    per_specimen: list[dict]
    predictions: list[dict]
    summary: dict = field(default_factory=dict)
    residual_after: dict = field(default_factory=dict)


def diagnose(model: Model, pts: Points, setup: Setup, window_points: int = 7) -> dict:
    """Residual structure of `model` against log ΔK, log Kmax and a."""
    r = log_residual(model, pts, setup.r_ratio)
    out = {
        "delta_k": structure(np.log10(pts.delta_k / 1e6), r, pts.specimen, window_points),
        "kmax": structure(np.log10(pts.kmax / 1e6), r, pts.specimen, window_points),
        "a": structure(pts.a_m * 1e3, r, pts.specimen, window_points),
    }
    # under constant amplitude ΔK, Kmax and a are one-to-one: say so instead of pretending to separate them
    out["collinear"] = bool(abs(np.corrcoef(np.log10(pts.delta_k), np.log10(pts.kmax))[0, 1]) > 0.999)
    s = out["delta_k"]
    noise = 2 * max(b["residual_se"] for b in s["bins"] if np.isfinite(b["residual_se"])) if s["bins"] else 0.0
    missing = []
    if s["significant"] and s["low_end_mean"] < -noise and s["low_end_mean"] < s["mid_mean"]:
        missing.append("threshold")
    if s["significant"] and s["high_end_mean"] > noise and s["high_end_mean"] > s["mid_mean"]:
        missing.append("toughness")
    out["missing_terms"] = missing
    return out


def candidates_for(missing: list[str]) -> list[tuple[str, tuple[str, ...], dict]]:
    """NASGRO variants that add the diagnosed term(s), plus each term alone (BIC chooses)."""
    cands = []
    if "threshold" in missing:
        cands.append(("paris+threshold", ("log10_c", "n") + THRESHOLD_TERM, {"q": 0.0}))
    if "toughness" in missing:
        cands.append(("paris+toughness", ("log10_c", "n") + TOUGHNESS_TERM, {"p": 0.0, "dk_th_mpa": 0.0}))
    if len(missing) == 2:
        cands.append(("paris+threshold+toughness", ("log10_c", "n") + THRESHOLD_TERM + TOUGHNESS_TERM, {}))
    return cands


def _shape_fixed(model: Model) -> dict:
    return {k: v for k, v in model.params.items() if k not in ("log10_c",)}


def _refit_c(model: Model, pts: Points, r_ratio: float) -> Model:
    """Rescale C so the mean log residual over `pts` is zero (C enters multiplicatively)."""
    shift = float(np.mean(log_residual(model, pts, r_ratio)))
    return Model(model.law, {**model.params, "log10_c": model.params["log10_c"] + shift})


def analyse(datas: list[CrackData], setup: Setup, n: int = 3, first_fraction: float = 0.2,
            life_fits: bool = True) -> LoopResult:
    """The whole loop over a set of replicate specimens (see module doc)."""
    reds = [reduce(d, setup, n=n) for d in datas]
    pts = Points.from_reduced(reds)
    w = 2 * n + 1
    r = setup.r_ratio
    before = fit_rate("paris", pts, r, window_points=w)
    diag = diagnose(before, pts, setup, w)
    cands = []
    after = before
    for name, free, fixed in candidates_for(diag["missing_terms"]):
        m = fit_rate("nasgro", pts, r, free=free, fixed=fixed, window_points=w)
        cands.append({"name": name, "model": m, "bic": m.fit["bic"], "rms_log10_rate": m.fit["rms_log10_rate"]})
    if cands:
        best = min(cands, key=lambda c: c["bic"])
        if best["bic"] < before.fit["bic"] - 10:
            after = best["model"]
            best["chosen"] = True
    after_name = next((c["name"] for c in cands if c.get("chosen")), "paris")
    residual_after = diagnose(after, pts, setup, w) if after is not before else diag

    # per specimen: Paris (C, m) vs the chosen law with its shape terms pooled and (C, exponent) own
    shape_terms = tuple(k for k in after.free if k not in ("log10_c", "n", "m"))
    per = []
    by_spec = {rd.specimen: rd for rd in reds}
    for d in datas:
        sp = Points.from_reduced([by_spec[d.specimen]])
        pb = fit_rate("paris", sp, r, window_points=w)
        if after.law == "paris":
            pa = pb
        else:
            fixed = {k: after.params[k] for k in after.params if k not in ("log10_c", "n")}
            pa = fit_rate(after.law, sp, r, free=("log10_c", "n"), fixed=fixed, start=after, window_points=w)
        row = {"specimen": d.specimen, "paris": pb, "after": pa,
               "rms_before": pb.fit["rms_log10_rate"], "rms_after": pa.fit["rms_log10_rate"],
               "measured_life": float(d.cycles[-1] - d.cycles[0])}
        if life_fits:
            lb = fit_life("paris", [d], setup, pb)
            la = fit_life(after.law, [d], setup, pa, free=("log10_c", "n") if after.law != "paris" else None)
            row.update({"paris_life": lb, "after_life": la,
                        "life_rms_before": lb.fit["rms_life_rel"], "life_rms_after": la.fit["rms_life_rel"]})
        per.append(row)

    # prediction from the first `first_fraction` of each specimen's a–N data
    preds = []
    for i, d in enumerate(datas):
        k = max(int(math.ceil(first_fraction * len(d.cycles))), 2 * n + 3)
        early = CrackData(d.specimen, d.cycles[:k], d.a_m[:k])
        ep = Points.from_reduced([reduce(early, setup, n=n)])
        others = Points.from_reduced([rd for j, rd in enumerate(reds) if j != i])
        own_paris = fit_rate("paris", ep, r)
        loo_paris = _refit_c(fit_rate("paris", others, r), ep, r)
        if after.law == "paris":
            loo_after = loo_paris
        else:
            fixed = {kk: vv for kk, vv in after.params.items() if kk not in after.free}
            loo_after = _refit_c(fit_rate(after.law, others, r, free=after.free, fixed=fixed, start=after), ep, r)
        meas = float(d.cycles[-1] - d.cycles[0])
        row = {"specimen": d.specimen, "points_used": k, "a_used_to_mm": float(d.a_m[k - 1] * 1e3),
               "measured_cycles": meas}
        for key, m in (("own_paris", own_paris), ("loo_paris", loo_paris), ("loo_after", loo_after)):
            try:
                life = m.life(setup, float(d.a_m[0]), float(d.a_m[-1]))
                pred = life["cycles"] if not life["fractured"] else float("nan")
            except Exception:  # noqa: BLE001 — a law that cannot grow the crack predicts no life
                pred = float("nan")
            row[key] = pred
            row[key + "_err"] = (pred - meas) / meas
        preds.append(row)

    def rms(v):
        v = np.asarray([x for x in v if np.isfinite(x)])
        return float(np.sqrt(np.mean(v ** 2))) if v.size else float("nan")

    summ = {
        "after_law": after_name,
        "pooled_rms_log10_before": before.fit["rms_log10_rate"],
        "pooled_rms_log10_after": after.fit["rms_log10_rate"],
        "per_specimen_rms_log10_before": rms([p["rms_before"] for p in per]),
        "per_specimen_rms_log10_after": rms([p["rms_after"] for p in per]),
        "prediction_rms_rel_own_paris": rms([p["own_paris_err"] for p in preds]),
        "prediction_rms_rel_loo_paris": rms([p["loo_paris_err"] for p in preds]),
        "prediction_rms_rel_loo_after": rms([p["loo_after_err"] for p in preds]),
        "prediction_mean_abs_rel_own_paris": float(np.nanmean([abs(p["own_paris_err"]) for p in preds])),
        "prediction_mean_abs_rel_loo_paris": float(np.nanmean([abs(p["loo_paris_err"]) for p in preds])),
        "prediction_mean_abs_rel_loo_after": float(np.nanmean([abs(p["loo_after_err"]) for p in preds])),
        "paris_scatter": scatter([p["paris"] for p in per]),
        "after_scatter": scatter([p["after"] for p in per]),
        "shape_terms": list(shape_terms),
    }
    if life_fits:
        summ["life_fit_rms_rel_before"] = rms([p["life_rms_before"] for p in per])
        summ["life_fit_rms_rel_after"] = rms([p["life_rms_after"] for p in per])
    return LoopResult(setup, reds, before, after, diag, cands, per, preds, summ, residual_after)
