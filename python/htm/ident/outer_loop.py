"""Identify a machine's closed displacement loop from command, position and load (no valve data).

For records of a vendor controller whose inner loop is unknown: only the position command
`y_ref`, the measured position `y` and the load force `f` exist. The model is the Rust
`outer_loop` model (a first-order loop with transport delay, plus optional effects); this module
fits it, finds what its residual correlates with, adds the effects that pay off on held-out
blocks of the records, and reports the error before and after.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, signal

from htm import _core
from htm.errors import RecordError

# baseline parameters and candidate effects: name -> (EFFECTS.md id or own id, params, scale, bounds)
BASE = {"gain": (1.0, (0.5, 2.0)), "bandwidth_hz": (5.0, (0.05, 500.0)), "delay_s": (0.0, (0.0, 0.2)), "offset_m": (0.0, (-0.05, 0.05))}
CANDIDATES = {
    # the specimen's force loading the actuator: valve flow falls with load pressure
    "load_pressure_feedback": {"load_m_s_per_n": (0.0, (-1e-3, 1e-3))},
    # extension and retraction move at different speeds for the same error (own id, not in EFFECTS.md)
    "direction_asymmetry": {"asymmetry": (0.0, (-0.9, 0.9))},
    # Coulomb friction of the actuator itself (not seen by the load cell) or a valve overlap (own id)
    "actuator_friction": {"friction_m_s": (1e-4, (0.0, 0.05))},
    # a first-order valve lag inside the loop (EFFECTS.md valve_dynamics; reported as tau_s)
    "valve_dynamics": {"valve_bandwidth_hz": (200.0, (1.0, 2000.0))},
}
# final RMSE above this multiple of the noise floor = systematic structure left
UNEXPLAINED_RATIO = 1.25

EVIDENCE = {
    "load_pressure_feedback": "residual correlates with the measured load force f",
    "direction_asymmetry": "residual differs between extension and retraction (its mean follows the motion's amplitude)",
    "actuator_friction": "residual steps with the direction of motion where the load cell shows no matching force: friction of the actuator's own seals, or a valve overlap (the two look alike without pressures)",
    "valve_dynamics": "residual leads the error by a fraction of a period at the higher frequencies",
}


@dataclass
class LoopRecord:
    """One outer-loop record: command `y_ref` [m], measured position `y` [m], load `f` [N],
    sampled every `dt` [s]; `active` marks the samples that count (e.g. the chirp)."""

    name: str
    y_ref: np.ndarray
    y: np.ndarray
    f: np.ndarray
    dt: float
    active: np.ndarray = field(default=None)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        for k in ("y_ref", "y", "f"):
            setattr(self, k, np.ascontiguousarray(getattr(self, k), dtype=float))
        n = len(self.y)
        if n < 50:
            raise RecordError(f"record `{self.name}`: {n} samples; need at least 50 to identify a loop")
        for k in ("y_ref", "f"):
            if len(getattr(self, k)) != n:
                raise RecordError(f"record `{self.name}`: column {k} has {len(getattr(self, k))} samples, y has {n}")
        for k in ("y_ref", "y", "f"):
            x = getattr(self, k)
            if not np.all(np.isfinite(x)):
                raise RecordError(f"record `{self.name}`: column {k} has NaN samples; fill or cut them first")
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise RecordError(f"record `{self.name}`: sample period {self.dt} s must be > 0")
        if self.active is None:
            self.active = np.ones(n, bool)
        if np.ptp(self.y_ref[self.active]) <= 0:
            raise RecordError(f"record `{self.name}`: the command is constant; nothing to identify from")


def simulate(params: dict[str, float], rec: LoopRecord) -> np.ndarray:
    """Model position [m] at every sample of `rec`."""
    return _core.outer_loop_simulate(params, rec.y_ref, rec.f, rec.dt)


def noise_floor(rec: LoopRecord) -> float:
    """Position noise [m]: rms of the high-pass (> fs/8) part of y, where the loop passes no signal."""
    b, a = signal.butter(4, 0.25, "highpass")
    hp = signal.filtfilt(b, a, rec.y)
    # white noise keeps 3/4 of its power above fs/8: scale back to the full band
    return float(np.std(hp[rec.active]) / np.sqrt(0.75))


def blocks(rec: LoopRecord, block_s: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Interleaved fit/validation masks over the active samples: alternate blocks of `block_s`."""
    k = (np.arange(len(rec.y)) * rec.dt // block_s).astype(int)
    return rec.active & (k % 2 == 0), rec.active & (k % 2 == 1)


def rmse(params: dict[str, float], rec: LoopRecord, mask: np.ndarray | None = None) -> float:
    m = rec.active if mask is None else mask
    return float(np.sqrt(np.mean((simulate(params, rec) - rec.y)[m] ** 2)))


def _spec(effects: list[str]) -> dict[str, tuple[float, tuple[float, float]]]:
    spec = dict(BASE)
    for e in effects:
        spec.update(CANDIDATES[e])
    return spec


def fit(recs: list[LoopRecord], effects: list[str] = (), *, start: dict[str, float] | None = None,
        masks: list[np.ndarray] | None = None) -> dict[str, float]:
    """Least-squares fit of the baseline plus `effects` to `recs` jointly (simulation error over
    `masks`, default each record's active samples, each record weighted by its noise floor)."""
    spec = _spec(list(effects))
    names = list(spec)
    start = dict(start or {})
    x0 = np.array([start.get(n, spec[n][0]) for n in names], float)
    lo = np.array([spec[n][1][0] for n in names])
    hi = np.array([spec[n][1][1] for n in names])
    x0 = np.clip(x0, lo + 1e-12 * (hi - lo), hi - 1e-12 * (hi - lo))
    scale = np.maximum(np.abs(x0), (hi - lo) * 1e-3)
    masks = masks or [r.active for r in recs]
    sigma = [max(noise_floor(r), 1e-9) for r in recs]

    def resid(z: np.ndarray) -> np.ndarray:
        p = dict(zip(names, z * scale))
        try:
            return np.concatenate([((simulate(p, r) - r.y) / s)[m] for r, s, m in zip(recs, sigma, masks)])
        except _core.HtmError:
            return np.full(sum(int(m.sum()) for m in masks), 1e3)

    sol = optimize.least_squares(resid, x0 / scale, bounds=(lo / scale, hi / scale), x_scale="jac", diff_step=1e-4)
    return dict(zip(names, sol.x * scale))


def features(params: dict[str, float], rec: LoopRecord) -> dict[str, float]:
    """Share [0..1] of the low-passed residual's variance each candidate feature explains."""
    r = rec.y - simulate(params, rec)
    b, a = signal.butter(2, min(0.99, 80.0 * 2 * rec.dt))
    rs = signal.filtfilt(b, a, r)
    ys = signal.filtfilt(b, a, rec.y)
    v = np.gradient(ys, rec.dt)
    e = params.get("gain", 1.0) * rec.y_ref - ys
    feats = {
        "load_pressure_feedback": rec.f,
        "direction_asymmetry": np.abs(e),
        "actuator_friction": np.sign(v),
        "valve_dynamics": np.gradient(v, rec.dt),
    }
    m = rec.active
    out = {}
    for k, x in feats.items():
        # the loop integrates velocity errors: regress on the feature and its running integral
        xi = np.cumsum(x - x[m].mean()) * rec.dt
        A = np.column_stack([x[m], xi[m] - xi[m].mean(), np.ones(m.sum())])
        coef, *_ = np.linalg.lstsq(A, rs[m], rcond=None)
        out[k] = float(max(0.0, 1 - np.var(rs[m] - A @ coef) / np.var(rs[m])))
    return out


def bic(params: dict[str, float], recs: list[LoopRecord], masks: list[np.ndarray], k: int) -> float:
    """Bayesian information criterion of the noise-normalised residual on `masks` (k parameters)."""
    rss, n = 0.0, 0
    for r, m in zip(recs, masks):
        e = (simulate(params, r) - r.y)[m] / max(noise_floor(r), 1e-9)
        rss += float(e @ e)
        n += int(m.sum())
    return n * np.log(rss / n) + k * np.log(n)


def search(recs: list[LoopRecord], baseline: dict[str, float], *, min_gain: float = 0.01,
           max_effects: int = 6) -> tuple[list[dict], list[list[dict]]]:
    """Greedy effect search: refit with each candidate on the fit blocks of all records, keep the
    one that lowers BIC on the validation blocks most and cuts the validation error by at least
    `min_gain`; repeat. Returns (findings in the order they were added, every round's trials with
    their validation figures and per-record RMSE — the evidence for what was not kept)."""
    fit_masks, val_masks = (list(x) for x in zip(*(blocks(r) for r in recs)))

    def val_rmse(p: dict[str, float]) -> float:
        return float(np.sqrt(np.mean([rmse(p, r, m) ** 2 for r, m in zip(recs, val_masks)])))

    current, effects, findings = dict(baseline), [], []
    base_bic = bic(current, recs, val_masks, len(current))
    rounds: list[list[dict]] = []
    while len(effects) < max_effects:
        trials = []
        for cand in CANDIDATES:
            if cand in effects:
                continue
            p = fit(recs, effects + [cand], start=current, masks=fit_masks)
            trials.append((bic(p, recs, val_masks, len(p)), cand, p))
        if not trials:
            break
        before = val_rmse(current)
        trials.sort(key=lambda t: t[0])
        rounds.append([{"effect": c, "params": {k: p[k] for k in CANDIDATES[c]}, "delta_bic": float(b - base_bic),
                        "validation_rmse_before": before, "validation_rmse_after": val_rmse(p),
                        "rmse_before": {r.name: rmse(current, r) for r in recs}, "rmse_after": {r.name: rmse(p, r) for r in recs}}
                       for b, c, p in trials])
        b, cand, p = trials[0]
        if not (b < base_bic - 10.0 and val_rmse(p) < (1 - min_gain) * before):
            break
        findings.append({
            "effect": cand,
            "params": {k: p[k] for k in CANDIDATES[cand]},
            "rmse_before": {r.name: rmse(current, r) for r in recs},
            "rmse_after": {r.name: rmse(p, r) for r in recs},
            "validation_rmse_before": before,
            "validation_rmse_after": val_rmse(p),
            "delta_bic": float(b - base_bic),
            "feature_share": {r.name: features(current, r).get(cand, 0.0) for r in recs},
            "evidence": EVIDENCE[cand],
        })
        effects.append(cand)
        current, base_bic = p, b
    return findings, rounds


def finalize(params: dict[str, float]) -> dict[str, float]:
    """Parameters as reported: valve bandwidth also as the EFFECTS.md `tau_s`."""
    out = dict(params)
    if out.get("valve_bandwidth_hz", 0.0) > 0:
        out["tau_s"] = 1.0 / (2 * np.pi * out["valve_bandwidth_hz"])
    return out
