"""What a fitted model can be expected to miss, and the verdict on structure left unexplained.

Two yardsticks stand between a residual and the word "unexplained":

* the model's own floor: the residual the fitted model leaves on a synthetic record of itself
  (its prediction with the record's noise and quantization), which holds what the fit's
  re-starts from noisy measurements cost, and for a free-running closed loop what it costs that
  a free run cannot follow the record's particular hunt on its sensor noise;
* the model's form: a real rig is never exactly the model's structure (its spool, lines,
  friction and orifices differ in shape). What a linear dynamic map of the model's own signals
  (its predicted states, the command, their rates, at a few lags) removes from the residual is
  such a form error of the model, not an effect the model lacks; structure that no such map
  reproduces — a force over part of the stroke, a pump's ripple, a cushion at an end — is.
"""
from __future__ import annotations

import numpy as np

from htm.ident import features as ft
from htm.ident.dsp import first_order_lag
from htm.ident.fit import Problem, side_by_side
from htm.ident.model import Model
from htm.ident.settings import DEFAULT, SearchSettings

# The knobs live in `settings.SearchSettings` (unexplained, margin, gross, form_lags_s, form_ridge,
# floor_realisations: unit and reason there); these names are its defaults.
UNEXPLAINED = DEFAULT.unexplained
MARGIN = DEFAULT.margin
GROSS = DEFAULT.gross
REALISATIONS = DEFAULT.floor_realisations
# The seed of the synthetic records (fixed: the same record gets the same verdict).
SEED = 20261121
FORM_LAGS_S = DEFAULT.form_lags_s
FORM_RIDGE = DEFAULT.form_ridge


def own_floor(prob: Problem, model: Model, pred: dict[str, np.ndarray], rate: float,
              quantum: dict[str, float]) -> dict[str, float]:
    """Per channel: the systematic ratio of the residual `model` leaves on synthetic records of
    itself — its whole-record prediction `pred` with white noise at the record's floors and
    the sensors' quantization — predicted the way the record is (same restarts, same loop)."""
    rng = np.random.default_rng(SEED)
    n = len(prob.rec.columns["t"])
    out = {c: 0.0 for c in prob.channels}
    syns = []
    for _ in range(prob.settings.floor_realisations):
        cols = dict(prob.rec.columns)
        for c in prob.channels:
            x = np.asarray(pred[c], dtype=float) + rng.normal(0.0, prob.sigma[c], n)
            q = quantum.get(c) or 0.0
            cols[c] = np.round(x / q) * q if q > 0 else x
        syns.append(Problem(type(prob.rec)(cols, prob.rec.meta, prob.rec.name), prob.simulate, prob.channels, prob.sigma,
                            prob.n_work, prob.fit_mask, prob.val_mask, prob.opts, prob.sparse, settings=prob.settings))
    # each synthetic record is its own simulation: side by side
    agains = side_by_side([lambda syn=syn: syn.predict([model.params()], whole=True)[0] for syn in syns])
    for syn, again in zip(syns, agains):
        prob.simulations += 1
        for c in prob.channels:
            out[c] = max(out[c], ft.systematic_ratio(np.asarray(again[c]) - syn.meas[c], prob.sigma[c], rate))
    return out


def loop_floor(prob: Problem, model: Model, clean: dict[str, np.ndarray], rate: float,
               quantum: dict[str, float]) -> dict[str, float]:
    """Per channel: how far a free run of the closed loop `model` (`clean`: its whole-record
    free run) can be from a record of itself — the model run with white noise at the record's
    floors and its sensors' quantization inside the loop, against the noise-free run. Near the
    white-noise level for a well-behaved loop; far above it when the loop hunts on its sensor
    noise (play), where no free run can follow one particular hunt."""
    n = len(prob.rec.columns["t"])
    p = model.params()
    rng = np.random.default_rng(SEED)
    out = {c: 0.0 for c in prob.channels}
    for _ in range(prob.settings.floor_realisations):
        noise = {c: rng.normal(0.0, prob.sigma[c], n) for c in prob.channels}
        syn = prob.predict([p], whole=True, noise=noise, quantum=quantum)[0]
        for c in prob.channels:
            out[c] = max(out[c], ft.systematic_ratio(clean[c] - np.asarray(syn[c], dtype=float), prob.sigma[c], rate))
    return out


def form_regressors(prob: Problem, pred: dict[str, np.ndarray], rate: float) -> np.ndarray:
    """The model's own signals a form error would follow: its predicted readings (position only
    through its rate: the actuator is the same all along its stroke), the command or reference,
    their rates, the direction of motion, each at a few first-order lags; plus a constant."""
    cols = prob.rec.columns
    dt = 1.0 / rate
    base: list[np.ndarray] = []
    for c in prob.channels:
        x = np.nan_to_num(np.asarray(pred[c], dtype=float))
        if c != "y":
            base.append(x)
        base.append(np.gradient(x, dt))
    for c in ("u", "y_ref", "f_ref"):
        if c in cols:
            x = np.nan_to_num(np.asarray(cols[c], dtype=float))
            base += [x, np.gradient(x, dt)]
    if "v" in pred or "y" in pred:
        v = np.asarray(pred["v"], dtype=float) if "v" in pred else np.gradient(np.asarray(pred["y"], dtype=float), dt)
        v = np.nan_to_num(v)
        base.append(np.tanh(v / max(1e-9, 0.05 * float(np.std(v)))))
    feats = [np.ones(len(base[0]))]
    for x in base:
        s = float(np.std(x))
        if s <= 0:
            continue
        z = (x - float(np.mean(x))) / s
        feats.append(z)
        for tau in prob.settings.form_lags_s:
            feats.append(first_order_lag(z, float(np.exp(-dt / tau))))
    return np.column_stack(feats)


def form_ratios(prob: Problem, pred: dict[str, np.ndarray], rate: float) -> dict[str, float]:
    """Per channel: the systematic ratio of the whole-record residual after the part a linear
    map of the model's own signals reproduces (fitted on the fit samples, judged on the held-out
    ones) is taken out."""
    X = form_regressors(prob, pred, rate)
    fit = np.zeros(len(X), bool)
    fit[: len(prob.fit_mask)] = prob.fit_mask
    out = {}
    for c in prob.channels:
        r = np.asarray(pred[c], dtype=float) - prob.meas[c]
        ok = np.isfinite(r)
        sel = fit & ok
        if sel.sum() <= X.shape[1] * 3:
            out[c] = ft.systematic_ratio(r, prob.sigma[c], rate)
            continue
        # ridge: the lags are nearly collinear and must not extrapolate to the held-out samples
        a = X[sel]
        coef = np.linalg.solve(a.T @ a + prob.settings.form_ridge * len(a) * np.eye(a.shape[1]), a.T @ r[sel])
        left = np.where(ok, r - X @ coef, np.nan)
        held = prob.val_mask & ok
        out[c] = ft.systematic_ratio(np.where(held, left, np.nan), prob.sigma[c], rate)
    return out


def unexplained(ratios: dict[str, float], floor: dict[str, float], margin: float = 1.0,
                settings: SearchSettings = DEFAULT) -> list[str]:
    """The channels whose structure is left unexplained: above `settings.unexplained` and above
    `settings.margin` times the model's own floor (both times `margin`)."""
    return [c for c, r in ratios.items() if r > margin * max(settings.unexplained, settings.margin * floor.get(c, 0.0))]
