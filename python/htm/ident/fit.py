"""Fitting a model to a record by simulation error: the problem (record, channels, noise floors,
interleaved fit/validation blocks, the family's simulator) and a bounded Levenberg-Marquardt fit
whose Jacobians and trial steps are batches of simulations (run in parallel by the core)."""
from __future__ import annotations

import math
import threading
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from htm.errors import RecordError
from htm.ident import features as ft
from htm.ident.model import Model
from htm.ident.records import Record
from htm.ident.settings import DEFAULT, SearchSettings

# The knobs live in `settings.SearchSettings` (unit and reason there); these names are its defaults.
BLOCK_S = DEFAULT.block_s
NOISE_COST = DEFAULT.noise_cost
RADIUS_MAX = DEFAULT.radius_max
JACOBIAN_EVERY = DEFAULT.jacobian_every
PRIOR_SHARE = DEFAULT.prior_share
SIGNIFICANT = DEFAULT.significant

# Jacobians simulated in lockstep with their point (`Problem.lockstep`) when True. Off: with it
# on, matrix C's entrained_air record ends unexplained (a probe's fit, better converged, pays off
# by a hair) — the same record and finding otherwise. On the three paths of benchmarks/diagnose.py
# (in process, same run): the same findings, CPU 11.6/31.8/19.8 s alone vs 11.8/28.8/17.7 s in
# lockstep, rejected steps halved. `benchmarks/diagnose.py --lockstep` compares both in one run.
LOCKSTEP = False

# Predictions a problem keeps for parameter sets simulated again (`Problem.predict`): each is
# the record's channels over the working window or the whole record (a 60 s record at 500 Hz:
# ~1 MB), the most recently used kept.
CACHE_SIZE = 160

Predictor = Callable[..., list[dict[str, np.ndarray]]]


class Cache:
    """The most recently used `size` predictions by key (not thread-safe: the caller locks)."""

    def __init__(self, size: int) -> None:
        self.size = size
        self.items: OrderedDict[Any, dict[str, np.ndarray]] = OrderedDict()
        self.hits = 0

    def get(self, key: Any) -> dict[str, np.ndarray] | None:
        got = self.items.get(key)
        if got is not None:
            self.items.move_to_end(key)
            self.hits += 1
        return got

    def put(self, key: Any, value: dict[str, np.ndarray]) -> None:
        self.items[key] = value
        self.items.move_to_end(key)
        while len(self.items) > self.size:
            self.items.popitem(last=False)


def _key(params: Any) -> Any:
    """A parameter set as a hashable key (every field's exact value)."""
    d = params.to_dict() if hasattr(params, "to_dict") else params
    return tuple(sorted((k, repr(v)) for k, v in d.items())) if isinstance(d, dict) else repr(d)
# Problems are simulated from several threads at once (independent fits run side by side).
_COUNT = threading.Lock()
_POOL: ThreadPoolExecutor | None = None
# Simulations run by every problem of this process (per-stage counts: `trace.Stages`).
SIMULATIONS = [0]


def simulations_so_far() -> int:
    return SIMULATIONS[0]


def side_by_side(jobs: list[Callable[[], Any]]) -> list[Any]:
    """Run independent jobs (fits, simulations) side by side on threads and return their results
    in order. The core's simulations release the GIL and each batch already spreads over the
    cores, but a batch of one or three simulations leaves cores idle that another fit can use;
    each job computes exactly what it would alone (the linear algebra runs on one BLAS thread,
    the simulations are deterministic), so the results do not depend on the scheduling."""
    global _POOL
    if len(jobs) <= 1:
        return [j() for j in jobs]
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=4, thread_name_prefix="htm-fit")
    return [f.result() for f in [_POOL.submit(j) for j in jobs]]


