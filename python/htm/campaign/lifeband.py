"""Crack-growth life as a distribution: per-specimen Paris fits across a specimen set (e.g. the 40
Virkler specimens), the joint normal of their (log10 C, m), and the life of the set's test as a
Monte Carlo campaign over that joint (`[scatter.joint]`), run by the campaign engine on the simulated
rig; then updating one running specimen's prediction from its first a–N points.

The band is a prediction band for a new specimen: its (log10 C, m) is drawn from the predictive
distribution of a new member of the specimen set — a bivariate t with n − 2 degrees of freedom about
the set's mean, scale Σ̂·(n + 1)(n − 1)/(n(n − 2)) (the normal's mean and covariance estimated from n
specimens, not known) — so the uncertainty of the fit across specimens widens it, the more so the
fewer specimens it rests on. The campaign draws from a normal twice as wide (its `[scatter.joint]`)
and each draw is weighted by the ratio of the two densities (importance weights).

The update reweights the campaign's draws by how well each one's law reproduces the early points
(importance weights, Gaussian in cycles with the scatter of a measured point around its own
specimen's fitted curve): the band narrows to the laws the specimen is following, with no new test
to run.
"""
from __future__ import annotations

import copy
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from htm import core
from htm import spec as test_spec
from htm.errors import SpecError
from htm.fatigue.data import CrackData, Setup
from htm.fatigue.laws import Model, fit_life

BAND = (5.0, 50.0, 95.0)


def setup_of(spec: test_spec.TestSpec) -> Setup:
    """The E647 setup (specimen, constant-amplitude load) of a one-phase constant-force test spec."""
    ph = spec.phases[-1]
    if len(spec.phases) != 1 or ph.mode != "constant_force":
        raise SpecError("life band: the base spec must be one constant_force loading (no precrack phase)")
    return Setup.from_loads(spec.geometry, spec.width_m, spec.thickness_m, delta_p_n=ph.delta_f_n, r_ratio=ph.r_ratio,
                            yield_strength_pa=spec.material["yield_strength_pa"])


def life_between(d: CrackData, a0_m: float, af_m: float) -> float | None:
    """Measured cycles from a0 to af (linear in a between points); None if the data do not span them."""
    if d.a_m[0] > a0_m + 1e-9 or d.a_m[-1] < af_m - 1e-9:
        return None
    return float(np.interp(af_m, d.a_m, d.cycles) - np.interp(a0_m, d.a_m, d.cycles))


def paris_fits(datas: list[CrackData], setup: Setup) -> list[Model]:
    """One Paris law per specimen, fitted by life: its N(a) integrated from the first point matches
    the measured one. Unlike `fit_life` no cycle offset is free, since a life prediction starts
    from a0 at N = 0 and an offset would hide part of the life's scatter from the law."""
    start = Model("paris", {"log10_c": -10.0, "m": 3.0})
    out = []
    for d in datas:
        m0 = fit_life("paris", [d], setup, start)
        span = float(d.cycles[-1] - d.cycles[0])

        def residual(x: np.ndarray, d: CrackData = d, span: float = span) -> np.ndarray:
            curve = Model("paris", {"log10_c": x[0], "m": x[1]}).life_curve(setup, d.a_m)
            r = (curve - (d.cycles - d.cycles[0])) / span
            return np.where(np.isfinite(r), r, 10.0)

        sol = least_squares(residual, [m0.params["log10_c"], m0.params["m"]], x_scale=[0.1, 0.05])
        res = residual(sol.x)
        out.append(Model("paris", {"log10_c": float(sol.x[0]), "m": float(sol.x[1])}, free=("log10_c", "m"),
                         fit={"method": "life_from_first_point", "rms_life_rel": float(np.sqrt(np.mean(res ** 2)))}))
    return out


BANDS = ("prediction", "specimens")
PROPOSAL_WIDTH = 2.0  # the campaign's normal: this times the predictive scale (variance), to cover the t's tails


