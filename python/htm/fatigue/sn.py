"""S-N (Wöhler) curves from fatigue lives: ASTM E739 (log-log least squares with N dependent, its
confidence and prediction bands, its linearity test) and maximum likelihood with run-outs as
right-censored lives, in the E739 form log10 N = a + b·log10 S (S the stress amplitude in Pa).

Every interval is a 90 % one. The maximum-likelihood fit's intervals are calibrated for small
samples: the scatter by the Cox–Reid adjusted profile likelihood (REML without run-outs), a and b by
the profile likelihood with the threshold n·ln(1 + t²/ν) that gives exactly E739's t-interval when
no specimen ran out. Bands are prediction bands for a new specimen (fit uncertainty + scatter).
"""
from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import optimize, special, stats

from htm.errors import RecordError, SpecError

LEVEL = 0.90  # two-sided level of every interval and band
COLUMNS = ("stress_amplitude_pa", "cycles", "runout")
_HALF_LOG_2PI = 0.5 * math.log(2 * math.pi)
_LS_MIN, _LS_MAX = math.log(1e-4), math.log(10.0)


# --- reading -------------------------------------------------------------------------------------

def read_columns(path: str | Path, required: tuple[str, ...], optional: tuple[str, ...] = (),
                 flags: tuple[str, ...] = (), positive: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """A CSV's numeric columns as float arrays (`flags` as bool arrays, each value 0 or 1).

    A binary file, a missing column, a value that is not a finite number (NaN included), a flag not
    0/1 or a value in `positive` that is ≤ 0 raises RecordError with one line naming the file, the
    row (the file's line number, header = 1) and the field. Blank lines are skipped; optional
    columns absent from the file are left out of the result.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise RecordError(f"{path}: no such file") from None
    except OSError as e:
        raise RecordError(f"{path}: cannot read it ({e.strerror})") from None
    nul = raw.find(b"\x00", 0, 65536)
    if nul >= 0:
        raise RecordError(f"{path}: not a text CSV file (binary content, a NUL byte at offset {nul})")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise RecordError(f"{path}: not a text CSV file (not UTF-8 at byte {e.start})") from None
    rows = list(csv.reader(io.StringIO(text)))
    lines = [(i + 1, r) for i, r in enumerate(rows) if any(c.strip() for c in r)]
    if not lines:
        raise RecordError(f"{path}: empty file (needs a header with {', '.join(required)})")
    header = [c.strip() for c in lines[0][1]]
    missing = [c for c in required if c not in header]
    if missing:
        raise RecordError(f"{path}: required column `{missing[0]}` is missing (found: {', '.join(header)})")
    if len(lines) < 2:
        raise RecordError(f"{path}: no data rows")
    want = [c for c in (*required, *optional) if c in header]
    idx = {c: header.index(c) for c in want}
    out: dict[str, list[Any]] = {c: [] for c in want}
    for line, r in lines[1:]:
        for c in want:
            s = r[idx[c]].strip() if idx[c] < len(r) else ""
            if c in flags:
                if s not in ("0", "1", "0.0", "1.0"):
                    raise RecordError(f"{path}: row {line}: field `{c}` = {s!r} must be 0 or 1")
                out[c].append(s.startswith("1"))
                continue
            try:
                v = float(s)
            except ValueError:
                raise RecordError(f"{path}: row {line}: field `{c}` = {s!r} is not a number") from None
            if not math.isfinite(v):
                raise RecordError(f"{path}: row {line}: field `{c}` = {s!r} is not a finite number")
            if c in positive and v <= 0:
                raise RecordError(f"{path}: row {line}: field `{c}` = {s} must be positive")
            out[c].append(v)
    return {c: np.array(v, bool if c in flags else float) for c, v in out.items()}


@dataclass
class SNData:
    """Fatigue lives at constant stress amplitude: S [Pa], cycles N, run-out flags."""

    stress_pa: np.ndarray
    cycles: np.ndarray
    runout: np.ndarray
    source: str = "data"

    def __post_init__(self) -> None:
        self.stress_pa = np.asarray(self.stress_pa, float)
        self.cycles = np.asarray(self.cycles, float)
        self.runout = np.asarray(self.runout, bool)

    @property
    def n_failures(self) -> int:
        return int((~self.runout).sum())

    @property
    def n_runouts(self) -> int:
        return int(self.runout.sum())


def read_sn(path: str | Path) -> SNData:
    """An S-N CSV: `stress_amplitude_pa` [Pa], `cycles` (to failure, or at run-out) and `runout`
    (0 failure, 1 run-out). Bad input is a RecordError naming file, row and field."""
    c = read_columns(path, COLUMNS, flags=("runout",), positive=("stress_amplitude_pa", "cycles"))
    d = SNData(c["stress_amplitude_pa"], c["cycles"], c["runout"], str(path))
    if d.stress_pa.max() < 1e4:
        raise RecordError(f"{path}: field `stress_amplitude_pa` is at most {d.stress_pa.max():g}: that looks like MPa; "
                          "give Pa (e.g. 250e6)")
    return d


def check_fittable(d: SNData) -> None:
    """The curve needs at least 3 failures on 2 stress levels; all run-outs is named as such."""
    if d.n_failures == 0:
        raise SpecError(f"{d.source}: all {len(d.cycles)} specimens are run-outs: no failure to fit a curve to")
    fl = np.unique(d.stress_pa[~d.runout])
    if d.n_failures < 3 or len(fl) < 2:
        raise SpecError(f"{d.source}: {d.n_failures} failure(s) on {len(fl)} stress level(s): the S-N fit needs at least 3 "
                        "failures on 2 levels")


# --- the fit -------------------------------------------------------------------------------------

@dataclass
class SNFit:
    """log10 N = a + b·log10 S (S in Pa) with 90 % intervals and the scatter of log10 N.

    `cov_ab` is the covariance of (a, b) used by the bands; `dof` the degrees of freedom of the
    t quantile in them; `x_mean` the mean log10 S of the fitted points (where a and b decorrelate).
    """

    method: str
    a: float
    b: float
    a_ci90: tuple[float, float]
    b_ci90: tuple[float, float]
    sigma_log10_n: float
    sigma_ci90: tuple[float, float]
    cov_ab: np.ndarray
    dof: int
    n_specimens: int
    n_failures: int
    n_runouts: int
    runouts_used: str
    x_mean: float
    stress_range_pa: tuple[float, float]
    linearity: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    mle: dict[str, float] = field(default_factory=dict)  # the plain maximum-likelihood (a, b, σ), σ with divisor n

    def median_log10_n(self, stress_pa: np.ndarray | float) -> np.ndarray:
        return self.a + self.b * np.log10(np.asarray(stress_pa, float))

    def _se_mean(self, stress_pa: np.ndarray | float) -> np.ndarray:
        x = np.log10(np.asarray(stress_pa, float))
        c = self.cov_ab
        return np.sqrt(np.maximum(c[0, 0] + 2 * x * c[0, 1] + x * x * c[1, 1], 0.0))

    def confidence_band(self, stress_pa: np.ndarray | float, level: float = LEVEL) -> tuple[np.ndarray, np.ndarray]:
        """log10 N band of the median curve as a whole (Working–Hotelling, as E739)."""
        w = math.sqrt(2 * stats.f.ppf(level, 2, self.dof)) * self._se_mean(stress_pa)
        m = self.median_log10_n(stress_pa)
        return m - w, m + w

    def prediction_band(self, stress_pa: np.ndarray | float, level: float = LEVEL) -> tuple[np.ndarray, np.ndarray]:
        """log10 N band for one new specimen at S: the fit's uncertainty and the scatter together
        (t quantile with the fit's degrees of freedom)."""
        t = stats.t.ppf(0.5 + level / 2, self.dof)
        w = t * np.sqrt(self.sigma_log10_n ** 2 + self._se_mean(stress_pa) ** 2)
        m = self.median_log10_n(stress_pa)
        return m - w, m + w

    def to_json(self) -> dict[str, Any]:
        s_lo, s_hi = self.stress_range_pa
        grid = np.geomspace(s_lo, s_hi, 5)
        plo, phi = self.prediction_band(grid)
        return {
            "form": "log10 N = a + b*log10 S, S = stress amplitude [Pa]", "method": self.method,
            "a": self.a, "b": self.b, "a_ci90": list(self.a_ci90), "b_ci90": list(self.b_ci90),
            "sigma_log10_n": self.sigma_log10_n, "sigma_log10_n_ci90": list(self.sigma_ci90),
            "basquin_exponent_k": -self.b, "cov_ab": self.cov_ab.tolist(), "dof": self.dof,
            "n_specimens": self.n_specimens, "n_failures": self.n_failures, "n_runouts": self.n_runouts,
            "runouts": self.runouts_used, "stress_range_pa": [s_lo, s_hi], "linearity": self.linearity,
            "prediction_band_90": {"note": f"for one new specimen, resting on {self.n_specimens} specimens "
                                           f"({self.n_failures} failures, {self.n_runouts} run-outs)",
                                   "stress_pa": grid.tolist(), "cycles_lo": (10 ** plo).tolist(),
                                   "cycles_median": (10 ** self.median_log10_n(grid)).tolist(), "cycles_hi": (10 ** phi).tolist()},
            "mle": self.mle, "notes": self.notes,
        }


    @classmethod
    def from_json(cls, doc: dict[str, Any], source: str = "fit.json") -> SNFit:
        """Back from `to_json` (a fit.json), for damage sums and bands."""
        try:
            return cls(doc["method"], float(doc["a"]), float(doc["b"]), tuple(doc["a_ci90"]), tuple(doc["b_ci90"]),  # type: ignore[arg-type]
                       float(doc["sigma_log10_n"]), tuple(doc["sigma_log10_n_ci90"]), np.array(doc["cov_ab"], float),  # type: ignore[arg-type]
                       int(doc["dof"]), int(doc["n_specimens"]), int(doc["n_failures"]), int(doc["n_runouts"]),
                       str(doc["runouts"]), float("nan"), tuple(doc["stress_range_pa"]), doc.get("linearity", {}),  # type: ignore[arg-type]
                       list(doc.get("notes", [])), dict(doc.get("mle", {})))
        except (KeyError, TypeError, ValueError) as e:
            raise RecordError(f"{source}: not an htm S-N fit (field {e})") from None


def _levels(x: np.ndarray) -> np.ndarray:
    """Level index of each log10 S (levels equal to 1e-6 in log10 S, i.e. 2 ppm in S, are one)."""
    r = np.round(x / 1e-6).astype(np.int64)
    return np.unique(r, return_inverse=True)[1]


def linearity_test(x: np.ndarray, y: np.ndarray, level: float = 0.95) -> dict[str, Any]:
    """E739's F test of the linear model against the level means (lack of fit over pure error).
    Needs replicates and at least 3 levels; otherwise says why it does not apply."""
    lv = _levels(x)
    n, ll = len(x), int(lv.max()) + 1
    if ll < 3 or n <= ll:
        why = f"{ll} stress level(s)" if ll < 3 else "no replicate specimens"
        return {"applicable": False, "reason": f"E739's F test needs replicates at 3 or more stress levels ({why} here)",
                "levels": ll}
    X = np.column_stack([np.ones(n), x])
    coef = np.linalg.lstsq(X, y, rcond=None)[0]
    sse = float(np.sum((y - X @ coef) ** 2))
    means = np.bincount(lv, y) / np.bincount(lv)
    sspe = float(np.sum((y - means[lv]) ** 2))
    df1, df2 = ll - 2, n - ll
    f = ((sse - sspe) / df1) / (sspe / df2) if sspe > 0 else math.inf
    crit = float(stats.f.ppf(level, df1, df2))
    return {"applicable": True, "levels": ll, "F": f, "F_critical": crit, "level": level, "df": [df1, df2],
            "linear": bool(f <= crit), "p_value": float(stats.f.sf(f, df1, df2)) if math.isfinite(f) else 0.0,
            "replication_percent": 100.0 * (1 - ll / n)}


def fit_e739(d: SNData, runouts_as_failures: bool = False) -> SNFit:
    """ASTM E739: least squares of log10 N on log10 S over the failures (run-outs left out, as E739
    says, or counted as failures at their cycles with `runouts_as_failures`: biased, shown for
    comparison). t intervals for a and b, χ² interval for the scatter (n − 2 degrees of freedom)."""
    check_fittable(d)
    use = np.ones(len(d.cycles), bool) if runouts_as_failures else ~d.runout
    x, y = np.log10(d.stress_pa[use]), np.log10(d.cycles[use])
    n = len(x)
    if n < 3 or len(np.unique(x)) < 2:
        raise SpecError(f"{d.source}: E739 needs at least 3 failures on 2 stress levels")
    xm = float(x.mean())
    sxx = float(np.sum((x - xm) ** 2))
    b = float(np.sum((x - xm) * (y - y.mean())) / sxx)
    a = float(y.mean() - b * xm)
    nu = n - 2
    sse = float(np.sum((y - a - b * x) ** 2))
    s2 = sse / nu
    var_b, var_a, cov = s2 / sxx, s2 * (1 / n + xm ** 2 / sxx), -s2 * xm / sxx
    t = float(stats.t.ppf(0.5 + LEVEL / 2, nu))
    s = math.sqrt(s2)
    sig_ci = (math.sqrt(sse / stats.chi2.ppf(0.5 + LEVEL / 2, nu)), math.sqrt(sse / stats.chi2.ppf(0.5 - LEVEL / 2, nu)))
    notes = []
    if d.n_runouts and not runouts_as_failures:
        notes.append(f"{d.n_runouts} run-out(s) left out (E739 fits failures only); the maximum-likelihood fit uses them")
    if runouts_as_failures and d.n_runouts:
        notes.append(f"{d.n_runouts} run-out(s) counted as failures at their cycles: biased towards short lives")
    return SNFit("e739_runouts_as_failures" if runouts_as_failures else "e739", a, b,
                 (a - t * math.sqrt(var_a), a + t * math.sqrt(var_a)), (b - t * math.sqrt(var_b), b + t * math.sqrt(var_b)),
                 s, sig_ci, np.array([[var_a, cov], [cov, var_b]]), nu, len(d.cycles), d.n_failures, d.n_runouts,
                 "as failures" if runouts_as_failures else "left out", xm,
                 (float(d.stress_pa.min()), float(d.stress_pa.max())), linearity_test(x, y), notes)


class _Censored:
    """Log-likelihood of log10 N ~ Normal(a + b·x, σ) with run-outs right-censored at their cycles."""

    def __init__(self, x: np.ndarray, y: np.ndarray, ro: np.ndarray):
        self.x, self.y, self.ro = x, y, ro
        self.f = ~ro
        self.xm = float(x.mean())

    def terms(self, a: float, b: float, ls: float) -> tuple[float, np.ndarray, float]:
        """loglik, its derivative in μ per point, and its derivative in ln σ (σ kept within
        1e-4..10 decades, so that a line search cannot overflow)."""
        ls = min(max(ls, _LS_MIN), _LS_MAX)
        sigma = math.exp(ls)
        z = (self.y - a - b * self.x) / sigma
        zf, zr = z[self.f], z[self.ro]
        ll = float(-0.5 * np.sum(zf * zf) - len(zf) * (ls + _HALF_LOG_2PI) + np.sum(special.log_ndtr(-zr)))
        dmu = np.empty_like(z)
        dmu[self.f] = zf / sigma
        lam = np.exp(-0.5 * zr * zr - _HALF_LOG_2PI - special.log_ndtr(-zr))
        dmu[self.ro] = lam / sigma
        dls = float(np.sum(zf * zf - 1.0) + np.sum(lam * zr))
        return ll, dmu, dls

    def loglik(self, a: float, b: float, sigma: float) -> float:
        return self.terms(a, b, math.log(sigma))[0] if sigma > 0 else -math.inf

    def info_ab(self, a: float, b: float, sigma: float) -> np.ndarray:
        """Observed information of (a, b) at fixed σ (failures weigh 1/σ², run-outs λ(λ − z)/σ²)."""
        w = np.ones(len(self.x))
        if self.ro.any():
            z = (self.y[self.ro] - a - b * self.x[self.ro]) / sigma
            lam = np.exp(-0.5 * z * z - _HALF_LOG_2PI - special.log_ndtr(-z))
            w[self.ro] = lam * (lam - z)
        X = np.column_stack([np.ones(len(self.x)), self.x])
        return (X.T * w) @ X / sigma ** 2

    def _min(self, fun: Any, p0: list[float]) -> tuple[np.ndarray, float]:
        r = optimize.minimize(fun, p0, jac=True, method="BFGS", options={"gtol": 1e-10, "maxiter": 500})
        return r.x, -float(r.fun)

    def best_ab(self, sigma: float, start: tuple[float, float]) -> tuple[float, float, float]:
        """max over (a, b) at fixed σ (centred in x for conditioning): (a, b, loglik)."""
        xm, ls = self.xm, math.log(sigma)

        def f(p: np.ndarray) -> tuple[float, np.ndarray]:
            ll, dmu, _ = self.terms(p[0] - p[1] * xm, p[1], ls)
            return -ll, -np.array([dmu.sum(), np.dot(dmu, self.x - xm)])

        p, ll = self._min(f, [start[0] + start[1] * xm, start[1]])
        return float(p[0] - p[1] * xm), float(p[1]), ll

    def best(self, start: tuple[float, float, float]) -> tuple[np.ndarray, float]:
        """max over (a, b, ln σ): ((a, b, ln σ), loglik)."""
        xm = self.xm

        def f(p: np.ndarray) -> tuple[float, np.ndarray]:
            ll, dmu, dls = self.terms(p[0] - p[1] * xm, p[1], p[2])
            return -ll, -np.array([dmu.sum(), np.dot(dmu, self.x - xm), dls])

        p, ll = self._min(f, [start[0] + start[1] * xm, start[1], start[2]])
        return np.array([p[0] - p[1] * xm, p[1], p[2]]), ll

    def adjusted_profile(self, log_sigma: float, start: tuple[float, float]) -> tuple[float, float, float]:
        s = math.exp(log_sigma)
        a, b, ll = self.best_ab(s, start)
        sign, logdet = np.linalg.slogdet(self.info_ab(a, b, s))
        return a, b, ll - 0.5 * logdet if sign > 0 else -math.inf

    def profile_fixed(self, which: int, value: float, start: np.ndarray) -> float:
        """max loglik with a (which = 0) or b (which = 1) fixed at `value`, over the other and ln σ."""
        def f(p: np.ndarray) -> tuple[float, np.ndarray]:
            a, b = (value, p[0]) if which == 0 else (p[0], value)
            ll, dmu, dls = self.terms(a, b, p[1])
            d_other = np.dot(dmu, self.x) if which == 0 else dmu.sum()
            return -ll, -np.array([d_other, dls])

        return self._min(f, list(start))[1]


def fit_ml(d: SNData) -> SNFit:
    """Maximum likelihood with run-outs as right-censored lives.

    The scatter is the maximiser of the Cox–Reid adjusted profile likelihood (without run-outs: the
    E739 scatter, n − 2 degrees of freedom) and a, b the likelihood's maximisers at that scatter.
    90 % intervals: a and b from the profile likelihood ratio with threshold n·ln(1 + t²/ν), ν = n_f − 2
    (exactly E739's t interval when no specimen ran out); σ from the adjusted profile with the χ²₁
    threshold. The bands use the observed information of (a, b) at σ and t with ν degrees of freedom.
    """
    check_fittable(d)
    x, y, ro = np.log10(d.stress_pa), np.log10(d.cycles), d.runout.copy()
    m = _Censored(x, y, ro)
    e = fit_e739(d)
    start = (e.a, e.b)
    # the scatter: maximise the adjusted profile over log σ
    r = optimize.minimize_scalar(lambda ls: -m.adjusted_profile(ls, start)[2],
                                 bounds=(math.log(max(e.sigma_log10_n, 1e-3)) - 3, math.log(max(e.sigma_log10_n, 1e-3)) + 3),
                                 method="bounded", options={"xatol": 1e-7})
    ls_hat = float(r.x)
    sigma = math.exp(ls_hat)
    a, b, _ = m.best_ab(sigma, start)
    adj_max = m.adjusted_profile(ls_hat, (a, b))[2]
    # full maximum of the likelihood (σ free) for the profile intervals of a and b
    p_mle, ll_max = m.best((a, b, ls_hat))
    n, nf = len(x), d.n_failures
    nu = max(nf - 2, 1)
    t = float(stats.t.ppf(0.5 + LEVEL / 2, nu))
    thr = n * math.log1p(t * t / nu)
    cov = np.linalg.inv(m.info_ab(a, b, sigma))
    cis = []
    for which, est, se in ((0, a, math.sqrt(cov[0, 0])), (1, b, math.sqrt(cov[1, 1]))):
        other = b if which == 0 else a

        def g(v: float, which: int = which, other: float = other) -> float:
            return 2 * (ll_max - m.profile_fixed(which, v, np.array([other, ls_hat]))) - thr

        ends = []
        for sgn in (-1.0, 1.0):
            step = se * t
            lo_v = est
            hi_v = est + sgn * step
            k = 0
            while g(hi_v) < 0 and k < 30:
                lo_v, hi_v = hi_v, hi_v + sgn * step
                k += 1
            ends.append(optimize.brentq(g, lo_v, hi_v, xtol=1e-9 * max(1.0, abs(est))) if k < 30 else est + sgn * math.inf)
        cis.append((min(ends), max(ends)))
    # σ interval: adjusted profile with the χ²₁ threshold
    c1 = float(stats.chi2.ppf(LEVEL, 1)) / 2

    def h(ls: float) -> float:
        return adj_max - m.adjusted_profile(ls, (a, b))[2] - c1

    s_ends = []
    for sgn in (-1.0, 1.0):
        lo_v, hi_v, k = ls_hat, ls_hat + sgn * 0.3, 0
        while h(hi_v) < 0 and k < 40:
            lo_v, hi_v = hi_v, hi_v + sgn * 0.3
            k += 1
        s_ends.append(math.exp(optimize.brentq(h, min(lo_v, hi_v), max(lo_v, hi_v), xtol=1e-9)))
    notes = [f"{d.n_runouts} run-out(s) as right-censored lives"] if d.n_runouts else []
    return SNFit("maximum_likelihood", a, b, cis[0], cis[1], sigma, (min(s_ends), max(s_ends)), cov, nu, n, nf,
                 d.n_runouts, "censored", float(x.mean()), (float(d.stress_pa.min()), float(d.stress_pa.max())),
                 linearity_test(x[~ro], y[~ro]), notes,
                 {"a": float(p_mle[0]), "b": float(p_mle[1]), "sigma_log10_n": math.exp(float(p_mle[2]))})


def sn_fit(data: SNData | str | Path, method: str = "auto", runouts_as_failures: bool = False) -> SNFit:
    """Fit the S-N curve of `data` (an SNData or a CSV path; see `read_sn`).

    method: ``"e739"`` (least squares over the failures), ``"ml"`` (maximum likelihood with run-outs
    censored) or ``"auto"`` (ml when there are run-outs, else e739; both agree then).
    """
    d = data if isinstance(data, SNData) else read_sn(data)
    if method not in ("auto", "e739", "ml"):
        raise SpecError(f"method `{method}` is unknown: use auto, e739 or ml")
    if method == "e739" or runouts_as_failures or (method == "auto" and d.n_runouts == 0):
        return fit_e739(d, runouts_as_failures)
    return fit_ml(d)


def simulate_sn(a: float, b: float, sigma: float, levels_pa: np.ndarray, per_level: int, runout_cycles: float,
                rng: np.random.Generator) -> SNData:
    """Lives log10 N = a + b·log10 S + σ·ε at each level (`per_level` specimens), run-outs where
    N would pass `runout_cycles` (stopped there): a data set with a known curve."""
    s = np.repeat(np.asarray(levels_pa, float), per_level)
    n = 10 ** (a + b * np.log10(s) + sigma * rng.standard_normal(len(s)))
    ro = n >= runout_cycles
    return SNData(s, np.where(ro, runout_cycles, n), ro, "simulated")


def write_sn_csv(path: str | Path, d: SNData) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(COLUMNS)
        for s, n, r in zip(d.stress_pa, d.cycles, d.runout):
            w.writerow([f"{s:.6g}", f"{n:.6g}", int(r)])
    return path


def miner_damage(stress_pa: np.ndarray, fit: SNFit, level: float = LEVEL) -> dict[str, Any]:
    """Palmgren–Miner damage of one pass of a measured stress history [Pa]: the core's rainflow
    count (ASTM E1049), each counted cycle's amplitude (range/2, no mean-stress correction) against
    the fitted curve, extrapolated beyond the tested stresses as it stands. Damage with the median
    curve and with the lower end of the prediction band (a weak new specimen); the passes to D = 1."""
    from htm import core

    s = np.asarray(stress_pa, float)
    if len(s) < 3:
        raise SpecError(f"damage: the stress history has {len(s)} points; a rainflow count needs at least 3")
    counted = np.array(core.rainflow(s.tolist()), float).reshape(-1, 3)
    amp, cnt = counted[:, 0] / 2, counted[:, 2]
    keep = amp > 0
    amp, cnt = amp[keep], cnt[keep]
    if not len(amp):
        return {"cycles_counted": 0.0, "damage_median": 0.0, "damage_lower_band": 0.0, "passes_to_failure_median": math.inf,
                "passes_to_failure_lower_band": math.inf}
    d_med = float(np.sum(cnt / 10 ** fit.median_log10_n(amp)))
    d_lo = float(np.sum(cnt / 10 ** fit.prediction_band(amp, level)[0]))
    lo, hi = fit.stress_range_pa
    return {"cycles_counted": float(cnt.sum()), "amplitude_max_pa": float(amp.max()), "amplitude_min_pa": float(amp.min()),
            "cycles_outside_fitted_stresses": float(cnt[(amp < lo) | (amp > hi)].sum()),
            "damage_median": d_med, "damage_lower_band": d_lo,
            "passes_to_failure_median": 1 / d_med if d_med > 0 else math.inf,
            "passes_to_failure_lower_band": 1 / d_lo if d_lo > 0 else math.inf,
            "rests_on_specimens": fit.n_specimens}