@dataclass
class Problem:
    """A record, its channels and noise floors, the fit/validation split and the simulator.

    Fits run on a working window (the record's first `n_work` samples, the whole of a short
    record), on its interleaved fit blocks; everything else is held out for validation.
    `simulate(plist, rec, **opts)` returns each parameter set's sensor readings; per-sample arrays
    in `opts` are cut to the working window with the record."""

    rec: Record
    simulate: Predictor
    channels: list[str]
    sigma: dict[str, float]
    n_work: int
    fit_mask: np.ndarray  # over the working window
    val_mask: np.ndarray  # over the whole record
    opts: dict[str, Any] = field(default_factory=dict)
    sparse: bool = False  # fits simulate only the fit samples (open loop / command: restarts make them independent)
    centred: tuple[str, ...] = ()  # channels whose fit residual has its mean taken out (an offset profiled out)
    simulations: int = 0
    meas: dict[str, np.ndarray] = field(default_factory=dict)
    work: Record | None = None
    settings: SearchSettings = DEFAULT
    # Jacobian columns simulated in lockstep with the point (`sim.predict`'s `lockstep`: the
    # neighbours take the point's integrator step sizes, so that the columns are free of
    # step-size noise — the worst column's error against rtol 1e-7 columns 5 % -> 0.4 % on p_a in
    # benchmarks/replay_speed.py). Default `LOCKSTEP`; turned off for good the first time the
    # simulator refuses the option (the displacement loop).
    lockstep: bool = field(default_factory=lambda: LOCKSTEP)
    cache: "Cache" = field(default_factory=lambda: Cache(CACHE_SIZE), repr=False)

    def __post_init__(self) -> None:
        self.meas = {c: np.asarray(self.rec.columns[c], dtype=float) for c in self.channels}
        n = len(self.rec.columns["t"])
        self.work = self.rec if self.n_work >= n else Record(
            {k: np.asarray(v)[: self.n_work] for k, v in self.rec.columns.items()}, self.rec.meta, self.rec.name)

    def variant(self, **opts: Any) -> "Problem":
        """The same problem simulated with other options (e.g. on the recorded command)."""
        return Problem(self.rec, self.simulate, self.channels, self.sigma, self.n_work, self.fit_mask, self.val_mask,
                       {**self.opts, **opts}, self.sparse, settings=self.settings, lockstep=self.lockstep)

    @property
    def truncated(self) -> bool:
        return self.work is not self.rec

    def predict(self, plist: list[Any], *, whole: bool = False, **extra: Any) -> list[dict[str, np.ndarray]]:
        """Sensor readings predicted for each parameter set over the working window (or the whole
        record). A parameter set this problem has already simulated the same way (the same
        model re-predicted by a later stage, a stalled fit's point screened again) is taken from
        `cache` (the simulations are deterministic: the same readings, not simulated again)."""
        n = len(self.rec.columns["t"])
        opts = {**self.opts, **extra}
        if not whole and self.truncated:
            opts = {k: v[: self.n_work] if isinstance(v, np.ndarray) and len(v) == n else v for k, v in opts.items()}
        if not whole and self.sparse:
            opts["active"] = self.fit_mask
        keys = [(whole, _key(p)) for p in plist] if not extra else [None] * len(plist)
        with _COUNT:
            known = [self.cache.get(k) if k is not None else None for k in keys]
        todo = [i for i, k in enumerate(known) if k is None]
        out = self.simulate([plist[i] for i in todo], self.rec if whole else self.work, **opts) if todo else []
        fresh = [{c: np.asarray(pr[c], dtype=float) for c in self.channels} for pr in out]
        with _COUNT:
            self.simulations += len(todo)
            SIMULATIONS[0] += len(todo)
            for i, pr in zip(todo, fresh):
                if keys[i] is not None:
                    self.cache.put(keys[i], pr)
        got = dict(zip(todo, fresh))
        return [dict(got[i]) if known[i] is None else dict(known[i]) for i in range(len(plist))]

    def neighbours(self, point: Any, plist: list[Any]) -> list[dict[str, np.ndarray]]:
        """Predictions of `plist`, parameter sets that each differ slightly from `point` (a
        Jacobian's finite-difference neighbours): run in lockstep with `point` where the
        simulator can (on its integrator step sizes; `point` simulated again beside them, once a
        thread, and counted once), else alone."""
        if self.lockstep and plist:
            try:
                return self.predict([point, *plist], lockstep=True)[1:]
            except (RecordError, TypeError):  # a simulator that takes no such option
                self.lockstep = False
        return self.predict(plist)

    def whole(self, model: Model, work_pred: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The whole-record prediction of a model whose working-window prediction is known."""
        return self.predict([model.params()], whole=True)[0] if self.truncated or self.sparse else work_pred

    def residual(self, pred: dict[str, np.ndarray], mask: np.ndarray) -> np.ndarray:
        """Weighted residual (prediction - measurement)/noise over `mask`, channels stacked;
        dropped samples count zero, a failed simulation counts as a huge error."""
        parts = []
        for c in self.channels:
            m = self.meas[c][: len(mask)]
            r = (pred[c] - m)[mask] / self.sigma[c]
            bad = ~np.isfinite(r)
            if bad.any():
                r = np.where(np.isfinite(m[mask]), np.where(bad, 1e4, r), 0.0)
            if c in self.centred:
                r = r - float(np.mean(r))
            parts.append(r)
        return np.concatenate(parts)

    def channel_ssr(self, pred: dict[str, np.ndarray], mask: np.ndarray) -> dict[str, tuple[float, int]]:
        """Per channel: weighted sum of squared residuals over `mask` and its sample count."""
        out = {}
        for c in self.channels:
            m = self.meas[c][: len(mask)]
            r = (pred[c] - m)[mask] / self.sigma[c]
            ok = np.isfinite(m[mask])
            r = np.where(np.isfinite(r), r, 1e4)[ok]
            out[c] = (float(np.dot(r, r)), int(ok.sum()))
        return out

    def fit_cost(self, pred: dict[str, np.ndarray]) -> float:
        """Cost over the fit blocks of a working-window prediction: `likelihood_cost` of its
        noise-scaled residual."""
        return likelihood_cost(self.residual(pred, self.fit_mask), len(self.channels))

    def ratios(self, pred: dict[str, np.ndarray], rate: float) -> dict[str, float]:
        """Per channel: low-passed residual RMS over the noise floor (whole-record prediction)."""
        return {c: ft.systematic_ratio(pred[c] - self.meas[c], self.sigma[c], rate) for c in self.channels}

    def rmse(self, pred: dict[str, np.ndarray]) -> dict[str, float]:
        """Per channel RMS of prediction - measurement over the measured samples (SI)."""
        out = {}
        for c in self.channels:
            r = np.asarray(pred[c], dtype=float) - self.meas[c]
            r = r[np.isfinite(self.meas[c])]
            out[c] = float(np.sqrt(np.mean(r**2))) if np.all(np.isfinite(r)) else float("nan")
        return out

    def bic_delta(self, before: dict, after: dict, extra: int) -> tuple[float, float]:
        """ΔBIC of adding `extra` parameters on the validation samples (per-channel Gaussian
        likelihoods with unknown variance) and the relative change of the weighted validation cost."""
        s0 = self.channel_ssr(before, self.val_mask)
        s1 = self.channel_ssr(after, self.val_mask)
        n_all = sum(n for _, n in s0.values())
        d = sum(n * math.log(max(s1[c][0], 1e-300) / max(s0[c][0], 1e-300)) for c, (_, n) in s0.items())
        # The relative change as the likelihood sees it: per channel the mean square over the
        # noise (floored at the noise: no gain below it), averaged in logarithm over the samples.
        floor = sum(n * math.log(max(s1[c][0] / max(n, 1), 1.0) / max(s0[c][0] / max(n, 1), 1.0)) for c, (_, n) in s0.items())
        return d + extra * math.log(max(n_all, 2)), math.exp(floor / max(n_all, 1)) - 1.0

    def explained(self, before: dict, after: dict, only: str | None = None) -> float:
        """The largest share, over the channels (or channel `only`), of the validation residual's
        systematic part (its mean square above the noise) that going from `before` to `after` removes."""
        s0 = self.channel_ssr(before, self.val_mask)
        s1 = self.channel_ssr(after, self.val_mask)
        # A channel counts only where its mean square stands above the noise's by more than white
        # noise's own scatter (SIGNIFICANT standard deviations, sqrt(2/n) each): at the floor there
        # is no systematic part to share, and a sliver of it would read as a huge share.
        shares = [(s0[c][0] - s1[c][0]) / n / (s0[c][0] / n - 1.0) for c, (_, n) in s0.items()
                  if n > 0 and only in (None, c) and s0[c][0] / n - 1.0 > self.settings.significant * np.sqrt(2.0 / n)]
        return max(shares, default=0.0)

    def explained_in_band(self, before: dict, after: dict, f_hz: float, rate: float) -> float:
        """The largest share, over the channels, of the residual's power within a narrow band
        around `f_hz` (a few 1/duration wide) that going from `before` to `after` removes (whole
        record, dropped samples as zero)."""
        n = len(self.rec.columns["t"])
        freqs = np.fft.rfftfreq(n, 1.0 / rate)
        band = np.abs(freqs - f_hz) <= max(4.0 * rate / n, 0.5)
        shares = []
        for c in self.channels:
            p0, p1 = (float(np.sum(np.abs(np.fft.rfft(np.nan_to_num(np.asarray(p[c], dtype=float) - self.meas[c])))[band] ** 2))
                      for p in (before, after))
            if p0 > 0:
                shares.append(1.0 - p1 / p0)
        return max(shares, default=0.0)


def blocks(n_work: int, n: int, rate_hz: float, block_s: float = BLOCK_S) -> tuple[np.ndarray, np.ndarray]:
    """Fit mask over the working window (the even ones of interleaved `block_s` blocks) and
    validation mask over the whole record (the odd blocks and all beyond the window)."""
    nblk = int(max(2, n_work / (block_s * rate_hz)))
    fit_mask = (np.arange(n_work) * nblk // n_work) % 2 == 0
    val_mask = np.ones(n, bool)
    val_mask[:n_work] = ~fit_mask
    return fit_mask, val_mask


def spread_blocks(n: int, rate_hz: float, horizon_s: float, fit_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Fit and validation masks over the whole record for fits that restart from the
    measurement every `horizon_s`: whole horizons, every k-th of them fitted (at most `fit_s`
    seconds in all, and never more than every other one), spread over the record so that every
    phase of the experiment is fitted and validated; the others validate."""
    every = max(1, int(round(horizon_s * rate_hz)))
    block = np.arange(n) // every
    nblk = int(block[-1]) + 1
    k = max(2, int(np.ceil(nblk / max(1.0, fit_s / horizon_s))))
    fit_mask = block % k == k // 2
    return fit_mask, ~fit_mask


def channel_scales(r_data: np.ndarray, n_channels: int) -> np.ndarray:
    """Per channel, the RMS of the noise-scaled residual, never below 1 (the noise itself)."""
    per = r_data.reshape(n_channels, -1)
    return np.sqrt(np.maximum(np.mean(per * per, axis=1), 1.0))


def likelihood_cost(r_data: np.ndarray, n_channels: int) -> float:
    """The negative log-likelihood of a noise-scaled residual whose channels each have an unknown
    variance no smaller than the noise: sum over channels of n·log(mean square, floored at 1),
    plus the mean square itself below the floor. A channel far off the noise (a sensor effect
    not yet modelled, a model-form misfit) then weighs by its logarithm and cannot bend the fit
    of the others; near the noise the cost is the usual sum of squares."""
    per = r_data.reshape(n_channels, -1)
    ms = np.mean(per * per, axis=1)
    n = per.shape[1]
    return float(n * np.sum(np.where(ms > 1.0, 1.0 + np.log(np.maximum(ms, 1e-300)), ms)))


def at_noise(r_data: np.ndarray, n_channels: int, noise_cost: float = NOISE_COST) -> bool:
    """Is the noise-scaled residual at the noise on every channel? (Judged per channel: one
    channel's systematic misfit must not hide among channels that are at their floor.)"""
    per = r_data.reshape(n_channels, -1)
    return bool(np.max(np.mean(per * per, axis=1)) < noise_cost)


def fit(prob: Problem, model: Model, *, iters: int, pred0: dict | None = None, ftol: float | None = None,
        hold: frozenset[str] = frozenset(), log: Callable[..., None] | None = None,
        jac0: np.ndarray | None = None, stop: Callable[[list[float], int], bool] | None = None,
        info: dict[str, Any] | None = None) -> tuple[Model, dict, np.ndarray]:
    """Bounded Levenberg-Marquardt on the weighted fit-block residual over the model's free
    parameters: forward-difference Jacobians (one batch of simulations), then three damping
    levels tried at once (one more batch). At most `iters` iterations; stops when an iteration
    gains less than `ftol` of the cost twice, or (the settings' `predicted_stop` > 0) once when
    the Gauss-Newton model of the next step (on the Jacobian carried to the new point) promises
    less than `predicted_stop` x ftol too. `pred0`: the model's working-window prediction, if known; `jac0`: the
    Jacobian at the model, if known (a previous fit's): it stands for the schedule's first
    differencing (one simulation per parameter saved), and a first step that fails on it has
    the Jacobian differenced afresh; `hold`: keys of free
    parameters kept where they are (columns of the Jacobian are zero). `stop(costs, left)`, if
    given, is asked after every iteration with the likelihood costs so far (the start's first)
    and the iterations left: True ends the fit there (a caller whose decision the fit can no
    longer change). `info`, if given, receives `iterations` and `ended`: "converged" (two small
    gains, a stall on a fresh Jacobian, at the noise, or the predicted stop), "budget" (all
    `iters` spent) or "stopped" (by `stop`). Returns the fitted model, its working-window
    prediction and the Jacobian there."""
    st = prob.settings
    ftol = st.ftol if ftol is None else ftol
    lo = np.array([f.lo for f in model.frees])
    hi = np.array([f.hi for f in model.frees])
    steps = np.array([f.step for f in model.frees])
    x = np.clip(model.x, lo, hi)
    moving = np.array([f.key not in hold for f in model.frees])
    hs = np.where(x + steps <= hi, steps, -steps)  # the Jacobian's steps (inwards at an upper bound)
    idx = np.flatnonzero(moving)
    ahead: list[dict[str, np.ndarray]] | None = None  # the first Jacobian's neighbours, simulated with the point
    warm = jac0 is not None and pred0 is not None and not hold and bool(np.array_equal(x, model.x))
    if pred0 is not None and np.array_equal(x, model.x):
        pred = pred0
    elif iters > 0 and not warm and not prob.lockstep and len(idx):
        # The point and its first Jacobian's neighbours in one batch (the cores not left idle
        # while the point is simulated alone): the same simulations, in parallel.
        pred, *ahead = prob.predict([model.at(x).params()] + [model.at(x + hs[i] * np.eye(len(x))[i]).params() for i in idx])
    else:
        pred = prob.predict([model.at(x).params()])[0]
    r_data = prob.residual(pred, prob.fit_mask)
    n_data = len(r_data)
    # Prior rows: sqrt(W) (x - x_nominal) / width, W a small share of the noise-level cost.
    has = np.array([f.prior > 0 for f in model.frees])
    width = np.array([f.prior if f.prior > 0 else 1.0 for f in model.frees])
    x_nom = model.start()
    wp = math.sqrt(st.prior_share * n_data) * has / width

    def full(rd: np.ndarray, xx: np.ndarray) -> np.ndarray:
        return np.concatenate([rd, wp * (xx - x_nom)])

    nc = len(prob.channels)
    rows = np.repeat(np.arange(nc), n_data // nc)

    def cost_of(rd: np.ndarray, xx: np.ndarray) -> float:
        pr = wp * (xx - x_nom)
        return likelihood_cost(rd, nc) + float(pr @ pr)

    r = full(r_data, x)
    cost = cost_of(r_data, x)
    lam, radius = 1e-2, 0.5  # damping; largest step of any normalised coordinate
    small = 0  # iterations in a row that gained less than ftol
    jac = np.zeros((n_data, len(x)))
    fresh = 0  # iterations since the Jacobian was last differenced
    # A Jacobian given at the start stands for the first differencing of the schedule.
    warm = warm and jac0 is not None and jac0.shape == jac.shape
    if warm:
        jac = np.array(jac0, dtype=float)
    costs = [likelihood_cost(r_data, nc)]
    ended, done = "budget", 0
    for it in range(iters):
        if warm:
            fresh = 0
        elif fresh == 0 or fresh >= st.jacobian_every:
            hs = np.where(x + steps <= hi, steps, -steps)  # step inwards at an upper bound
            if ahead is not None:
                preds, ahead = ahead, None
            else:
                preds = prob.neighbours(model.at(x).params(), [model.at(x + hs[i] * np.eye(len(x))[i]).params() for i in idx])
            jac = np.zeros((n_data, len(x)))
            for i, pr in zip(idx, preds):
                jac[:, i] = (prob.residual(pr, prob.fit_mask) - r[:n_data]) / hs[i]
            fresh = 0
        fresh += 1
        # Iteratively reweighted: each channel scaled by its current RMS over the noise (the
        # Gauss-Newton step of `likelihood_cost`).
        w = 1.0 / channel_scales(r[:n_data], nc)[rows]
        rw = np.concatenate([w * r[:n_data], r[n_data:]])
        jfull = np.vstack([w[:, None] * jac, np.diag(wp)])
        g = jfull.T @ rw
        # Parameters at a bound that the gradient pushes outward stay put, and so do held ones.
        free = moving & ~(((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0)))
        jtj = jfull.T @ jfull
        # A linear parameter far from its origin may move in proportion to its size (air at 50
        # units would otherwise crawl one unit per iteration); a log parameter moves by `radius`.
        reach = _reach(model, x)
        d = np.maximum(np.diag(jtj), 1e-12 * max(1.0, float(np.max(np.diag(jtj)))))
        improved, gain, lam0 = False, 0.0, lam
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
            tpreds = prob.predict([model.at(xt).params() for xt in trials])
            tres = [full(prob.residual(tp, prob.fit_mask), xt) for tp, xt in zip(tpreds, trials)]
            tcost = [cost_of(tr[:n_data], xt) for tr, xt in zip(tres, trials)]
            k = int(np.argmin(tcost))
            if tcost[k] < cost:
                gain = (cost - tcost[k]) / cost
                if np.max(np.abs(trials[k] - x) / reach) >= 0.99 * radius:
                    radius = min(st.radius_max, 2.0 * radius)  # the step was capped and still good: widen
                # Broyden's rank-one update carries the Jacobian to the new point until it is
                # differenced again (one simulation per parameter saved on every other iteration).
                dx, dr = trials[k] - x, tres[k][:n_data] - r[:n_data]
                jac = jac + np.outer(dr - jac @ dx, dx) / max(float(dx @ dx), 1e-300)
                x, pred, r, cost, lam = trials[k], tpreds[k], tres[k], tcost[k], max(lams[k] * (0.3 if k == 0 else 1.0), 1e-7)
                improved = True
                break
            lam *= 100.0
            radius *= 0.25
        if not improved and (fresh > 1 or warm):  # failed on a carried Jacobian: difference it afresh, same damping
            fresh, lam = st.jacobian_every, lam0
        warm = False
        if log is not None:
            log(f"    LM cost {cost:.6g} lam {lam:.3g} radius {radius:.3g} free {int(free.sum())}/{len(x)}")
        small = 0 if improved and gain >= ftol else small + 1
        done = it + 1
        costs.append(likelihood_cost(r[:n_data], nc))
        if (not improved and fresh == 1) or small >= 2 or at_noise(r[:n_data], len(prob.channels), st.noise_cost):
            ended = "converged"
            break  # stalled on a fresh Jacobian, or down to the noise on every channel
        if improved and small == 1 and st.predicted_stop > 0 and \
                predicted_gain(jac, r, n_data, nc, rows, wp, moving, x, lo, hi, _reach(model, x), lam * 0.1, radius) \
                < st.predicted_stop * ftol:
            ended = "converged"
            break  # a small gain, and the next step promises as little
        if stop is not None and done < iters and stop(costs, iters - done):
            ended = "stopped"
            break  # the caller's decision no longer depends on the rest of the fit
    if info is not None:
        info.update(iterations=done, ended=ended)
    return model.at(x), pred, jac


def _reach(model: Model, x: np.ndarray) -> np.ndarray:
    return np.array([1.0 if f.log else max(1.0, 0.5 * abs(xi)) for f, xi in zip(model.frees, x)])


def predicted_gain(jac: np.ndarray, r: np.ndarray, n_data: int, nc: int, rows: np.ndarray, wp: np.ndarray,
                   moving: np.ndarray, x: np.ndarray, lo: np.ndarray, hi: np.ndarray, reach: np.ndarray, lam: float,
                   radius: float) -> float:
    """The share of the cost the Gauss-Newton model of `fit`'s next step (reweighted as there,
    damped by `lam`, bounded as there) promises to remove: the decrease of the weighted sum of
    squares it predicts (to first order the likelihood cost's) over the cost itself."""
    w = 1.0 / channel_scales(r[:n_data], nc)[rows]
    rw = np.concatenate([w * r[:n_data], r[n_data:]])
    jfull = np.vstack([w[:, None] * jac, np.diag(wp)])
    g = jfull.T @ rw
    free = moving & ~(((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0)))
    if not free.any():
        return 0.0
    jtj = jfull.T @ jfull
    d = np.maximum(np.diag(jtj), 1e-12 * max(1.0, float(np.max(np.diag(jtj)))))
    step = np.zeros_like(x)
    try:
        step[free] = np.linalg.solve(jtj[np.ix_(free, free)] + lam * np.diag(d[free]), -g[free])
    except np.linalg.LinAlgError:
        return float("inf")
    big = float(np.max(np.abs(step) / reach))
    if big > radius:
        step *= radius / big
    step = np.clip(x + step, lo, hi) - x
    decrease = -2.0 * float(g @ step) - float(step @ jtj @ step)
    cost = likelihood_cost(r[:n_data], nc) + float(r[n_data:] @ r[n_data:])
    return decrease / cost if cost > 0 else 0.0
