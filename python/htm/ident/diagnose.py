"""`diagnose`: fit the EFFECTS.md base model to a record by simulation error, then trace what it
still gets wrong to EFFECTS.md effects, keeping each only if it pays off on held-out data."""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from htm._core import Params
from htm.errors import RecordError
from htm.ident import features as ft
from htm.ident.records import Record, validate_record

FORMAT = "htm-diagnosis/1"
MIN_SAMPLES = 200
# Non-noise residual over the noise floor (features.systematic_ratio): the search stops at or
# below SYSTEMATIC; structure is reported unexplained above UNEXPLAINED (a clear margin).
SYSTEMATIC = 1.0
UNEXPLAINED = 1.5
# A refit must cut the held-out weighted cost by this fraction (and win by BIC) to count.
MIN_GAIN = 0.05
# Evidence a candidate's signature must carry before it is refitted (chi^2 units, fraction).
SCREEN_CHI2 = 25.0
SCREEN_FRACTION = 0.01
# Length of the interleaved fit/validation blocks (s).
BLOCK_S = 0.3
# Which of two effects that explain a record equally well is named (the more common first).
PREFERENCE = ("sensor_offset", "valve_null_bias", "sensor_gain", "sensor_delay", "valve_dynamics", "internal_leakage",
              "friction_asymmetry", "valve_deadband", "valve_hysteresis", "supply_pressure_sag",
              "pressure_dependent_friction", "entrained_air", "load_pressure_feedback", "specimen_nonlinearity")
# Distance (in normalised coordinates) from a bound at which a parameter counts as pinned.
PIN = 0.02
# A fit that pins a metadata parameter at its bound and still misses a channel by this many noise
# floors says the record is not of the stated rig.
RIG_MISS = 3.0
# A fit whose noise-scaled cost per residual falls below this is at the noise: stop iterating.
NOISE_COST = 1.2
# Largest LM step of any normalised coordinate (a factor e for a log parameter): far jumps land in
# wrong basins (friction trading against compressibility).
RADIUS_MAX = 1.0
# Candidates refitted per round: those whose screened gain is at least this share of the best.
REFIT_SHARE = 0.3
# The free run's own spread (`_loop_floor`): synthetic records of the fitted model, their seed,
# and the margin above the largest spread beyond which structure counts as unexplained.
LOOP_REALISATIONS, LOOP_SEED, LOOP_MARGIN = 3, 20261121, 3.0
# Least-squares budgets: Jacobians (one simulation per free parameter each, plus 3 trial steps).
BASE_ITERS, REFIT_ITERS, POLISH_ITERS = 10, 6, 15


DEBUG = False


class IdentificationError(RecordError):
    """The record cannot be identified (no excitation, wrong rig, too short): says why."""


# --------------------------------------------------------------------------- parameters
# Weak prior on the base parameters, as a share of the noise-level cost that a change of `prior`
# (normalised coordinates) costs: it gives the flat valleys (bulk modulus vs dead volumes)
# curvature without moving what the data determine.
PRIOR_SHARE = 0.003


@dataclass(frozen=True)
class Free:
    """One free parameter in normalised coordinates x: value = ref*exp(x) (log) or origin + unit*x."""

    key: str
    lo: float
    hi: float
    log: bool = False
    unit: float = 1.0
    step: float = 0.02  # finite-difference / screening step in x
    origin: float = 0.0  # the "effect off" value of a linear parameter (x = 0)
    prior: float = 0.0  # prior width in x around the nominal (0 = no prior)

    def value(self, x: float, ref: float) -> float:
        return ref * math.exp(x) if self.log else self.origin + self.unit * x

    def coord(self, value: float, ref: float) -> float:
        return math.log(value / ref) if self.log else (value - self.origin) / self.unit


def _set(p: Params, key: str, value: float) -> None:
    if key == "friction_coulomb_n":  # the base model's Coulomb friction is symmetric
        p["friction_coulomb_pos_n"] = value
        p["friction_coulomb_neg_n"] = value
    elif key == "friction_coulomb_diff_n":  # friction_asymmetry: pos = C + d, neg = C - d
        c = p["friction_coulomb_pos_n"]
        p["friction_coulomb_pos_n"] = max(0.0, c + value)
        p["friction_coulomb_neg_n"] = max(0.0, c - value)
    else:
        p[key] = value


def _get(p: Params, key: str) -> float:
    if key == "friction_coulomb_n":
        return 0.5 * (p["friction_coulomb_pos_n"] + p["friction_coulomb_neg_n"])
    if key == "friction_coulomb_diff_n":
        return 0.5 * (p["friction_coulomb_pos_n"] - p["friction_coulomb_neg_n"])
    return p[key]


@dataclass
class Model:
    """A parameter set: the nominal Params, the free parameters and their coordinates."""

    nominal: Params
    frees: list[Free]
    x: np.ndarray

    def params(self, x: np.ndarray | None = None) -> Params:
        x = self.x if x is None else x
        p = self.nominal.copy()
        for f, xi in zip(self.frees, x):
            _set(p, f.key, f.value(float(xi), _get(self.nominal, f.key) if f.log else 0.0))
        return p

    def unpinned(self, start: np.ndarray) -> "Model":
        """This model with parameters that sit at a bound moved back to `start`: a base parameter
        pinned at its bound was standing in for an effect the model lacked."""
        x = self.x.copy()
        for i, f in enumerate(self.frees[: len(start)]):
            if x[i] <= f.lo + PIN or x[i] >= f.hi - PIN:
                x[i] = start[i]
        return Model(self.nominal, self.frees, x)

    def with_candidate(self, cand: "Candidate", x0: float | None = None) -> "Model":
        """This model with a candidate effect added (its first parameter at x0, default its step)."""
        nominal = self.nominal
        if cand.switch:
            nominal = nominal.copy()
            for k, v in cand.switch:
                nominal[k] = v
        xs = [cand.frees[0].step if x0 is None else x0, *cand.starts] if cand.frees else []
        return Model(nominal, [*self.frees, *cand.frees], np.append(self.x, xs))

    def values(self) -> dict[str, float]:
        p = self.params()
        out: dict[str, float] = {}
        for f in self.frees:
            if f.key == "friction_coulomb_n":
                out["friction_coulomb_pos_n"] = p["friction_coulomb_pos_n"]
                out["friction_coulomb_neg_n"] = p["friction_coulomb_neg_n"]
            elif f.key != "friction_coulomb_diff_n":
                out[f.key] = p[f.key]
        if any(f.key == "friction_coulomb_diff_n" for f in self.frees):
            out["friction_coulomb_pos_n"] = p["friction_coulomb_pos_n"]
            out["friction_coulomb_neg_n"] = p["friction_coulomb_neg_n"]
        return out


