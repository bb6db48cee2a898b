"""ASTM E647 data reduction: secant and incremental-polynomial da/dN, ΔK and Kmax, validity flags,
threshold ΔK_th, and the region-II Paris fit. SI inside (m, m/cycle, Pa·√m)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from htm import core
from htm.errors import SpecError
from htm.fatigue.data import CrackData, Setup, check_a_n

#: E647 §9.1 minimum crack extension between readings (0.25 mm, or 10× the measurement precision).
MIN_SPACING_M = 0.25e-3
#: E647 threshold: ΔK at da/dN = 1e-10 m/cycle from ≥ 5 points between 1e-10 and 1e-9 m/cycle.
THRESHOLD_RATE = 1e-10
THRESHOLD_UPPER_RATE = 1e-9


def max_spacing_m(setup: Setup, a_m: np.ndarray) -> np.ndarray:
    """E647 §8.6.3 largest crack extension between readings [m] at each a.

    C(T): 0.04W for a/W ≤ 0.40, 0.02W for 0.40 < a/W ≤ 0.60, 0.01W beyond.
    M(T): 0.03W for 2a/W ≤ 0.60, 0.02W beyond.
    """
    w = setup.width_m
    if setup.geometry == "ct":
        al = a_m / w
        return np.where(al <= 0.40, 0.04 * w, np.where(al <= 0.60, 0.02 * w, 0.01 * w))
    al = 2 * a_m / w
    return np.where(al <= 0.60, 0.03 * w, 0.02 * w)


@dataclass
class Reduced:
    """Per-point results of a reduction (arrays of equal length; `valid` and `reasons` per point)."""

    specimen: str
    method: str
    cycles: np.ndarray
    a_m: np.ndarray
    a_fit_m: np.ndarray
    dadn_m_per_cycle: np.ndarray
    delta_k_pa_sqrt_m: np.ndarray
    kmax_pa_sqrt_m: np.ndarray
    valid: np.ndarray
    reasons: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.cycles)

    def mask(self, only_valid: bool = True) -> np.ndarray:
        m = np.isfinite(self.dadn_m_per_cycle) & np.isfinite(self.delta_k_pa_sqrt_m) & (self.dadn_m_per_cycle > 0)
        return m & self.valid if only_valid else m


def resolution_of(values: np.ndarray, significant_digits: int = 3) -> np.ndarray:
    """Quantisation step of numbers printed with `significant_digits` (e.g. 1.26e5 → 1000)."""
    v = np.abs(np.asarray(values, float))
    v = np.where(v > 0, v, 1.0)
    return 10.0 ** (np.floor(np.log10(v)) - (significant_digits - 1))


def _odr_quadratic(x: np.ndarray, y: np.ndarray, sx: np.ndarray, sy: np.ndarray, beta0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Errors-in-variables quadratic y = b0 + b1 t + b2 t² through points (x, y) with standard
    deviations sx, sy (orthogonal distance in the scaled metric). Returns (b, t) with t the
    adjusted abscissae."""
    from scipy.optimize import least_squares

    k = len(x)

    def res(z: np.ndarray) -> np.ndarray:
        b, t = z[:3], z[3:]
        return np.concatenate([(t - x) / sx, (b[0] + b[1] * t + b[2] * t * t - y) / sy])

    sol = least_squares(res, np.concatenate([beta0, x]), method="lm", xtol=1e-14, ftol=1e-14, max_nfev=200 * (k + 3))
    return sol.x[:3], sol.x[3:]


