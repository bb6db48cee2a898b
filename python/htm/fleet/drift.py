"""Drift: a parameter's latest value against the scatter of its own earlier values."""
from __future__ import annotations

from typing import Any

import numpy as np

K_SIGMA = 3.0
MIN_HISTORY = 3  # earlier dates needed before a scatter means anything
# a scatter below this share of the mean is taken as this share (a parameter identified to the
# same digits every time must not flag a rounding change)
MIN_REL_SCATTER = 0.01


def judge(points: list[tuple[str, float]], k_sigma: float = K_SIGMA) -> dict[str, Any]:
    """{"drift": bool | None (None: too little history), "z": deviation of the latest value in units
    of the earlier values' scatter, "mean", "scatter", "latest", "date"}."""
    dates, v = zip(*points)
    vals = np.array(v, float)
    latest, earlier = vals[-1], vals[:-1]
    if len(earlier) < MIN_HISTORY:
        return {"drift": None, "z": None, "mean": float(vals.mean()), "scatter": None, "latest": float(latest), "date": dates[-1]}
    mean = float(earlier.mean())
    scatter = max(float(earlier.std(ddof=1)), MIN_REL_SCATTER * abs(mean), 1e-300)
    z = (latest - mean) / scatter
    return {"drift": bool(abs(z) > k_sigma), "z": float(z), "mean": mean, "scatter": scatter, "latest": float(latest), "date": dates[-1]}


def judge_all(hist: dict[str, list[tuple[str, float]]], k_sigma: float = K_SIGMA) -> dict[str, dict[str, Any]]:
    return {p: judge(pts, k_sigma) for p, pts in hist.items()}