# Base-model parameters stated by the metadata (nominal; bounds say how far a rig may be off).
RIG_FREES = [
    Free("moving_mass_kg", math.log(0.4), math.log(2.5), log=True, prior=0.3),
    Free("valve_rated_flow_m3_s", math.log(0.4), math.log(2.5), log=True, prior=0.3),
    Free("bulk_modulus_pa", math.log(0.4), math.log(2.5), log=True, prior=0.3),
    Free("dead_volume_a_m3", math.log(0.5), math.log(2.0), log=True, step=0.05, prior=0.3),
    Free("dead_volume_b_m3", math.log(0.5), math.log(2.0), log=True, step=0.05, prior=0.3),
    Free("supply_pressure_pa", math.log(0.5), math.log(1.5), log=True, step=0.01, prior=0.1),
]
# Friction and underlap are not in the metadata: wide bounds, wide priors.
OTHER_FREES = [
    Free("friction_viscous_n_s_m", math.log(0.02), math.log(20.0), log=True, step=0.05, prior=1.0),
    Free("friction_coulomb_n", math.log(0.02), math.log(20.0), log=True, step=0.05, prior=1.0),
    Free("friction_static_n", math.log(0.2), math.log(4.0), log=True, step=0.1, prior=0.5),
    Free("valve_underlap_v", 0.0, 5.0, unit=0.1, step=0.1, prior=1.0),
]


# --------------------------------------------------------------------------- candidates
@dataclass(frozen=True)
class Candidate:
    """An EFFECTS.md effect the model can take on: free parameters (the first is screened, the
    others start at `starts`) and/or a switch applied to the nominal parameters."""

    effect: str
    channel: str | None
    frees: tuple[Free, ...]
    feature: str  # the regressor whose correlation with the residual is the effect's signature
    starts: tuple[float, ...] = ()
    switch: tuple[tuple[str, float], ...] = ()

    def report(self, p: Params) -> dict[str, float]:
        from htm.ident.sim import effect_values

        return effect_values(p, self.effect, self.channel)

    @property
    def label(self) -> str:
        return self.effect + (f" on {self.channel}" if self.channel else "")


def _lin(key: str, unit: float, lo: float, hi: float, step: float = 1.0, origin: float = 0.0) -> Free:
    return Free(key, lo, hi, unit=unit, step=step, origin=origin)


def candidates(p: Params, rec: Record, channels: list[str], scales: dict[str, float], rate_hz: float) -> list[Candidate]:
    """Every effect the core can switch on for this record (sensor effects on its channels)."""
    out: list[Candidate] = []
    dt = 1.0 / rate_hz
    ctrl = (rec.meta.get("controller") or {}).get("type")
    for c in channels:
        # The loop regulates what its own sensor reads: an offset or gain of that sensor only moves
        # the true position, which nothing measures unless a specimen's force does.
        if (c, ctrl) in (("y", "position_pff"), ("f", "force_p")) and not (c == "y" and "f" in channels):
            out.append(Candidate("sensor_delay", c, (_lin(f"sensor_delay_{c}_s", dt, 0.0, 100.0),), f"d(predicted {c})/dt"))
            continue
        out += [
            Candidate("sensor_offset", c, (_lin(f"sensor_offset_{c}", scales[c], -1e3, 1e3),), "constant"),
            Candidate("sensor_gain", c, (_lin(f"sensor_gain_{c}", 0.01, -50.0, 50.0, origin=1.0),), f"predicted {c}"),
            Candidate("sensor_delay", c, (_lin(f"sensor_delay_{c}_s", dt, 0.0, 100.0),), f"d(predicted {c})/dt"),
        ]
    out += [
        Candidate("valve_null_bias", None, (_lin("valve_null_bias_v", 0.02, -50.0, 50.0),), "small |u|"),
        Candidate("valve_dynamics", None, (_lin("valve_tau_s", 1e-3, 0.0, 100.0, step=2.0),), "du/dt"),
        Candidate("valve_deadband", None, (_lin("valve_deadband_half_width_v", 0.05, 0.0, 40.0),), "small |u|"),
        Candidate("valve_hysteresis", None, (_lin("valve_hysteresis_half_width_v", 0.05, 0.0, 40.0),), "sign(du/dt)"),
        Candidate("supply_pressure_sag", None, (_lin("supply_resistance_pa_s_per_m3", 1e9, 0.0, 1e3),), "v"),
        Candidate("internal_leakage", None, (_lin("leakage_coeff_m3_per_s_pa", 1e-12, 0.0, 1e3),), "load pressure"),
        Candidate("friction_asymmetry", None, (_lin("friction_coulomb_diff_n", 50.0, -100.0, 100.0),), "sign(v)"),
        Candidate("pressure_dependent_friction", None, (_lin("friction_pressure_coeff_n_per_pa", 1e-6, 0.0, 1e3, step=2.0),),
                  "(p_a + p_b) sign(v)"),
        Candidate("entrained_air", None, (_lin("air_fraction", 1e-3, 0.0, 100.0, step=5.0),), "p_a + p_b"),
    ]
    if p["valve_linear_flow"] > 0.5:  # a declared linear valve may in truth feel the load pressure
        out.append(Candidate("load_pressure_feedback", None, (), "load pressure", switch=(("valve_linear_flow", 0.0),)))
    if p["specimen_stiffness_n_m"] > 0 and "f" in channels:
        # The closure position is not smooth to find: screen a few along the travel.
        k = p["specimen_stiffness_n_m"]
        y = np.asarray(rec.columns["y"], dtype=float)
        y0 = p["specimen_zero_force_position_m"]
        unit_off = max(1e-5, float(np.nanstd(y)) * 0.1)
        for q in (10, 30, 50, 70, 90):
            off = float(np.nanpercentile(y, q)) - y0
            out.append(Candidate("specimen_nonlinearity", "f",
                                 (_lin("specimen_closure_stiffness_n_m", 0.1 * k, 0.0, 1e3),
                                  _lin("specimen_closure_offset_m", unit_off, -1e4, 1e4)), "y", starts=(off / unit_off,)))
    return [c for c in out if all(f.key in p or f.key == "friction_coulomb_diff_n" for f in c.frees)]