def incremental_polynomial(cycles: np.ndarray, a_m: np.ndarray, n: int = 3,
                           cycles_resolution: np.ndarray | float | None = None,
                           a_resolution_m: np.ndarray | float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """E647 X1.2 (thesis eq. 1.4–1.5): local quadratic over 2n+1 points.

    Returns (â_i [m], da/dN_i [m/cycle]) at every point; NaN for the first and last n points.
    With `cycles_resolution` and `a_resolution_m` (quantisation steps of the recorded N and a,
    e.g. from printed rounding) the local quadratic is fitted errors-in-variables, each reading
    carrying a uniform quantisation error (σ = step/√12), and â_i, da/dN_i are taken at the
    adjusted N_i; without them it is E647's least squares in a at the recorded N_i.
    """
    if not isinstance(n, (int, np.integer)) or n < 1 or n > 10:
        raise SpecError(f"incremental polynomial n = {n} is out of range: allowed integers 1..10 (E647 uses 1–4)")
    N = np.asarray(cycles, float)
    a = np.asarray(a_m, float)
    k = len(N)
    eiv = cycles_resolution is not None and a_resolution_m is not None
    if eiv:
        sN = np.broadcast_to(np.asarray(cycles_resolution, float), N.shape) / np.sqrt(12)
        sa = np.broadcast_to(np.asarray(a_resolution_m, float), a.shape) / np.sqrt(12)
        if np.any(sN <= 0) or np.any(sa <= 0):
            raise SpecError("cycles_resolution and a_resolution_m must be positive")
    a_hat = np.full(k, np.nan)
    rate = np.full(k, np.nan)
    for i in range(n, k - n):
        sl = slice(i - n, i + n + 1)
        Ns, As = N[sl], a[sl]
        c1 = 0.5 * (Ns[0] + Ns[-1])
        c2 = 0.5 * (Ns[-1] - Ns[0])
        if c2 <= 0:
            continue
        x = (Ns - c1) / c2
        b2, b1, b0 = np.polyfit(x, As, 2)
        xi = (N[i] - c1) / c2
        if eiv:
            (b0, b1, b2), t = _odr_quadratic(x, As, sN[sl] / c2, sa[sl], np.array([b0, b1, b2]))
            xi = t[n]
        a_hat[i] = b0 + b1 * xi + b2 * xi * xi
        rate[i] = (b1 + 2 * b2 * xi) / c2
    return a_hat, rate


def secant(cycles: np.ndarray, a_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """E647 X1.1 secant method: (interval mid-N, mean crack size ā [m], da/dN [m/cycle]); NaN where ΔN = 0."""
    N = np.asarray(cycles, float)
    a = np.asarray(a_m, float)
    dn = np.diff(N)
    with np.errstate(divide="ignore", invalid="ignore"):
        rate = np.where(dn > 0, np.diff(a) / np.where(dn > 0, dn, 1.0), np.nan)
    return 0.5 * (N[1:] + N[:-1]), 0.5 * (a[1:] + a[:-1]), rate


def reduce(data: CrackData, setup: Setup, method: str = "polynomial", n: int = 3,
           min_spacing_m: float = MIN_SPACING_M, cycles_resolution: np.ndarray | float | None = None,
           a_resolution_m: np.ndarray | float | None = None) -> Reduced:
    """Reduce one specimen's a–N record per ASTM E647: da/dN and ΔK per point, with validity.

    Parameters
    ----------
    data : CrackData
        Cycles and crack size a [m] of one specimen.
    setup : Setup
        Specimen (W, B [m]), load (Pmax [N], R) and optional yield strength [Pa].
    method : str
        ``"polynomial"`` (incremental polynomial, 2n+1 points; ΔK at the fitted â_i) or
        ``"secant"`` (ΔK at the interval's mean crack size).
    n : int
        Half-width of the incremental polynomial.
    min_spacing_m : float
        Minimum crack extension between points [m] (E647: 0.25 mm).
    cycles_resolution, a_resolution_m : array or float, optional
        Reading resolution of N [cycles] and a [m]; see `incremental_polynomial`.

    Returns
    -------
    Reduced
        Per point: da/dN [m/cycle], ΔK and Kmax [Pa·√m], fitted a [m], and validity (ΔK
        expression range in a/W, crack-extension spacing per §8.6.3, size criterion if σ_ys is
        given, positive growth rate) with reasons.
    """
    check_a_n(data, setup)
    N, a = data.cycles.astype(float), data.a_m.astype(float)
    if method in ("polynomial", "incremental_polynomial"):
        if len(N) < 2 * n + 1:
            raise SpecError(f"specimen {data.specimen}: the incremental polynomial with n = {n} needs at least "
                            f"{2 * n + 1} points, got {len(N)}")
        a_fit, rate = incremental_polynomial(N, a, n, cycles_resolution, a_resolution_m)
        cyc, a_meas = N, a
        # spacing around point i: the readings used in its window
        gaps = np.diff(a)
        lo_gap = np.full(len(N), np.nan)
        hi_gap = np.full(len(N), np.nan)
        for i in range(n, len(N) - n):
            g = gaps[i - n:i + n]
            lo_gap[i], hi_gap[i] = g.min(), g.max()
        a_k = a_fit
    elif method == "secant":
        cyc, a_fit, rate = secant(N, a)
        a_meas = a[:-1]
        lo_gap = hi_gap = np.diff(a)
        a_k = a_fit
    else:
        raise SpecError(f"method `{method}` is unknown: use polynomial or secant")

    lo, hi = setup.a_range_m
    k = len(cyc)
    dk = np.full(k, np.nan)
    kmax = np.full(k, np.nan)
    in_range = np.isfinite(a_k) & (a_k >= lo) & (a_k <= hi)
    if in_range.any():
        dk[in_range] = setup.delta_k(a_k[in_range])
        kmax[in_range] = setup.kmax(a_k[in_range])

    reasons: list[str] = []
    valid = np.ones(k, bool)
    smax = max_spacing_m(setup, np.where(np.isfinite(a_k), a_k, a_meas))
    req = np.full(k, np.nan)
    lig = np.full(k, np.nan)
    if setup.yield_strength_pa is not None and in_range.any():
        l_, r_ = core.size_criterion(setup.geometry, setup.width_m, setup.thickness_m,
                                      np.ascontiguousarray(a_k[in_range]), setup.pmax_n, setup.yield_strength_pa)
        lig[in_range], req[in_range] = l_, r_
    for i in range(k):
        why = []
        if not np.isfinite(rate[i]):
            why.append("no_rate")
        elif rate[i] <= 0:
            why.append("non_positive_rate")
        if np.isfinite(a_k[i]) and not in_range[i]:
            why.append("a_over_w")
        if np.isfinite(lo_gap[i]) and lo_gap[i] < min_spacing_m * (1 - 1e-9):
            why.append("spacing_small")
        if np.isfinite(hi_gap[i]) and hi_gap[i] > smax[i] * (1 + 1e-9):
            why.append("spacing_large")
        if np.isfinite(req[i]) and lig[i] < req[i]:
            why.append("size_criterion")
        valid[i] = not why
        reasons.append(";".join(why))
    return Reduced(data.specimen, "polynomial" if method != "secant" else "secant", cyc, a_meas,
                   a_fit, rate, dk, kmax, valid, reasons)


@dataclass
class ParisFit:
    """da/dN = C·ΔK^m with C in (m/cycle)/(MPa·√m)^m (and `c_si` in (m/cycle)/(Pa·√m)^m)."""

    c_mpa: float
    m: float
    se_log10_c: float
    se_m: float
    npoints: int
    rms_log10: float
    dk_range_mpa: tuple[float, float]

    @property
    def c_si(self) -> float:
        return self.c_mpa * 1e-6 ** self.m

    def to_dict(self) -> dict:
        return {"c_mpa": self.c_mpa, "c_si": self.c_si, "m": self.m, "se_log10_c": self.se_log10_c,
                "se_m": self.se_m, "npoints": self.npoints, "rms_log10_rate": self.rms_log10,
                "delta_k_range_mpa_sqrt_m": list(self.dk_range_mpa)}


def fit_paris_points(dk_pa: np.ndarray, dadn: np.ndarray) -> ParisFit:
    """Least squares of log10 da/dN on log10 ΔK[MPa·√m]; standard errors from the residual variance."""
    x = np.log10(np.asarray(dk_pa) / 1e6)
    y = np.log10(np.asarray(dadn))
    if len(x) < 3:
        raise SpecError(f"a Paris fit needs at least 3 valid da/dN points, got {len(x)}")
    A = np.column_stack([np.ones_like(x), x])
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    res = y - A @ coef
    dof = max(len(x) - 2, 1)
    s2 = float(res @ res) / dof
    cov = s2 * np.linalg.inv(A.T @ A)
    return ParisFit(10 ** coef[0], float(coef[1]), float(np.sqrt(cov[0, 0])), float(np.sqrt(cov[1, 1])), len(x),
                    float(np.sqrt(np.mean(res ** 2))), (float(10 ** x.min()), float(10 ** x.max())))


def paris_region_ii(red: Reduced | list[Reduced]) -> ParisFit:
    """Region-II Paris fit over valid points above the near-threshold band (da/dN > 1e-9 m/cycle)."""
    reds = red if isinstance(red, list) else [red]
    dk, r = [], []
    for rd in reds:
        m = rd.mask() & (rd.dadn_m_per_cycle > THRESHOLD_UPPER_RATE)
        dk.append(rd.delta_k_pa_sqrt_m[m])
        r.append(rd.dadn_m_per_cycle[m])
    return fit_paris_points(np.concatenate(dk), np.concatenate(r))


def threshold(red: Reduced) -> dict:
    """E647 §9.4 ΔK_th: ΔK at 1e-10 m/cycle from a linear fit of log ΔK on log da/dN over ≥ 5 valid
    points with 1e-10 ≤ da/dN ≤ 1e-9 m/cycle. Returns {"reached": bool, ...}."""
    m = red.mask() & (red.dadn_m_per_cycle >= THRESHOLD_RATE) & (red.dadn_m_per_cycle <= THRESHOLD_UPPER_RATE)
    npts = int(m.sum())
    if npts < 5:
        lowest = float(np.nanmin(np.where(red.mask(), red.dadn_m_per_cycle, np.nan))) if red.mask().any() else float("nan")
        return {"reached": False, "npoints": npts, "lowest_rate_m_per_cycle": lowest,
                "note": "needs ≥ 5 valid points with 1e-10 ≤ da/dN ≤ 1e-9 m/cycle"}
    y = np.log10(red.delta_k_pa_sqrt_m[m])
    x = np.log10(red.dadn_m_per_cycle[m])
    b, a0 = np.polyfit(x, y, 1)
    return {"reached": True, "npoints": npts, "delta_k_th_pa_sqrt_m": float(10 ** (a0 + b * np.log10(THRESHOLD_RATE))),
            "slope": float(b)}


def summary(red: Reduced) -> dict:
    """Counts of valid points and of each invalidity reason."""
    counts: dict[str, int] = {}
    for r in red.reasons:
        for w in filter(None, r.split(";")):
            counts[w] = counts.get(w, 0) + 1
    return {"points": len(red), "valid": int(red.valid.sum()), "reasons": counts}
