"""Strain-life (ε-N, ASTM E606 / ISO 12106) from strain-controlled tests: Basquin + Coffin–Manson,
εa = σ'f/E·(2N)^b + ε'f·(2N)^c, and the cyclic stress–strain curve σa = K'·(εpa)^n' from each
test's stabilised loop (stress amplitude σa, plastic strain amplitude εpa = εa − σa/E).

Basquin and Coffin–Manson are fitted as E739 says, life 2N (reversals) the dependent variable, then
solved for the amplitude; the cyclic curve is σa on εpa; 90 % t intervals. The
life band is a prediction band for a new specimen: the scatter of log10 life about the total-strain
curve together with the fitted parameters' uncertainty (delta method), t with n − 4 degrees of freedom.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import optimize, stats

from htm.errors import RecordError, SpecError
from htm.fatigue.sn import LEVEL, read_columns

EN_REQUIRED = ("strain_amplitude", "cycles")
EN_OPTIONAL = ("stress_amplitude_pa", "plastic_strain_amplitude", "runout")


@dataclass
class Line:
    """log10 y = p + q·log10 x with 90 % intervals; cov of (p, q), residual sd, dof."""

    p: float
    q: float
    p_ci90: tuple[float, float]
    q_ci90: tuple[float, float]
    cov: np.ndarray
    s: float
    dof: int
    n: int


def life_line(life: np.ndarray, y: np.ndarray) -> Line:
    """log10 y = p + q·log10 life fitted as E739 does, with life the dependent variable (log10 life
    on log10 y), then solved for y: q = 1/β, p = −α/β; the interval of q is the t interval of β
    mapped (exact), that of p by the delta method."""
    inv = loglog_line(y, life)  # log10 life = α + β·log10 y
    alpha, beta = inv.p, inv.q
    if beta == 0:
        raise SpecError("strain-life: the lives do not change with the amplitude (zero slope)")
    q, p = 1 / beta, -alpha / beta
    g = np.array([[-1 / beta, alpha / beta ** 2], [0.0, -1 / beta ** 2]])  # d(p, q)/d(α, β)
    cov = g @ inv.cov @ g.T
    t = float(stats.t.ppf(0.5 + LEVEL / 2, inv.dof))
    sp = math.sqrt(cov[0, 0])
    qs = sorted((1 / inv.q_ci90[0], 1 / inv.q_ci90[1])) if inv.q_ci90[0] * inv.q_ci90[1] > 0 else [-math.inf, math.inf]
    return Line(p, q, (p - t * sp, p + t * sp), (qs[0], qs[1]), cov, inv.s, inv.dof, inv.n)


def loglog_line(x: np.ndarray, y: np.ndarray) -> Line:
    lx, ly = np.log10(x), np.log10(y)
    n = len(lx)
    if n < 3 or np.ptp(lx) == 0:
        raise SpecError(f"a log-log line needs at least 3 points at 2 or more x values ({n} given)")
    xm = lx.mean()
    sxx = float(np.sum((lx - xm) ** 2))
    q = float(np.sum((lx - xm) * (ly - ly.mean())) / sxx)
    p = float(ly.mean() - q * xm)
    nu = n - 2
    s2 = float(np.sum((ly - p - q * lx) ** 2)) / nu
    cov = s2 * np.array([[1 / n + xm ** 2 / sxx, -xm / sxx], [-xm / sxx, 1 / sxx]])
    t = float(stats.t.ppf(0.5 + LEVEL / 2, nu))
    sp, sq = math.sqrt(cov[0, 0]), math.sqrt(cov[1, 1])
    return Line(p, q, (p - t * sp, p + t * sp), (q - t * sq, q + t * sq), cov, math.sqrt(s2), nu, n)


@dataclass
class ENData:
    strain_amplitude: np.ndarray
    cycles: np.ndarray
    stress_pa: np.ndarray
    plastic: np.ndarray
    modulus_pa: float
    runout: np.ndarray
    source: str = "data"


def read_en(path: str | Path, modulus_pa: float | None = None) -> ENData:
    """A strain-life CSV: `strain_amplitude` (total, m/m), `cycles` (to failure), and the stabilised
    `stress_amplitude_pa` [Pa] with the modulus E (`modulus_pa`), or `plastic_strain_amplitude`
    directly (then E, when not given, is the median of σa/εe). `runout` (0/1) is optional."""
    c = read_columns(path, EN_REQUIRED, EN_OPTIONAL, flags=("runout",),
                     positive=("strain_amplitude", "cycles", "stress_amplitude_pa"))
    ea, n = c["strain_amplitude"], c["cycles"]
    if ea.max() > 0.2:
        raise RecordError(f"{path}: field `strain_amplitude` reaches {ea.max():g}: give strain in m/m (e.g. 0.005), not %")
    ro = c.get("runout", np.zeros(len(ea), bool))
    if "stress_amplitude_pa" not in c:
        raise RecordError(f"{path}: required column `stress_amplitude_pa` (the stabilised stress amplitude) is missing")
    sa = c["stress_amplitude_pa"]
    if modulus_pa is not None and not (modulus_pa > 1e9):
        raise SpecError(f"--modulus-pa = {modulus_pa}: give E in Pa (e.g. 200e9)")
    if "plastic_strain_amplitude" in c:
        ep = c["plastic_strain_amplitude"]
        e_mod = modulus_pa if modulus_pa else float(np.median(sa / np.maximum(ea - ep, 1e-12)))
    elif modulus_pa:
        e_mod, ep = float(modulus_pa), ea - sa / modulus_pa
    else:
        raise SpecError(f"{path}: no `plastic_strain_amplitude` column: give the modulus with --modulus-pa to split "
                        "elastic and plastic strain")
    return ENData(ea, n, sa, ep, e_mod, ro, str(path))


@dataclass
class ENFit:
    basquin: Line  # log10 σa = log10 σ'f + b·log10 2N
    coffin: Line  # log10 εpa = log10 ε'f + c·log10 2N
    cyclic: Line  # log10 σa = log10 K' + n'·log10 εpa
    modulus_pa: float
    life_sigma_log10: float
    life_dof: int
    n_specimens: int
    n_plastic: int

    @property
    def sigma_f_pa(self) -> float:
        return 10 ** self.basquin.p

    @property
    def epsilon_f(self) -> float:
        return 10 ** self.coffin.p

    def strain(self, reversals: np.ndarray, params: np.ndarray | None = None) -> np.ndarray:
        """Total strain amplitude at 2N reversals."""
        p = self._params() if params is None else params
        r = np.asarray(reversals, float)
        return 10 ** p[0] / self.modulus_pa * r ** p[1] + 10 ** p[2] * r ** p[3]

    def _params(self) -> np.ndarray:
        return np.array([self.basquin.p, self.basquin.q, self.coffin.p, self.coffin.q])

    def log10_reversals(self, strain_amplitude: np.ndarray | float, params: np.ndarray | None = None) -> np.ndarray:
        """log10 2N at a total strain amplitude (the curve solved for life)."""
        e = np.atleast_1d(np.asarray(strain_amplitude, float))
        out = np.empty(len(e))
        for i, ei in enumerate(e):
            def g(lr: float, ei: float = float(ei)) -> float:
                return math.log10(float(self.strain(np.array([10 ** lr]), params)[0])) - math.log10(ei)

            out[i] = optimize.brentq(g, -2.0, 14.0)
        return out

    def prediction_band(self, strain_amplitude: np.ndarray | float, level: float = LEVEL) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """log10 N (cycles, not reversals) at each strain amplitude: (lower, median, upper) for a new specimen."""
        e = np.atleast_1d(np.asarray(strain_amplitude, float))
        p0 = self._params()
        med = self.log10_reversals(e)
        cov = np.zeros((4, 4))
        cov[:2, :2], cov[2:, 2:] = self.basquin.cov, self.coffin.cov
        grad = np.zeros((len(e), 4))
        for j in range(4):
            dp = np.zeros(4)
            dp[j] = 1e-5
            grad[:, j] = (self.log10_reversals(e, p0 + dp) - self.log10_reversals(e, p0 - dp)) / 2e-5
        var_fit = np.einsum("ij,jk,ik->i", grad, cov, grad)
        t = float(stats.t.ppf(0.5 + level / 2, self.life_dof))
        w = t * np.sqrt(self.life_sigma_log10 ** 2 + var_fit)
        lg2 = math.log10(2)
        return med - w - lg2, med - lg2, med + w - lg2

    def to_json(self) -> dict[str, Any]:
        b, c, k = self.basquin, self.coffin, self.cyclic
        n_compat = b.q / c.q
        return {
            "form": "strain_amplitude = sigma_f/E*(2N)^b + epsilon_f*(2N)^c; stress_amplitude = K*(plastic_strain_amplitude)^n",
            "method": "log-log least squares, life (2N reversals) the dependent variable (E739); cyclic curve: stress on plastic strain",
            "modulus_pa": self.modulus_pa,
            "sigma_f_pa": 10 ** b.p, "sigma_f_pa_ci90": [10 ** b.p_ci90[0], 10 ** b.p_ci90[1]],
            "b": b.q, "b_ci90": list(b.q_ci90),
            "epsilon_f": 10 ** c.p, "epsilon_f_ci90": [10 ** c.p_ci90[0], 10 ** c.p_ci90[1]],
            "c": c.q, "c_ci90": list(c.q_ci90),
            "K_prime_pa": 10 ** k.p, "K_prime_pa_ci90": [10 ** k.p_ci90[0], 10 ** k.p_ci90[1]],
            "n_prime": k.q, "n_prime_ci90": list(k.q_ci90),
            "n_prime_from_b_over_c": n_compat, "K_prime_from_sigma_f_epsilon_f_pa": 10 ** b.p / (10 ** c.p) ** n_compat,
            "transition_reversals": (10 ** c.p * self.modulus_pa / 10 ** b.p) ** (1 / (b.q - c.q)),
            "sigma_log10_life": self.life_sigma_log10, "life_dof": self.life_dof,
            "n_specimens": self.n_specimens, "n_with_plastic_strain": self.n_plastic,
            "life_band_90": f"prediction band for one new specimen, resting on {self.n_specimens} specimens",
        }


def en_fit(data: ENData | str | Path, modulus_pa: float | None = None) -> ENFit:
    """Fit the strain-life and the cyclic stress–strain curves (failures only; run-outs are left out
    of these least-squares lines and counted in `n_specimens`)."""
    d = data if isinstance(data, ENData) else read_en(data, modulus_pa)
    f = ~d.runout
    if f.sum() < 3:
        raise SpecError(f"{d.source}: {int(f.sum())} failure(s): the strain-life fit needs at least 3")
    rev = 2 * d.cycles[f]
    basquin = life_line(rev, d.stress_pa[f])
    pl = f & (d.plastic > 0)
    if pl.sum() < 3:
        raise SpecError(f"{d.source}: {int(pl.sum())} test(s) with a positive plastic strain amplitude: Coffin–Manson and "
                        "K', n' need at least 3 (check the modulus)")
    coffin = life_line(2 * d.cycles[pl], d.plastic[pl])
    cyclic = loglog_line(d.plastic[pl], d.stress_pa[pl])
    fit = ENFit(basquin, coffin, cyclic, d.modulus_pa, 0.0, max(int(f.sum()) - 4, 1), len(d.cycles), int(pl.sum()))
    resid = np.log10(rev) - fit.log10_reversals(d.strain_amplitude[f])
    fit.life_sigma_log10 = float(math.sqrt(np.sum(resid ** 2) / fit.life_dof))
    return fit


def simulate_en(sigma_f_pa: float, b: float, epsilon_f: float, c: float, modulus_pa: float, strains: np.ndarray,
                per_level: int, sigma_log10_life: float, rng: np.random.Generator) -> ENData:
    """Strain-controlled tests on a material that follows the strain-life curve exactly (its cyclic
    curve the compatible K' = σ'f/ε'f^(b/c), n' = b/c), with lognormal life scatter."""
    ea = np.repeat(np.asarray(strains, float), per_level)
    fit = ENFit(Line(math.log10(sigma_f_pa), b, (0, 0), (0, 0), np.zeros((2, 2)), 0, 1, 0),
                Line(math.log10(epsilon_f), c, (0, 0), (0, 0), np.zeros((2, 2)), 0, 1, 0),
                Line(0, 0, (0, 0), (0, 0), np.zeros((2, 2)), 0, 1, 0), modulus_pa, 0.0, 1, 0, 0)
    lr = fit.log10_reversals(ea)
    sa = sigma_f_pa * (10 ** lr) ** b
    ep = ea - sa / modulus_pa
    n = 10 ** (lr + sigma_log10_life * rng.standard_normal(len(ea))) / 2
    return ENData(ea, n, sa, ep, modulus_pa, np.zeros(len(ea), bool), "simulated")