# --------------------------------------------------------------------------- the fitting problem
@dataclass
class Problem:
    """A record, its channels and noise floors, the fit/validation split and a simulation count.

    Fits run on a working window (the record's first `work_s` seconds, the whole of a short
    record), on its interleaved fit blocks; everything else is held out for validation."""

    rec: Record
    channels: list[str]
    sigma: dict[str, float]
    weight: dict[str, float]
    n_work: int
    fit_mask: np.ndarray  # over the working window
    val_mask: np.ndarray  # over the whole record
    horizon_s: float | None = None
    command: bool = False  # predict from the recorded command even in closed loop (sim.predict)
    simulations: int = 0
    meas: dict[str, np.ndarray] = field(default_factory=dict)
    work: Record | None = None
    supply: np.ndarray | None = None

    def __post_init__(self) -> None:
        from htm.ident.sim import supply_schedule

        self.meas = {c: np.asarray(self.rec.columns[c], dtype=float) for c in self.channels}
        self.supply = supply_schedule(self.rec)  # once: a switched supply the model follows
        n = len(self.rec.columns["t"])
        self.work = self.rec if self.n_work >= n else Record({k: np.asarray(v)[: self.n_work] for k, v in self.rec.columns.items()},
                                                             self.rec.meta, self.rec.name)

    @property
    def truncated(self) -> bool:
        return self.work is not self.rec

    def predict(self, plist: list[Params], *, whole: bool = False) -> list[dict[str, np.ndarray]]:
        """Sensor readings predicted for each parameter set over the working window (or the whole record)."""
        from htm.ident.sim import predict

        self.simulations += len(plist)
        kw = {} if self.horizon_s is None else {"horizon_s": self.horizon_s}
        supply = self.supply if self.supply is None or whole else self.supply[: self.n_work]
        out = predict(plist, self.rec if whole else self.work, supply=supply, command=self.command, **kw)
        return [{c: np.asarray(pr[c], dtype=float) for c in self.channels} for pr in out]

    def whole(self, model: "Model", work_pred: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The whole-record prediction of a model whose working-window prediction is known."""
        return self.predict([model.params()], whole=True)[0] if self.truncated else work_pred

    def residual(self, pred: dict[str, np.ndarray], mask: np.ndarray) -> np.ndarray:
        """Weighted residual (prediction - measurement)/noise over `mask`, channels stacked;
        dropped samples count zero, a failed simulation counts as a huge error."""
        parts = []
        for c in self.channels:
            m = self.meas[c][: len(mask)]
            r = (pred[c] - m)[mask] / self.weight[c]
            bad = ~np.isfinite(r)
            if bad.any():
                r = np.where(np.isfinite(m[mask]), np.where(bad, 1e4, r), 0.0)
            parts.append(r)
        return np.concatenate(parts)

    def channel_ssr(self, pred: dict[str, np.ndarray], mask: np.ndarray) -> dict[str, tuple[float, int]]:
        """Per channel: weighted sum of squared residuals over `mask` and its sample count."""
        out = {}
        for c in self.channels:
            m = self.meas[c][: len(mask)]
            r = (pred[c] - m)[mask] / self.weight[c]
            ok = np.isfinite(m[mask])
            r = np.where(np.isfinite(r), r, 1e4)[ok]
            out[c] = (float(np.dot(r, r)), int(ok.sum()))
        return out

    def fit_cost(self, pred: dict[str, np.ndarray]) -> float:
        """Weighted cost over the fit blocks of a working-window prediction."""
        r = self.residual(pred, self.fit_mask)
        return float(r @ r)

    def ratios(self, pred: dict[str, np.ndarray], rate: float) -> dict[str, float]:
        """Per channel: low-passed residual RMS over the noise floor (whole-record prediction)."""
        return {c: ft.systematic_ratio(pred[c] - self.meas[c], self.sigma[c], rate) for c in self.channels}


def fit(prob: Problem, model: Model, *, iters: int, pred0: dict | None = None,
        ftol: float = 2e-3) -> tuple[Model, dict, np.ndarray]:
    """Bounded Levenberg-Marquardt on the weighted fit-segment residual over the model's free
    parameters: forward-difference Jacobians (one batch of simulations), then three damping
    levels tried at once (one more batch). At most `iters` Jacobians; stops when an iteration
    gains less than `ftol` of the cost. `pred0`: the model's working-window prediction, if known.
    Returns the fitted model, its working-window prediction and the Jacobian there."""
    lo = np.array([f.lo for f in model.frees])
    hi = np.array([f.hi for f in model.frees])
    steps = np.array([f.step for f in model.frees])
    x = np.clip(model.x, lo, hi)
    at = Model(model.nominal, model.frees, x)
    pred = pred0 if pred0 is not None and np.array_equal(x, model.x) else prob.predict([at.params()])[0]
    r_data = prob.residual(pred, prob.fit_mask)
    n_data = len(r_data)
    # Prior rows: sqrt(W) (x - x_nominal) / width, W a small share of the noise-level cost.
    has = np.array([f.prior > 0 for f in model.frees])
    width = np.array([f.prior if f.prior > 0 else 1.0 for f in model.frees])
    x_nom = np.array([0.0 if f.log else f.coord(_get(model.nominal, f.key), 0.0) for f in model.frees])
    wp = math.sqrt(PRIOR_SHARE * n_data) * has / width

    def full(rd: np.ndarray, xx: np.ndarray) -> np.ndarray:
        return np.concatenate([rd, wp * (xx - x_nom)])

    r = full(r_data, x)
    cost = float(r @ r)
    lam, radius = 1e-2, 0.5  # damping; largest step of any normalised coordinate
    small = 0  # iterations in a row that gained less than ftol
    jac = np.zeros((n_data, len(x)))
    for _ in range(iters):
        hs = np.where(x + steps <= hi, steps, -steps)  # step inwards at an upper bound
        preds = prob.predict([Model(model.nominal, model.frees, x + h * e).params() for h, e in zip(hs, np.eye(len(x)))])
        jac = np.column_stack([(prob.residual(pr, prob.fit_mask) - r[:n_data]) / h for pr, h in zip(preds, hs)])
        jfull = np.vstack([jac, np.diag(wp)])
        g = jfull.T @ r
        # Parameters at a bound that the gradient pushes outward stay put.
        free = ~(((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0)))
        jtj = jfull.T @ jfull
        # A linear parameter far from its origin may move in proportion to its size (air at 50
        # units would otherwise crawl one unit per iteration); a log parameter moves by `radius`.
        reach = np.array([1.0 if f.log else max(1.0, 0.5 * abs(xi)) for f, xi in zip(model.frees, x)])
        d = np.maximum(np.diag(jtj), 1e-12 * max(1.0, float(np.max(np.diag(jtj)))))
        improved = False
        for _retry in range(3):
            lams = [lam * 0.1, lam, lam * 10]
            trials = []
            for lm in lams:
                step = np.zeros_like(x)
                a = jtj[np.ix_(free, free)] + lm * np.diag(d[free])
                try:
                    step[free] = np.linalg.solve(a, -g[free])
                except np.linalg.LinAlgError:
                    step[free] = -g[free] / (lm * d[free])
                big = float(np.max(np.abs(step) / reach))
                if big > radius:
                    step *= radius / big
                trials.append(np.clip(x + step, lo, hi))
            tpreds = prob.predict([Model(model.nominal, model.frees, xt).params() for xt in trials])
            tres = [full(prob.residual(tp, prob.fit_mask), xt) for tp, xt in zip(tpreds, trials)]
            tcost = [float(tr @ tr) for tr in tres]
            k = int(np.argmin(tcost))
            if tcost[k] < cost:
                gain = (cost - tcost[k]) / cost
                if np.max(np.abs(trials[k] - x) / reach) >= 0.99 * radius:
                    radius = min(RADIUS_MAX, 2.0 * radius)  # the step was capped and still good: widen
                x, pred, r, cost, lam = trials[k], tpreds[k], tres[k], tcost[k], max(lams[k] * (0.3 if k == 0 else 1.0), 1e-7)
                improved = True
                break
            lam *= 100.0
            radius *= 0.25
        if DEBUG:
            print(f"    LM cost {cost:.6g} lam {lam:.3g} radius {radius:.3g} free {int(free.sum())}/{len(x)} improved {improved}")
        small = 0 if improved and gain >= ftol else small + 1
        if not improved or small >= 2 or _at_noise(r[:n_data], len(prob.channels)):
            break  # stalled, or down to the noise on every channel
    return Model(model.nominal, model.frees, x), pred, jac


def _at_noise(r_data: np.ndarray, n_channels: int) -> bool:
    """Is the noise-scaled residual at the noise on every channel? (Judged per channel: one
    channel's systematic misfit must not hide among channels that are at their floor.)"""
    per = r_data.reshape(n_channels, -1)
    return bool(np.max(np.mean(per * per, axis=1)) < NOISE_COST)


# --------------------------------------------------------------------------- diagnosis
def _blocks(n_work: int, n: int, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Fit mask over the working window (the even ones of interleaved ~0.3 s blocks) and
    validation mask over the whole record (the odd blocks and all beyond the window). Short
    blocks put every phase of the experiment (holds, ramps, sines, steps) on both sides."""
    nblk = int(max(2, n_work / (BLOCK_S * rate_hz)))
    fit_mask = (np.arange(n_work) * nblk // n_work) % 2 == 0
    val_mask = np.ones(n, bool)
    val_mask[:n_work] = ~fit_mask
    return fit_mask, val_mask


def _rmse(prob: Problem, pred: dict[str, np.ndarray]) -> dict[str, float]:
    out = {}
    for c in prob.channels:
        r = np.asarray(pred[c], dtype=float) - prob.meas[c]
        r = r[np.isfinite(prob.meas[c])]
        out[c] = float(np.sqrt(np.mean(r**2))) if np.all(np.isfinite(r)) else float("nan")
    return out


def _bic_delta(prob: Problem, before: dict, after: dict, extra: int) -> tuple[float, float]:
    """ΔBIC of adding `extra` parameters on the validation samples (per-channel Gaussian
    likelihoods with unknown variance) and the relative change of the weighted validation cost."""
    s0 = prob.channel_ssr(before, prob.val_mask)
    s1 = prob.channel_ssr(after, prob.val_mask)
    n_all = sum(n for _, n in s0.values())
    d = sum(n * math.log(max(s1[c][0], 1e-300) / max(s0[c][0], 1e-300)) for c, (_, n) in s0.items())
    tot0 = sum(v for v, _ in s0.values())
    tot1 = sum(v for v, _ in s1.values())
    return d + extra * math.log(max(n_all, 2)), (tot1 - tot0) / max(tot0, 1e-300)


def _check_excitation(rec: Record, sigma: dict[str, float]) -> None:
    y = np.asarray(rec.columns["y"], dtype=float)
    u = np.asarray(rec.columns["u"], dtype=float)
    span_y = float(np.nanmax(y) - np.nanmin(y))
    span_u = float(np.nanmax(u) - np.nanmin(u))
    stroke = float((rec.meta.get("rig") or {}).get("stroke_m") or 0.0)
    if span_y < max(50 * sigma["y"], 1e-4 * stroke):
        raise IdentificationError(
            f"cannot identify `{rec.name}`: no excitation — position y moves only {span_y:.3g} m "
            f"(noise {sigma['y']:.2g} m) and command u spans {span_u:.3g} V; record a moving experiment "
            "(ramps, sines, steps)")


def diagnose(rec: Record, *, out_dir: str | Path | None = None, max_findings: int = 3, max_refits: int = 2,
             work_s: float = 20.0, horizon_s: float | None = None, verbose: bool = False,
             stats: dict[str, Any] | None = None) -> dict[str, Any]:
    """Diagnose a record: base-model fit, residual diagnostics, effects kept only if they pay off
    on held-out segments. Returns the report.json content (DATA_FORMAT.md); with `out_dir` also
    writes report.json, predictions.csv, report.md and plots there. `stats`, if given, receives
    `simulations`, `seconds`, per-channel `noise_floor` and `systematic_ratio` and the whole-record
    predictions `before`/`after` (SI arrays per channel).

    Fits use the first `work_s` seconds (interleaved fit/validation blocks); the rest of a longer
    record is held out too.

    Raises IdentificationError ("cannot identify ...: why") for a record that carries no
    information (too short, no excitation) or that does not belong to its metadata's rig.
    """
    from htm.ident.sim import closed_loop, params_from_meta

    t_start = time.perf_counter()
    try:
        validate_record(rec, min_samples=MIN_SAMPLES)
    except RecordError as e:
        raise IdentificationError(f"cannot identify: {e}") from None
    rate = float(rec.meta.get("sample_rate_hz") or 1.0 / float(np.median(np.diff(rec.columns["t"]))))
    channels = ft.measured_channels(rec.columns)
    # A declared sensor noise (datasheet) is the floor; else it is estimated from the record.
    sigma = {c: ft.declared_noise(rec.meta, c) or ft.noise_floor(rec.columns[c], ft.declared_resolution(rec.meta, c))
             for c in channels}
    _check_excitation(rec, sigma)
    scales = {c: max(sigma[c] * 10, 1e-6 * float(np.nanmax(np.abs(rec.columns[c])) or 1.0)) for c in channels}
    weight = dict(sigma)
    n = len(rec.columns["t"])
    n_work = min(n, int(round(work_s * rate)))
    fit_mask, val_mask = _blocks(n_work, n, rate)
    prob = Problem(rec, channels, sigma, weight, n_work, fit_mask, val_mask, horizon_s=horizon_s)
    log: Callable[..., None] = (lambda *a: print(f"[{time.perf_counter() - t_start:6.1f}s {prob.simulations:4d} sims]", *a)) if verbose else (lambda *a: None)

    nominal = params_from_meta(rec.meta)
    if "p_s" in channels:  # a measured supply starts the fit at what the gauge reads at rest
        nominal["supply_pressure_pa"] = float(np.nanpercentile(rec.columns["p_s"], 90))
    frees = [f for f in RIG_FREES + OTHER_FREES if f.key in nominal or f.key == "friction_coulomb_n"]
    x0 = np.array([0.0 if f.log else f.coord(_get(nominal, f.key), 0.0) for f in frees])
    # A zero nominal friction term cannot be scaled: start it at a small value instead.
    for i, f in enumerate(frees):
        if f.log and _get(nominal, f.key) <= 0:
            raise IdentificationError(f"cannot identify: nominal {f.key} is {_get(nominal, f.key)}; need > 0")
    base = Model(nominal, frees, x0)

    pool = candidates(nominal, rec, channels, scales, rate)
    base, base_pred, model, pred, findings = _search(prob, rec, base, nominal, pool, rate, max_findings, max_refits, log)
    misfit = _rig_misfit(rec, prob, model, pred, rate)
    fitted_on = "closed loop" if closed_loop(rec) else "recorded command"
    floor = {c: 0.0 for c in channels} if misfit else _loop_floor(prob, model, pred, rate)
    unexplained = _unexplained(prob, pred, floor, rate)
    if closed_loop(rec) and np.isfinite(rec.columns["u"]).any() and (misfit or unexplained or max(floor.values()) > SYSTEMATIC):
        # The closed loop hunts on its own sensor noise (or the free-run fit is stuck): a free
        # run cannot follow the record's particular hunt, so its fit is not to be trusted. Fit
        # again by the prediction error from the recorded command (well posed however the loop
        # hunts), then judge that model by its free run as the record's contract asks.
        log("free run noise floor", {c: round(v, 2) for c, v in floor.items()}, "-> refit on the recorded command")
        cprob = Problem(rec, prob.channels, prob.sigma, prob.weight, prob.n_work, prob.fit_mask, prob.val_mask,
                        horizon_s=horizon_s, command=True)
        cbase, _, cmodel, cpred, cfind = _search(cprob, rec, Model(nominal, frees, x0), nominal, pool, rate,
                                                 max_findings, max_refits, log)
        free = _free_run(prob, rec, cbase, cmodel, cfind, rate)
        cfloor = _loop_floor(prob, cmodel, free[2], rate)
        why = ("the fitted closed loop hunts on its sensor noise, so no free run follows the record's own hunt"
               if max(cfloor.values()) > SYSTEMATIC else "the free-run fit of the closed loop did not reach the record")
        for f in free[1]:
            f["evidence"] += f" Fitted on the recorded command ({why}); the errors are of the free-run closed loop."
        good = _rig_misfit(rec, cprob, cmodel, cpred, rate) is None and not _unexplained(prob, free[2], cfloor, rate)
        log("on the recorded command", [f["effect"] for f in free[1]], "explained" if good else "not explained")
        prob.simulations += cprob.simulations
        if good:
            base, base_pred, model, pred, findings = cbase, free[0], cmodel, free[2], free[1]
            misfit, unexplained, floor, fitted_on = None, False, cfloor, f"recorded command: {why}"
    if misfit:
        raise IdentificationError(misfit)
    ratios = prob.ratios(pred, rate)
    report: dict[str, Any] = {
        "format": FORMAT,
        "record": rec.name,
        "baseline": {"params": base.values(), "rmse": _rmse(prob, base_pred)},
        "findings": [{k: v for k, v in f.items() if not k.startswith("_")} for f in findings],
        "final": {"params": _final_params(model), "rmse": _rmse(prob, pred)},
        "unexplained": unexplained,
        "predictions": "predictions.csv",
    }
    if rec.meta.get("controller") is None:
        from htm.ident import sim

        report["horizon_s"] = horizon_s if horizon_s is not None else getattr(sim, "DEFAULT_HORIZON_S", None)
    log("done", report["final"]["rmse"], "unexplained" if unexplained else "")
    info = {"simulations": prob.simulations, "seconds": time.perf_counter() - t_start,
            "noise_floor": sigma, "systematic_ratio": ratios, "loop_floor": floor,
            "fitted_on": fitted_on}
    if out_dir is not None:
        from htm.ident.diagnose_report import write_diagnosis

        write_diagnosis(Path(out_dir), rec, report, base_pred, pred, findings, info)
    if stats is not None:
        stats.update(info, before=base_pred, after=pred, seconds=time.perf_counter() - t_start)
    return report


def _search(prob: Problem, rec: Record, base: Model, nominal: Params, pool: list[Candidate], rate: float,
            max_findings: int, max_refits: int,
            log: Callable[..., None]) -> tuple[Model, dict, Model, dict, list[dict[str, Any]]]:
    """Fit the base model, then add effects from `pool` while one pays off on the held-out data.
    Returns the baseline (model, whole-record prediction), the final (model, prediction) and
    the findings."""
    x0 = base.x.copy()
    base, work_pred, jac = fit(prob, base, iters=BASE_ITERS)
    base_pred = prob.whole(base, work_pred)
    log("baseline", {k: f"{v:.4g}" for k, v in base.values().items()}, _rmse(prob, base_pred))

    model, pred = base, base_pred
    findings: list[dict[str, Any]] = []
    kept_base = False
    for _round in range(max_findings + 2):
        if len(findings) >= max_findings:
            break
        ratios = prob.ratios(pred, rate)
        log("systematic ratios", {c: round(v, 2) for c, v in ratios.items()})
        if max(ratios.values()) <= SYSTEMATIC:
            break  # at the noise floor: nothing left to explain
        # The same budget without a new effect: a candidate must beat a model merely fitted longer.
        model, work_pred, jac = fit(prob, model, iters=REFIT_ITERS, pred0=work_pred)
        pred = prob.whole(model, work_pred)
        ratios = prob.ratios(pred, rate)
        log("refit without effect", {c: round(v, 2) for c, v in ratios.items()})
        if max(ratios.values()) <= SYSTEMATIC:
            break
        ranked = _screen(prob, model, work_pred, jac, pool)
        q = np.linalg.qr(jac)[0]  # what the base parameters can absorb, to first order
        log("screen", [(c.effect, c.channel, round(g, 3)) for c, g, _ in ranked[:6]])
        good: list[tuple[Candidate, dict, Model, dict, tuple]] = []
        better_base: tuple[float, Model] | None = None
        for cand, gain, step in ranked[:max_refits]:
            if gain < REFIT_SHARE * ranked[0][1]:
                break
            # Refit from the current fit and from the nominal base parameters (the current fit may
            # have bent them to stand in for this very effect), each at the best size of the
            # candidate's parameter; keep the better fit.
            restart = model.x.copy()
            restart[: len(x0)] = x0
            fits = [fit(prob, _scan(prob, [start.with_candidate(cand, step)], cand, q), iters=REFIT_ITERS)
                    for start in (model.unpinned(x0), Model(model.nominal, model.frees, restart))]
            fits.sort(key=lambda f: prob.fit_cost(f[1]))
            trial, twork, tjac = fits[0]
            tpred = prob.whole(trial, twork)
            verdict = _pays_off(prob, pred, trial, tpred, model, cand)
            log("refit", cand.label, cand.report(trial.params()), verdict)
            if verdict["ok"]:
                good.append((cand, verdict, trial, twork, fits[1]))
            elif verdict["dcost"] < -MIN_GAIN:
                # Not the effect but a better fit of the base parameters: remember those.
                cost = prob.fit_cost(twork)
                if better_base is None or cost < better_base[0]:
                    better_base = (cost, Model(model.nominal, trial.frees[: len(model.x)], trial.x[: len(model.x)]))
        if not good:
            if better_base is None or kept_base:
                break  # no candidate pays off on the held-out data
            kept_base = True  # once: a second time the search would only go round in circles
            model = better_base[1]
            work_pred = prob.predict([model.params()])[0]
            pred = prob.whole(model, work_pred)
            log("kept better base parameters")
            continue
        good.sort(key=lambda g: g[1]["dbic"])
        # Close contenders (e.g. an offset and a gain of the same sensor) are told apart polished.
        contenders = [g for g in good[:2] if g[1]["dbic"] <= 0.5 * good[0][1]["dbic"]]
        polished = []
        for cand, _, trial, twork, other in contenders:
            trial, twork, tjac = fit(prob, trial, iters=POLISH_ITERS, pred0=twork)
            again = trial.unpinned(x0)
            if not np.array_equal(again.x, trial.x):
                # Stuck with base parameters at a bound: polish once more from their nominal values.
                retry = fit(prob, again, iters=POLISH_ITERS)
                if prob.fit_cost(retry[1]) < prob.fit_cost(twork):
                    trial, twork, tjac = retry
            if not _at_noise(prob.residual(twork, prob.fit_mask), len(prob.channels)):
                # Still off the noise: the refit from the other start may be in the better basin
                # (the current fit's base parameters were bent by the missing effect).
                retry = fit(prob, other[0], iters=POLISH_ITERS, pred0=other[1])
                if prob.fit_cost(retry[1]) < prob.fit_cost(twork):
                    trial, twork, tjac = retry
            tpred = prob.whole(trial, twork)
            polished.append((cand, _pays_off(prob, pred, trial, tpred, model, cand), trial, twork, tjac, tpred))
        # Both at the noise floor: the record cannot tell them apart; name the more common effect
        # (EFFECTS.md order: an offset before a gain before a delay...) and say so.
        at_floor = [g for g in polished if max(prob.ratios(g[5], rate).values()) <= SYSTEMATIC]
        if len(at_floor) == 2:
            at_floor.sort(key=lambda g: PREFERENCE.index(g[0].effect) if g[0].effect in PREFERENCE else len(PREFERENCE))
            cand, verdict, trial, twork, tjac, tpred = at_floor[0]
            other = at_floor[1]
            verdict["alternative"] = (f" {other[0].label} ({', '.join(f'{k} = {v:.4g}' for k, v in other[0].report(other[2].params()).items())}) "
                                      "explains the record as well; this record cannot tell the two apart.")
        else:
            cand, verdict, trial, twork, tjac, tpred = min(polished, key=lambda g: g[1]["dbic"])
        pool = [c for c in pool if (c.effect, c.channel) != (cand.effect, cand.channel)]
        if not verdict["ok"]:
            # Polished, the effect no longer matters: keep the better-fitted model without it.
            k = len(model.x)
            model = Model(model.nominal, trial.frees[:k], trial.x[:k])
            work_pred = prob.predict([model.params()])[0]
            pred, jac = prob.whole(model, work_pred), tjac[:, :k]
            log("polished away", cand.label, verdict)
            continue
        if not findings:  # the baseline is the base model as fitted just before the first finding
            base, base_pred = model, pred
        findings.append(_finding(prob, rec, cand, model, pred, trial, tpred, verdict, rate))
        findings[-1].update(_before=model, _verdict=verdict)
        model, pred, work_pred, jac = trial, tpred, twork, tjac

    # Backward check: an earlier finding that the later ones make redundant is dropped.
    for f in list(findings[:-1]) if len(findings) > 1 else []:
        without = _without(model, f["_cand"], nominal)
        wmodel, wwork, wjac = fit(prob, without, iters=REFIT_ITERS)
        wpred = prob.whole(wmodel, wwork)
        dbic, dcost = _bic_delta(prob, wpred, pred, max(1, len(f["_cand"].frees)))
        log("backward check", f["_cand"].label, f"dBIC {dbic:.0f} dcost {dcost:+.3f}")
        if not (dbic < 0 and dcost < -MIN_GAIN):
            findings.remove(f)
            model, pred, work_pred, jac = wmodel, wpred, wwork, wjac
    if findings and findings[0]["_pred_before"] is not base_pred:
        first = findings[0]  # after a drop, the first remaining finding starts from the baseline
        first["_pred_before"] = base_pred
        first["rmse_before"] = _rmse(prob, base_pred)
    if not findings:
        base, base_pred = model, pred
    else:  # refits after the last finding belong to it: its "after" is the final model
        last = findings[-1]
        last["_pred_after"] = pred
        last["rmse_after"] = _rmse(prob, pred)
        last["params"] = last["_cand"].report(model.params())
    return base, base_pred, model, pred, findings


def _loop_floor(prob: Problem, model: Model, clean: dict[str, np.ndarray], rate: float) -> dict[str, float]:
    """Per channel: how far a free run of `model` (`clean`: its whole-record prediction) can be
    from a record of itself, as a systematic
    ratio — the largest over `LOOP_REALISATIONS` synthetic records (the model's run with white
    noise at the record's floors and its sensors' quantization in the loop) against the
    noise-free run. Near the white-noise level for a well-behaved loop; far above it when the loop
    hunts on its sensor noise (play), where no free run can follow one particular hunt. Zero for
    open-loop records (they are restarted from the measurement)."""
    from htm.ident.sim import closed_loop, predict

    if not closed_loop(prob.rec):
        return {c: 0.0 for c in prob.channels}
    n = len(prob.rec.columns["t"])
    p = model.params()
    quantum = {c: ft.declared_resolution(prob.rec.meta, c) or 0.0 for c in prob.channels}
    rng = np.random.default_rng(LOOP_SEED)
    out = {c: 0.0 for c in prob.channels}
    for _ in range(LOOP_REALISATIONS):
        noise = {c: rng.normal(0.0, prob.sigma[c], n) for c in prob.channels}
        syn = predict([p], prob.rec, supply=prob.supply, noise=noise, quantum=quantum)[0]
        prob.simulations += 1
        for c in prob.channels:
            out[c] = max(out[c], ft.systematic_ratio(clean[c] - np.asarray(syn[c], dtype=float), prob.sigma[c], rate))
    return out


def _unexplained(prob: Problem, pred: dict[str, np.ndarray], floor: dict[str, float], rate: float) -> bool:
    """Systematic structure left: some channel's residual above UNEXPLAINED and above what the
    model's own free run varies by (`LOOP_MARGIN` x its loop floor)."""
    ratios = prob.ratios(pred, rate)
    return any(r > max(UNEXPLAINED, LOOP_MARGIN * floor[c]) for c, r in ratios.items())


def _free_run(prob: Problem, rec: Record, base: Model, model: Model, findings: list[dict[str, Any]],
              rate: float) -> tuple[dict, list[dict[str, Any]], dict]:
    """Findings made on the recorded command, restated by free runs of the closed loop (the
    record's contract): the baseline's prediction, the findings with the errors just before and
    after each (the model before the next finding, the final model after the last) and the final
    prediction."""
    chain = [base] + [f["_before"] for f in findings[1:]] + [model]
    preds = prob.predict([m.params() for m in chain], whole=True)
    out = []
    for i, f in enumerate(findings):
        g = _finding(prob, rec, f["_cand"], chain[i], preds[i], chain[i + 1], preds[i + 1], f["_verdict"], rate)
        g["params"] = f["params"]
        out.append(g)
    return preds[0], out, preds[-1]


def _final_params(model: Model) -> dict[str, float]:
    vals = model.values()
    return vals


def _scan(prob: Problem, starts: list[Model], cand: Candidate, q: np.ndarray) -> Model:
    """The best start for a refit among `starts` and a few sizes of the candidate's first
    parameter (its cost is not convex for a delay, a dead band or play): one batch of simulations,
    each judged by the cost left once the base parameters absorb what they can (columns `q`)."""
    models = list(starts)
    if cand.frees:
        f = cand.frees[0]
        i = len(starts[0].x) - len(cand.frees)
        x_lin = starts[0].x[i]
        sign = -1.0 if x_lin < 0 else 1.0
        values = sorted({float(np.clip(v, f.lo, f.hi)) for v in (sign * f.step * 2.0**k for k in range(-1, 7))} - {x_lin})
        for start in starts:
            for v in values:
                x = start.x.copy()
                x[i] = v
                models.append(Model(start.nominal, start.frees, x))
    preds = prob.predict([m.params() for m in models])
    costs = []
    for p in preds:
        r = prob.residual(p, prob.fit_mask)
        r = r - q @ (q.T @ r)
        costs.append(float(r @ r))
    return models[int(np.argmin(costs))]


def _without(model: Model, cand: Candidate, nominal: Params) -> Model:
    """`model` with an accepted effect taken out (its parameters removed, its switch undone)."""
    nom = model.nominal
    if cand.switch:
        nom = nom.copy()
        for k, _ in cand.switch:
            nom[k] = nominal[k]
    if not cand.frees:
        return Model(nom, model.frees, model.x)
    i = model.frees.index(cand.frees[0])
    j = i + len(cand.frees)
    return Model(nom, model.frees[:i] + model.frees[j:], np.concatenate([model.x[:i], model.x[j:]]))


def _ablated(trial: Model, before: Model, cand: Candidate) -> Model:
    """`trial` with the candidate effect switched off (its parameters at their off value)."""
    x = trial.x.copy()
    x[len(before.x):] = 0.0
    return Model(before.nominal if cand.switch else trial.nominal, trial.frees, x)


def _pays_off(prob: Problem, pred0: dict, trial: Model, tpred: dict, before: Model, cand: Candidate) -> dict[str, Any]:
    """Does the effect pay off on the held-out data? It must beat the model without it by the
    information criterion and by MIN_GAIN of the cost, and so must it against its own refit
    with the effect switched off (else it only helped the base parameters converge)."""
    k = max(1, len(cand.frees))
    dbic, dcost = _bic_delta(prob, pred0, tpred, k)
    abl = prob.predict([_ablated(trial, before, cand).params()], whole=True)[0]
    abic, acost = _bic_delta(prob, abl, tpred, k)
    ok = dbic < 0 and dcost < -MIN_GAIN and abic < 0 and acost < -MIN_GAIN
    return {"ok": bool(ok), "dbic": dbic, "dcost": dcost, "ablation_dcost": acost}


def _screen(prob: Problem, model: Model, work_pred: dict, jac: np.ndarray,
            pool: list[Candidate]) -> list[tuple[Candidate, float, float | None]]:
    """Rank candidates by how much of the fit residual their simulated signature explains beyond
    what the current free parameters absorb (a linearised score test, one simulation each).
    Returns (candidate, explained fraction of the cost, starting value of its first parameter),
    best first, one entry per effect and channel."""
    r0 = prob.residual(work_pred, prob.fit_mask)
    cost = float(r0 @ r0)
    trials = [model.with_candidate(c) for c in pool]
    preds = prob.predict([t.params() for t in trials])
    q = np.linalg.qr(jac)[0] if jac.size else np.zeros((len(r0), 0))
    pr = r0 - q @ (q.T @ r0)
    best: dict[tuple[str, str | None], tuple[Candidate, float, float | None]] = {}
    for c, t, p in zip(pool, trials, preds):
        s = prob.residual(p, prob.fit_mask) - r0
        if not np.all(np.isfinite(s)) or not np.any(s):
            continue
        # Two readings of the signature: beyond what the base parameters absorb (projected), and
        # on its own (the current fit may have bent the base parameters to mimic the effect).
        for sig, res in ((s - q @ (q.T @ s), pr), (s, r0)):
            ss = float(sig @ sig)
            if ss <= 0:
                continue
            if c.frees:  # best linear step along the signature, within the bounds
                h = c.frees[0].step
                step = float(np.clip(-float(sig @ res) / ss * h, c.frees[0].lo, c.frees[0].hi))
                e = res + sig * (step / h)
            else:  # a switch: all or nothing
                step, e = None, res + sig
            gain = float(res @ res - e @ e)
            key = (c.effect, c.channel)
            if gain > SCREEN_CHI2 and gain > SCREEN_FRACTION * cost and (key not in best or gain / cost > best[key][1]):
                best[key] = (c, gain / cost, step)
    return sorted(best.values(), key=lambda g: -g[1])


def _finding(prob: Problem, rec: Record, cand: Candidate, before: Model, pred0: dict, after: Model, pred1: dict,
             verdict: dict[str, Any], rate: float) -> dict[str, Any]:
    rb, ra = _rmse(prob, pred0), _rmse(prob, pred1)
    # The channel the effect shows in: its own for a sensor effect, else the one it improves most.
    ch = cand.channel or min(prob.channels, key=lambda c: ra[c] / rb[c] if rb[c] > 0 else 1.0)
    resid = np.asarray(pred0[ch]) - prob.meas[ch]
    regs = ft.regressors(rec.columns, rate)
    if cand.feature.startswith("predicted"):
        regs[cand.feature] = np.asarray(pred0[ch], dtype=float)
    if cand.feature.startswith("d(predicted"):
        regs[cand.feature] = np.gradient(np.asarray(pred0[ch], dtype=float))
    corr = ft.correlations(resid, {cand.feature: regs[cand.feature]}).get(cand.feature, float("nan"))
    unit = ft.UNITS[ch]
    what = "mean/RMS" if cand.feature == "constant" else f"correlation with {cand.feature}"
    params = cand.report(after.params())
    ptxt = ", ".join(f"{k} = {v:.4g}" for k, v in params.items())
    evidence = (f"Before: the {ch} residual (RMS {rb[ch]:.3g} {unit}, noise floor {prob.sigma[ch]:.2g} {unit}) has "
                f"{what} {corr:+.2f}. Adding {cand.effect}{f' on {ch}' if cand.channel else ''} ({ptxt}) brings it to "
                f"{ra[ch]:.3g} {unit} and cuts the held-out cost by {-verdict['dcost']:.0%} (ΔBIC {verdict['dbic']:.0f}); "
                f"Switched off again, other parameters kept, the held-out cost would be "
                f"{1 / max(1 + verdict['ablation_dcost'], 1e-9):.3g}x higher." + verdict.get("alternative", ""))
    return {
        "effect": cand.effect,
        "channel": cand.channel,
        "params": params,
        "rmse_before": rb,
        "rmse_after": ra,
        "evidence": evidence,
        "_pred_before": pred0,
        "_pred_after": pred1,
        "_focus": ch,
        "_cand": cand,
        # An offset shows best against the reading itself (a shift; a gain would be a slope).
        "_feature": (f"measured {ch}", prob.meas[ch]) if cand.feature == "constant" else (cand.feature, regs[cand.feature]),
    }


def _rig_misfit(rec: Record, prob: Problem, base: Model, pred: dict, rate: float) -> str | None:
    """Why the record is not of its metadata's rig, or None: rig parameters pinned at their
    bounds while the residual stays far above the noise floor."""
    pinned = [f.key for f, x in zip(base.frees, base.x) if f in RIG_FREES and (x <= f.lo + PIN or x >= f.hi - PIN)]
    ratios = prob.ratios(pred, rate)
    worst = max(ratios, key=ratios.get)
    if not (pinned and ratios[worst] > RIG_MISS):
        return None
    vals = base.values()
    return (f"cannot identify `{rec.name}`: the record does not match its metadata's rig — the model fit pins "
            + ", ".join(f"{k} = {vals[k]:.4g} (nominal {_get(base.nominal, k):.4g})" for k in pinned)
            + f" at its bound and still misses {worst} by {ratios[worst]:.0f}x its noise floor, and no EFFECTS.md effect "
            "closes the gap; check the `rig` metadata (or the record holds an effect outside the table)")
