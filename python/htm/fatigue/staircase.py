"""Staircase (up-and-down) tests, ISO 12107 / Dixon–Mood: the fatigue strength at the run-out
life and its scatter from a sequence of failures and run-outs on equally spaced stress levels.

Each specimen is tested at one level; after a failure the next goes one step down, after a
run-out one step up. The estimate counts the less frequent outcome on each level.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from htm.errors import SpecError
from htm.fatigue.sn import read_columns


@dataclass
class Staircase:
    """The estimate: fatigue strength [Pa] (50 %), its standard deviation [Pa], and how it was made."""

    strength_pa: float
    sd_pa: float
    step_pa: float
    event: str  # "failures" or "runouts": the less frequent outcome, the one counted
    n_specimens: int
    n_used: int
    ratio: float  # (F·B − A²)/F²
    sd_rule: str
    levels: list[dict[str, Any]]

    def to_json(self) -> dict[str, Any]:
        return {"method": "staircase_dixon_mood_iso12107", "fatigue_strength_pa": self.strength_pa,
                "sd_pa": self.sd_pa, "step_pa": self.step_pa, "event_counted": self.event,
                "n_specimens": self.n_specimens, "n_used": self.n_used, "ratio_FB_minus_A2_over_F2": self.ratio,
                "sd_rule": self.sd_rule, "levels": self.levels}


def read_staircase(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """A staircase result file in test order: `stress_amplitude_pa` [Pa] and `runout` (0/1);
    `cycles` may be there and is not used."""
    c = read_columns(path, ("stress_amplitude_pa", "runout"), flags=("runout",), positive=("stress_amplitude_pa",))
    return c["stress_amplitude_pa"], c["runout"]


def infer_step(stress_pa: np.ndarray, source: str = "staircase") -> float:
    """The staircase's step [Pa]: the smallest spacing of its levels, checked to divide every other."""
    lv = np.unique(np.round(stress_pa, 3))
    if len(lv) < 2:
        raise SpecError(f"{source}: all specimens were tested on one level; give --step-pa")
    d = float(np.min(np.diff(lv)))
    k = (lv - lv[0]) / d
    if np.any(np.abs(k - np.round(k)) > 0.02):
        raise SpecError(f"{source}: the levels {', '.join(f'{v / 1e6:g}' for v in lv)} MPa are not equally spaced; give --step-pa")
    return d


def dixon_mood(stress_pa: np.ndarray, runout: np.ndarray, step_pa: float | None = None, source: str = "staircase") -> Staircase:
    """ISO 12107's estimate. The specimens before the first change of outcome are dropped except the
    last of them. With i the level index above the lowest level of the counted event, F = Σnᵢ,
    A = Σi·nᵢ, B = Σi²·nᵢ: strength = S₀ + d(A/F ∓ ½) (− for failures, + for run-outs);
    sd = 1.62·d·((F·B − A²)/F² + 0.029) when that ratio is ≥ 0.3, else 0.53·d (ISO 12107)."""
    s, ro = np.asarray(stress_pa, float), np.asarray(runout, bool)
    if len(s) < 3:
        raise SpecError(f"{source}: {len(s)} specimens; a staircase needs at least 3")
    if ro.all() or (~ro).all():
        what = "run-outs" if ro.all() else "failures"
        raise SpecError(f"{source}: all {len(s)} specimens are {what}: the staircase never crossed the fatigue strength")
    if step_pa is not None and not step_pa > 0:
        raise SpecError(f"--step-pa = {step_pa}: the step must be a positive stress [Pa]")
    d = float(step_pa) if step_pa else infer_step(s, source)
    change = int(np.argmax(ro != ro[0]))
    keep = slice(max(change - 1, 0), None)
    s_u, ro_u = s[keep], ro[keep]
    n_f, n_r = int((~ro_u).sum()), int(ro_u.sum())
    use_fail = n_f <= n_r
    ev = ~ro_u if use_fail else ro_u
    s0 = float(s_u[ev].min())
    i = np.round((s_u[ev] - s0) / d).astype(int)
    n_i = np.bincount(i)
    idx = np.arange(len(n_i))
    F, A, B = float(n_i.sum()), float((idx * n_i).sum()), float((idx * idx * n_i).sum())
    mean = s0 + d * (A / F + (-0.5 if use_fail else 0.5))
    ratio = (F * B - A * A) / (F * F)
    if ratio >= 0.3:
        sd, rule = 1.62 * d * (ratio + 0.029), "1.62·d·(ratio + 0.029)"
    else:
        sd, rule = 0.53 * d, "0.53·d (ratio < 0.3)"
    levels = []
    for lv in np.unique(np.round(s, 3)):
        at = np.isclose(s, lv, rtol=0, atol=1e-3)
        levels.append({"stress_pa": float(lv), "failures": int((at & ~ro).sum()), "runouts": int((at & ro).sum())})
    return Staircase(float(mean), float(sd), d, "failures" if use_fail else "runouts", len(s), len(s_u), float(ratio), rule, levels)


def simulate_staircase(mean_pa: float, sd_pa: float, start_pa: float, step_pa: float, n: int,
                       rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A staircase on specimens whose fatigue strength is Normal(mean, sd) [Pa]: each fails (before
    the run-out life) when tested above its own strength. Returns (levels, run-out flags) in order."""
    s = start_pa
    levels, ro = [], []
    for _ in range(n):
        strength = mean_pa + sd_pa * rng.standard_normal()
        r = strength >= s
        levels.append(s)
        ro.append(bool(r))
        s = s + step_pa if r else s - step_pa
        if not math.isfinite(s) or s <= 0:
            raise SpecError("staircase: the level went to zero; the step is too large for the start level")
    return np.array(levels), np.array(ro)