@dataclass
class Joint:
    """Normal of (log10 C [SI: (m/cycle)/(Pa·√m)^m], m) across specimens, and the point scatter."""

    mean: np.ndarray
    cov: np.ndarray
    point_sigma_cycles: float
    n_specimens: int

    @property
    def corr(self) -> float:
        return float(self.cov[0, 1] / np.sqrt(self.cov[0, 0] * self.cov[1, 1]))

    @property
    def dof(self) -> int:
        """Degrees of freedom of the predictive t: n − 2 (two parameters)."""
        return self.n_specimens - 2

    @property
    def predictive_scale(self) -> np.ndarray:
        """Scale matrix of the predictive bivariate t for a new specimen: Σ̂·(n + 1)(n − 1)/(n(n − 2))."""
        n = self.n_specimens
        return self.cov * (n + 1) * (n - 1) / (n * (n - 2))

    def proposal(self) -> Joint:
        """The normal the campaign draws from for the prediction band (wider than the t)."""
        return Joint(self.mean, self.predictive_scale * PROPOSAL_WIDTH, self.point_sigma_cycles, self.n_specimens)

    def predictive_weights(self, x: np.ndarray) -> np.ndarray:
        """Importance weights (normalised) turning draws x [k, 2] of `proposal()` into draws of the
        predictive t: t density over the normal density."""
        from scipy import stats

        t = stats.multivariate_t(loc=self.mean, shape=self.predictive_scale, df=self.dof).logpdf(x)
        q = stats.multivariate_normal(mean=self.mean, cov=self.predictive_scale * PROPOSAL_WIDTH).logpdf(x)
        w = np.exp(t - q - np.max(t - q))
        return w / w.sum()


def joint(models: list[Model], datas: list[CrackData]) -> Joint:
    # the fits hold C per (MPa·√m)^m; the core's SI C is that × 1e-6^m, a linear map of (log10 C, m)
    x = np.array([[m.params["log10_c"] - 6.0 * m.params["m"], m.params["m"]] for m in models])
    spans = np.array([float(d.cycles[-1] - d.cycles[0]) for d in datas])
    rms = np.array([m.fit["rms_life_rel"] for m in models])
    return Joint(x.mean(axis=0), np.cov(x.T), float(np.median(rms * spans)), len(models))


def campaign_text(base: Path, j: Joint, samples: int, seed: int, name: str, chunk: int = 8) -> str:
    m, c = [float(v) for v in j.mean], [[float(v) for v in row] for row in j.cov]
    return (f'# generated by htm life-band: Monte Carlo of the life over the specimens\' Paris laws\n'
            f'[campaign]\nname = "{name}"\nbase = "{base.resolve()}"\nmode = "jump"\nchunk_tests = {chunk}\nseed = {seed}\n\n'
            f'[scatter]\nsamples = {samples}\n[scatter.joint]\nfields = ["law.c", "law.m"]\nlog10 = [true, false]\n'
            f'mean = [{m[0]!r}, {m[1]!r}]\ncov = [[{c[0][0]!r}, {c[0][1]!r}], [{c[1][0]!r}, {c[1][1]!r}]]\n')


def with_paris_base(spec_path: Path, out: Path) -> Path:
    """The base spec with a Paris law (its values are replaced by every draw), written beside the campaign."""
    doc = tomllib.loads(spec_path.read_text())
    doc = copy.deepcopy(doc)
    doc["law"] = {"law": "paris", "c": 1e-30, "m": 3.0}
    out.mkdir(parents=True, exist_ok=True)
    p = out / "base_spec.toml"
    p.write_text(_toml(doc))
    return p


def _toml(doc: dict, prefix: str = "") -> str:
    """A small TOML writer for spec documents (tables of numbers, strings, lists)."""
    lines, tables = [], []
    for k, v in doc.items():
        if isinstance(v, dict):
            tables.append((k, v))
        else:
            lines.append(f"{k} = {_value(v)}")
    out = "\n".join(lines) + ("\n" if lines else "")
    for k, v in tables:
        name = f"{prefix}{k}"
        out += f"\n[{name}]\n" + _toml(v, name + ".")
    return out


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    return repr(float(v)) if isinstance(v, float) else str(v)


def quantiles(life: np.ndarray, weights: np.ndarray | None = None) -> tuple[float, float, float]:
    """5 %, 50 %, 95 % of life (weighted: by the weights' cumulative sum)."""
    if weights is None:
        return tuple(float(q) for q in np.percentile(life, BAND))  # type: ignore[return-value]
    o = np.argsort(life)
    cw = np.cumsum(weights[o])
    cw /= cw[-1]
    return tuple(float(np.interp(q / 100.0, cw, life[o])) for q in BAND)  # type: ignore[return-value]


