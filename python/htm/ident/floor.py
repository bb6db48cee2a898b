"""What a fitted model can be expected to miss: the free run's own spread when sensor noise acts
inside a closed loop (the loop floor), and the verdict on structure left unexplained."""
from __future__ import annotations

import numpy as np

from htm.ident import features as ft
from htm.ident.fit import Problem
from htm.ident.model import Model

# Structure is reported unexplained above this systematic ratio (a clear margin over the search's
# stopping point, search.SYSTEMATIC).
UNEXPLAINED = 1.5
# The free run's own spread (`loop_floor`): synthetic records of the fitted model, their seed,
# and the margin above the largest spread beyond which structure counts as unexplained.
LOOP_REALISATIONS, LOOP_SEED, LOOP_MARGIN = 3, 20261121, 3.0


def loop_floor(prob: Problem, model: Model, clean: dict[str, np.ndarray], rate: float,
               quantum: dict[str, float]) -> dict[str, float]:
    """Per channel: how far a free run of `model` (`clean`: its whole-record prediction) can be
    from a record of itself, as a systematic ratio — the largest over `LOOP_REALISATIONS`
    synthetic records (the model's run with white noise at the record's floors and its sensors'
    quantization inside the loop) against the noise-free run. Near the white-noise level for a
    well-behaved loop; far above it when the loop hunts on its sensor noise (play), where no free
    run can follow one particular hunt."""
    n = len(prob.rec.columns["t"])
    p = model.params()
    rng = np.random.default_rng(LOOP_SEED)
    out = {c: 0.0 for c in prob.channels}
    for _ in range(LOOP_REALISATIONS):
        noise = {c: rng.normal(0.0, prob.sigma[c], n) for c in prob.channels}
        syn = prob.predict([p], whole=True, noise=noise, quantum=quantum)[0]
        for c in prob.channels:
            out[c] = max(out[c], ft.systematic_ratio(clean[c] - np.asarray(syn[c], dtype=float), prob.sigma[c], rate))
    return out


def unexplained(prob: Problem, pred: dict[str, np.ndarray], floor: dict[str, float], rate: float) -> bool:
    """Systematic structure left: some channel's residual above UNEXPLAINED and above what the
    model's own free run varies by (`LOOP_MARGIN` x its loop floor)."""
    ratios = prob.ratios(pred, rate)
    return any(r > max(UNEXPLAINED, LOOP_MARGIN * floor[c]) for c, r in ratios.items())