def early_weights(draws: list[dict[str, float]], early: CrackData, setup: Setup, a0_m: float, sigma_cycles: float) -> np.ndarray:
    """Importance weight of each draw (its "law.c", "law.m") given a running specimen's first points:
    Gaussian likelihood of the measured cycles at each early crack size against the draw's N(a)."""
    keep = early.a_m >= a0_m - 1e-9
    a, n = early.a_m[keep], early.cycles[keep] - float(np.interp(a0_m, early.a_m, early.cycles))
    if len(a) < 2:
        raise SpecError(f"early data: needs at least 2 points at or beyond a0 = {a0_m * 1e3:.2f} mm")
    grid = np.concatenate([[a0_m], a])
    logl = np.empty(len(draws))
    for i, d in enumerate(draws):
        law = {"law": "paris", "c": d["law.c"], "m": d["law.m"]}
        curve = core.life_curve(law, setup.geometry, setup.width_m, setup.thickness_m, setup.pmax_n, setup.r_ratio,
                                 np.ascontiguousarray(grid, float))[1:]
        # the residuals of one specimen's points are not independent (they follow its own curve): the
        # misfit counts as one observation, its mean square, not as many
        logl[i] = -0.5 * float(np.mean(((curve - n) / sigma_cycles) ** 2)) if np.all(np.isfinite(curve)) else -np.inf
    w = np.exp(logl - logl.max())
    return w / w.sum()


def effective_samples(w: np.ndarray) -> float:
    return float(1.0 / np.sum(w ** 2))


def first_points(d: CrackData, cycles: float) -> CrackData:
    """The points of `d` measured up to `cycles` (a running test's data so far)."""
    k = d.cycles <= cycles
    return CrackData(d.specimen, d.cycles[k], d.a_m[k])


def read_data(path: str | Path, a_mm_column: str | None = None) -> list[CrackData]:
    """A specimen set's a–N CSV (`read_a_n`), with a in mm in the column `a_mm_column` when it is
    not named a_mm (e.g. Virkler's a_half_crack_mm). A missing or unreadable file is a RecordError."""
    from htm.fatigue.data import read_a_n

    return read_a_n(path, a_mm_column)


def build(spec_path: Path, datas: list, hold_out: set[str], samples: int, seed: int, store: Any, runner: Any,
          out: Path, progress: bool, band: str = "prediction") -> dict[str, Any]:
    """Fit the specimens not held out, run the campaign, and return the band and what it rests on.

    band: ``"prediction"`` (a new specimen: the fit's uncertainty across specimens included, see the
    module's text) or ``"specimens"`` (the normal of the fitted specimens taken as known: the band
    before issue 33, too narrow on specimens it did not see)."""
    if band not in BANDS:
        raise SpecError(f"life band: band `{band}` is unknown: use {' or '.join(BANDS)}")
    from htm.campaign import engine
    from htm.campaign import spec as campaign_spec

    spec = test_spec.load(spec_path)
    setup = setup_of(spec)
    a0, af = spec.a0_m, spec.phases[-1].end_a_m
    fit_set = [d for d in datas if d.specimen not in hold_out]
    if len(fit_set) < 4:
        raise SpecError(f"life band: {len(fit_set)} specimens left to fit; at least 4 are needed (a prediction band "
                        "for a new specimen with two law parameters)")
    unknown = hold_out - {d.specimen for d in datas}
    if unknown:
        raise SpecError(f"--hold-out: no specimen {', '.join(sorted(unknown))} in the data")
    models = paris_fits(fit_set, setup)
    j = joint(models, fit_set)
    base = with_paris_base(spec_path, out)
    cpath = out / "campaign.toml"
    drawn = j.proposal() if band == "prediction" else j
    cpath.write_text(campaign_text(base, drawn, samples, seed, f"life-band-{spec.name}-{band}"))
    c = campaign_spec.load(cpath)
    s = engine.run(c, store, runner, progress=progress)
    rows = engine.table(store, c.id)
    ok = [r for r in rows if r["end_reason"] == "target_crack_length"]
    life = np.array([r["life_cycles"] for r in ok], float)
    if len(life) == 0:
        raise SpecError(f"life band: none of the {len(rows)} simulated tests reached a = {af * 1e3:.2f} mm")
    weights = None
    if band == "prediction":
        # draws that did not reach af are left out as for the specimens band (their number is reported)
        x = np.array([[np.log10(r["law.c"]), r["law.m"]] for r in ok])
        weights = j.predictive_weights(x)
    return {"campaign": c.id, "run": s, "setup": setup, "a0_m": a0, "af_m": af, "joint": j, "fit_set": fit_set,
            "rows": ok, "life": life, "weights": weights, "band_kind": band, "band": quantiles(life, weights),
            "effective_draws": effective_samples(weights) if weights is not None else float(len(life)),
            "tests_not_reaching_af": len(rows) - len(ok)}


def _prior(res: dict[str, Any]) -> np.ndarray:
    w = res.get("weights")
    return np.full(len(res["life"]), 1.0 / len(res["life"])) if w is None else w


def evaluate(res: dict[str, Any], held: list, early_fraction: float) -> list[dict[str, Any]]:
    """For each held-out specimen: its measured life against the band, and the early-data update
    from its points up to `early_fraction` of the band's median life."""
    lo, med, hi = res["band"]
    draws = [{"law.c": r["law.c"], "law.m": r["law.m"]} for r in res["rows"]]
    out = []
    for d in held:
        actual = life_between(d, res["a0_m"], res["af_m"])
        if actual is None:
            continue
        early = first_points(d, early_fraction * med)
        w = _prior(res) * early_weights(draws, early, res["setup"], res["a0_m"], res["joint"].point_sigma_cycles)
        w /= w.sum()
        ulo, umed, uhi = quantiles(res["life"], w)
        out.append({"specimen": d.specimen, "life": actual, "in_band": lo <= actual <= hi,
                    "err_no_update": (med - actual) / actual, "early_points": len(early.cycles),
                    "early_a_mm": float(early.a_m[-1] * 1e3), "updated": (ulo, umed, uhi),
                    "err_update": (umed - actual) / actual, "in_updated_band": ulo <= actual <= uhi,
                    "effective_draws": effective_samples(w)})
    return out


def update(res: dict[str, Any], early: CrackData) -> dict[str, Any]:
    """The band of `build`'s result updated from a running specimen's first points `early`:
    5 %, median, 95 % of the reweighted draws, the points used and the effective draws left."""
    draws = [{"law.c": r["law.c"], "law.m": r["law.m"]} for r in res["rows"]]
    w = _prior(res) * early_weights(draws, early, res["setup"], res["a0_m"], res["joint"].point_sigma_cycles)
    w /= w.sum()
    lo, med, hi = quantiles(res["life"], w)
    return {"p5": lo, "median": med, "p95": hi, "points": len(early.cycles), "effective_draws": effective_samples(w)}


def early_from_table(name: str, cycles: np.ndarray, a_m: np.ndarray, up_to_cycles: float | None = None,
                     max_points: int = 40) -> CrackData:
    """A test's a–N so far from its per-cycle table (store `cycles`: one row per cycle or jump): the
    first cycle at each new crack size, up to `up_to_cycles`, thinned to `max_points` evenly in cycles
    (the first and last kept). Too few points is a SpecError saying how many there are."""
    n, a = np.asarray(cycles, float), np.asarray(a_m, float)
    keep = np.isfinite(n) & np.isfinite(a)
    if up_to_cycles is not None:
        keep &= n <= up_to_cycles
    n, a = n[keep], a[keep]
    if len(a):
        grown = np.concatenate([[True], np.diff(a) > 0])  # the crack's first cycle at each size
        n, a = n[grown], a[grown]
    if len(a) < 2:
        where = f" up to {up_to_cycles:,.0f} cycles" if up_to_cycles is not None else ""
        raise SpecError(f"test {name}: {len(a)} a–N point{'s' * (len(a) != 1)} with a growing crack{where}; "
                        "the update needs at least 2")
    if len(a) > max_points:
        idx = np.unique(np.round(np.linspace(0, len(a) - 1, max_points)).astype(int))
        n, a = n[idx], a[idx]
    return CrackData(name, n, a)
