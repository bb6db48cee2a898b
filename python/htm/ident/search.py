"""The effect search: fit the base model, then add candidate effects one at a time while one
pays off on held-out data (greedy forward selection with a backward check). Family-neutral: the
problem's simulator and the candidates say what the model is."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from htm.ident import features as ft
from htm.ident.fit import Problem, fit
from htm.ident.model import Candidate, Model
from htm.ident.sim import SENSOR_EFFECTS

# Non-noise residual over the noise floor (features.systematic_ratio): the search stops at or below.
SYSTEMATIC = 1.0
# A refit must cut the held-out weighted cost by this fraction (and win by BIC) to count.
MIN_GAIN = 0.05
# ...and remove this share of the systematic residual (above the noise) of at least one channel:
# a finding that shaves a few percent off a large misfit is bending to the model's form.
MIN_SHARE = 0.2
# Evidence a candidate's signature must carry before it is refitted (chi^2 units, fraction).
SCREEN_CHI2 = 25.0
SCREEN_FRACTION = 0.01
# A probe for structure outside the vocabulary must cut the held-out cost by this much.
PROBE_GAIN = 0.1
# ...and account for half of some channel's systematic residual: structure outside the
# vocabulary is a feature that dominates what is left, not a sliver of the model's form.
PROBE_SHARE = 0.5
# Candidates refitted per round: those whose screened gain is at least this share of the best.
REFIT_SHARE = 0.3
# Least-squares budgets: Jacobians (one simulation per free parameter each, plus 3 trial steps).
BASE_ITERS, REFIT_ITERS, POLISH_ITERS = 10, 6, 15
# ...and for a contender's own parameters on another contender's base (few: the base is held).
COMMON_ITERS = 3
# Fitting a tone's amplitude (sine and cosine, the model held: nearly linear).
TONE_ITERS = 1
# Which of two effects that explain a record equally well is named (the more common first).
PREFERENCE = ("sensor_offset", "valve_null_bias", "sensor_gain", "sensor_delay", "valve_dynamics", "internal_leakage",
              "friction_asymmetry", "valve_deadband", "valve_hysteresis", "supply_pressure_sag",
              "pressure_dependent_friction", "entrained_air", "load_pressure_feedback", "specimen_nonlinearity")

Log = Callable[..., None]


@dataclass
class Finding:
    """An effect added to the model, with the errors just before and after it (DATA_FORMAT
    `findings` entry) and what the report needs to show its evidence."""

    cand: Candidate
    params: dict[str, float]
    rmse_before: dict[str, float]
    rmse_after: dict[str, float]
    evidence: str
    before: Model  # the model just before this finding
    pred_before: dict[str, np.ndarray]
    pred_after: dict[str, np.ndarray]
    focus: str  # the channel the effect shows in most
    feature: tuple[str, np.ndarray]  # (name, signal) the residual is plotted against
    verdict: dict[str, Any] = field(default_factory=dict)

    @property
    def effect(self) -> str:
        return self.cand.effect

    @property
    def channel(self) -> str | None:
        return self.cand.channel

    def to_json(self) -> dict[str, Any]:
        return {"effect": self.effect, "channel": self.channel, "params": self.params, "rmse_before": self.rmse_before,
                "rmse_after": self.rmse_after, "evidence": self.evidence}


@dataclass
class Result:
    """What a search found: the baseline and final models with their whole-record predictions."""

    base: Model
    base_pred: dict[str, np.ndarray]
    model: Model
    pred: dict[str, np.ndarray]
    findings: list[Finding]
    work_pred: dict[str, np.ndarray] | None = None  # the final model's prediction over the fit samples
    jac: np.ndarray | None = None  # and its Jacobian there


def search(prob: Problem, base: Model, nominal: Any, pool: list[Candidate], rate: float, *, max_findings: int = 3,
           max_refits: int = 2, first: frozenset[str] = frozenset(), log: Log = lambda *a: None) -> Result:
    """Fit the base model, then add effects from `pool` while one pays off on the held-out data.
    The base model is fitted in two stages: first with the parameters in `first` held (the
    details of a real rig — its spool, return line, orifice shape — that would otherwise wander
    into a wrong basin while the gross parameters are far off), then with all free."""
    x0 = base.x.copy()
    # The nominal values (the spool at its typical value, not static as the fit starts it):
    # where a parameter pinned at the bound it started from goes back to (Model.unpinned).
    xn = base.start()
    if first:
        base, _, _ = fit(prob, base, iters=BASE_ITERS, hold=first)
        log("first stage", {k: f"{v:.4g}" for k, v in base.values().items()})
    base, work_pred, jac = fit(prob, base, iters=BASE_ITERS)
    base_pred = prob.whole(base, work_pred)
    log("baseline", {k: f"{v:.4g}" for k, v in base.values().items()}, prob.rmse(base_pred))

    model, pred = base, base_pred
    findings: list[Finding] = []
    kept_base = False
    for _round in range(2 * max_findings + 2):  # a round per finding, and one per better base
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
        ranked = screen(prob, model, work_pred, jac, pool)
        q = np.linalg.qr(jac)[0]  # what the base parameters can absorb, to first order
        log("screen", [(c.effect, c.channel, round(g, 3)) for c, g, _ in ranked[:6]])
        good: list[tuple[Candidate, dict, Model, dict, dict]] = []  # (cand, verdict, fit, its work and whole predictions)
        better_base: tuple[float, Model] | None = None
        too_small = False
        for cand, gain, step in ranked[:max_refits]:
            if gain < REFIT_SHARE * ranked[0][1]:
                break
            # Refit from the current fit and from the nominal base parameters (the current fit may
            # have bent them to stand in for this very effect), each at the best size of the
            # candidate's parameter; keep the better fit.
            starts = [start.with_candidate(cand, step) for start in _restarts(model, x0, xn)]
            trial, twork, tjac = fit(prob, _scan(prob, starts, cand, q), iters=REFIT_ITERS)
            tpred = prob.whole(trial, twork)
            verdict = pays_off(prob, pred, trial, tpred, model, cand)
            log("refit", cand.label, cand.report(trial.params()), verdict)
            if verdict["ok"]:
                good.append((cand, verdict, trial, twork, tpred))
                continue
            if not verdict["claimable"]:
                # The record wants it only at a size the base's form mimics: not an effect here,
                # and not to be screened again ahead of the others.
                pool = [c for c in pool if c.key != cand.key]
                too_small = True
            if verdict["dcost"] < -MIN_GAIN:
                # Not the effect but a better fit of the base parameters: remember those.
                cost = prob.fit_cost(twork)
                if better_base is None or cost < better_base[0]:
                    better_base = (cost, trial.truncated(len(model.x)))
        if better_base is not None and good:
            # A refit whose effect did nothing still cut the cost: the current fit had not settled.
            # An effect must pay off against those base parameters too, or it is only getting
            # the credit for their convergence.
            bpred = prob.predict([better_base[1].params()], whole=True)[0]
            settled = []
            for g in good:
                if pays_off(prob, bpred, g[2], g[4], model, g[0])["ok"]:
                    settled.append(g)
                else:
                    log("not against the better base", g[0].label)
            good = settled
        if not good:
            if (better_base is None or kept_base) and not too_small:
                break  # no candidate pays off on the held-out data
            if better_base is None or kept_base:
                continue  # a candidate too small to claim left the pool: screen the others
            kept_base = True  # once per finding: a second time the search would only go round in circles
            model = better_base[1]
            work_pred = prob.predict([model.params()])[0]
            pred = prob.whole(model, work_pred)
            log("kept better base parameters")
            continue
        good.sort(key=lambda g: g[1]["dbic"])
        # Close contenders (e.g. an offset and a gain of the same sensor) are told apart polished.
        contenders = [g for g in good[:2] if g[1]["dbic"] <= 0.5 * good[0][1]["dbic"]]
        polished = []
        for cand, _, trial, twork, _ in contenders:
            trial, twork, tjac = fit(prob, trial, iters=POLISH_ITERS, pred0=twork)
            again = trial.unpinned(x0, xn)
            if not np.array_equal(again.x, trial.x):
                # Stuck with base parameters at a bound: polish once more from their nominal values.
                retry = fit(prob, again, iters=POLISH_ITERS)
                if prob.fit_cost(retry[1]) < prob.fit_cost(twork):
                    trial, twork, tjac = retry
            tpred = prob.whole(trial, twork)
            polished.append((cand, pays_off(prob, pred, trial, tpred, model, cand), trial, twork, tjac, tpred))
            log("polished", cand.label, cand.report(trial.params()), polished[-1][1])
        if len(polished) == 2:
            polished = _on_common_base(prob, pred, model, polished, log)
        # Both at the noise floor, or two faults of one sensor whose held-out costs are apart by
        # less than the MIN_GAIN that makes a refit count at all (a reading that moves little
        # about its mean is scaled or shifted alike): the record cannot tell them apart; name
        # the more common effect (PREFERENCE: an offset before a gain before a delay...) and say so.
        at_floor = [g for g in polished if max(prob.ratios(g[5], rate).values()) <= SYSTEMATIC]
        if len(polished) == 2 and polished[0][0].channel is not None and polished[0][0].channel == polished[1][0].channel \
                and _tied(polished[0][1], polished[1][1]):
            at_floor = polished
        if len(at_floor) == 2:
            at_floor.sort(key=lambda g: PREFERENCE.index(g[0].effect) if g[0].effect in PREFERENCE else len(PREFERENCE))
            cand, verdict, trial, twork, tjac, tpred = at_floor[0]
            other = at_floor[1]
            verdict["alternative"] = (f" {other[0].label} ({', '.join(f'{k} = {v:.4g}' for k, v in other[0].report(other[2].params()).items())}) "
                                      "explains the record as well; this record cannot tell the two apart.")
        else:
            cand, verdict, trial, twork, tjac, tpred = min(polished, key=lambda g: g[1]["dbic"])
        pool = [c for c in pool if c.key != cand.key]
        if not verdict["ok"]:
            # Polished, the effect no longer matters: keep the better-fitted model without it.
            model = trial.truncated(len(model.x))
            work_pred = prob.predict([model.params()])[0]
            pred, jac = prob.whole(model, work_pred), tjac[:, : len(model.x)]
            log("polished away", cand.label, verdict)
            continue
        if not findings:  # the baseline is the base model as fitted just before the first finding
            base, base_pred = model, pred
        findings.append(finding(prob, cand, model, pred, trial, tpred, verdict, rate))
        model, pred, work_pred, jac = trial, tpred, twork, tjac
        kept_base = False

    # Backward check, latest first: a finding the others make redundant is dropped. Without it the
    # model is refitted from where the search left it and from the base parameters anew: a
    # finding added late may only have led the fit out of a basin it had settled in.
    def too_small(f: Finding) -> bool:
        # Refits after a finding move its parameters too: one that ends below a claimable size goes.
        return f.cand.claimable is not None and not f.cand.claimable(f.cand.report(model.params()))

    def refit_without(f: Finding) -> tuple[Model, dict, dict, np.ndarray]:
        fits = [fit(prob, start, iters=REFIT_ITERS) for start in _restarts(model.without(f.cand, nominal), x0, xn)]
        wmodel, wwork, wjac = min(fits, key=lambda g: prob.fit_cost(g[1]))
        return wmodel, prob.whole(wmodel, wwork), wwork, wjac

    for f in list(reversed(findings)):
        small = too_small(f)
        if len(findings) < 2 and not small:
            break  # a single finding was weighed against the model without it when it was made
        wmodel, wpred, wwork, wjac = refit_without(f)
        dbic, dcost = prob.bic_delta(wpred, pred, max(1, len(f.cand.frees)))
        log("backward check", f.cand.label, f"dBIC {dbic:.0f} dcost {dcost:+.3f}")
        if small or not (dbic < 0 and dcost < -MIN_GAIN):
            findings.remove(f)
            model, pred, work_pred, jac = wmodel, wpred, wwork, wjac
    # A drop refits the model, which moves the findings checked before it: one it left below a
    # claimable size (a leak gone to zero once the dead band beside it went) goes too.
    while small_ones := [f for f in findings if too_small(f)]:
        log("below a claimable size after a drop", small_ones[-1].cand.label)
        model, pred, work_pred, jac = refit_without(small_ones[-1])
        findings.remove(small_ones[-1])
    if findings and findings[0].pred_before is not base_pred:
        first = findings[0]  # after a drop, the first remaining finding starts from the baseline
        first.pred_before = base_pred
        first.rmse_before = prob.rmse(base_pred)
    if not findings:
        base, base_pred = model, pred
    else:  # refits after the last finding belong to it: its "after" is the final model
        last = findings[-1]
        last.pred_after = pred
        last.rmse_after = prob.rmse(pred)
        last.params = last.cand.report(model.params())
    return Result(base, base_pred, model, pred, findings, work_pred, jac)


def probe(prob: Problem, res: Result, pool: list[Candidate], rate: float, log: Log = lambda *a: None) -> Finding | None:
    """Structure outside the effect vocabulary: the probe of `pool` (a force over part of the
    stroke, a pump's ripple...) that pays off on the held-out data on top of the final model by
    `PROBE_GAIN` of the cost, or None. Not a finding of the record: evidence that structure
    remains which no effect of the vocabulary accounts for."""
    if not pool or res.work_pred is None or res.jac is None:
        return None
    model, pred = res.model, res.pred
    best: tuple[float, Finding] | None = None
    # A tone (a pump's ripple) is small against a broadband residual but stands out in its band:
    # its amplitude is fitted with the model held, and it must remove PROBE_SHARE of the
    # residual's power there and pay off on the held-out data.
    tones = {c.tone_hz: c for c in pool if c.tone_hz}
    for f_hz, cand in tones.items():
        trial, twork = _tone(prob, model, cand)
        tpred = prob.whole(trial, twork)
        dbic, dcost = prob.bic_delta(pred, tpred, len(cand.frees))
        share = prob.explained_in_band(pred, tpred, f_hz, rate)
        log("tone", f"{f_hz:.4f} Hz", cand.report(trial.params()), f"dBIC {dbic:.0f} dcost {dcost:+.4f} in band {share:.0%}")
        if dbic < 0 and share >= PROBE_SHARE and (best is None or dbic < best[0]):
            verdict = {"ok": True, "dbic": dbic, "dcost": dcost, "ablation_dcost": dcost, "explained": share}
            best = (dbic, finding(prob, cand, model, pred, trial, tpred, verdict, rate))
    pool = [c for c in pool if not c.tone_hz]
    if not pool:
        return best[1] if best else None
    ranked = screen(prob, model, res.work_pred, res.jac, pool)
    log("probe screen", [(c.effect, round(g, 3)) for c, g, _ in ranked[:4]])
    q = np.linalg.qr(res.jac)[0]
    for cand, gain, step in ranked[:2]:
        trial, twork, _ = fit(prob, _scan(prob, [model.with_candidate(cand, step)], cand, q), iters=REFIT_ITERS)
        tpred = prob.whole(trial, twork)
        verdict = pays_off(prob, pred, trial, tpred, model, cand)
        log("probe", cand.label, cand.report(trial.params()), verdict)
        if (verdict["ok"] and verdict["dcost"] < -PROBE_GAIN and verdict["explained"] >= PROBE_SHARE
                and (best is None or verdict["dbic"] < best[0])):
            best = (verdict["dbic"], finding(prob, cand, model, pred, trial, tpred, verdict, rate))
    return best[1] if best else None


def _tone(prob: Problem, model: Model, cand: Candidate) -> tuple[Model, dict]:
    """A tone's amplitudes on top of `model` (held): the readings are linear in them to first
    order, so one simulation per amplitude and a least-squares solve place them; one held
    Levenberg-Marquardt pass takes up what is not linear."""
    zero = model.with_candidate(cand, 0.0)
    k = len(cand.frees)
    units = [zero.at(np.concatenate([model.x, np.eye(k)[i]])) for i in range(k)]
    preds = prob.predict([zero.params()] + [u.params() for u in units])
    r0 = prob.residual(preds[0], prob.fit_mask)
    sig = np.column_stack([prob.residual(p, prob.fit_mask) - r0 for p in preds[1:]])
    amp = np.linalg.lstsq(sig, -r0, rcond=None)[0]
    lo, hi = np.array([f.lo for f in cand.frees]), np.array([f.hi for f in cand.frees])
    start = zero.at(np.concatenate([model.x, np.clip(amp, lo, hi)]))
    trial, twork, _ = fit(prob, start, iters=TONE_ITERS, hold=frozenset(f.key for f in model.frees))
    return trial, twork


def _tied(a: dict, b: dict) -> bool:
    """Two verdicts whose held-out costs after (1 + dcost of the cost before) differ by less than
    MIN_GAIN of the larger: no evidence for either over the other by the search's own standard."""
    ca, cb = 1.0 + a["dcost"], 1.0 + b["dcost"]
    return a["ok"] and b["ok"] and abs(ca - cb) < MIN_GAIN * max(ca, cb)


def _on_common_base(prob: Problem, pred0: dict, model: Model, polished: list[tuple], log: Log) -> list[tuple]:
    """Two contenders polished apart may have settled their base parameters in different basins
    (a flat cost lets them wander), and the better base would then decide between the effects.
    Each contender is also fitted on the other's base (its own parameters only, the base held)
    and keeps the better of the two by the information criterion: the effects are compared on
    the same base."""
    n = len(model.x)
    hold = frozenset(f.key for f in model.frees)
    out = []
    for i, (cand, verdict, trial, twork, tjac, tpred) in enumerate(polished):
        other = polished[1 - i][2]
        x = trial.x.copy()
        x[:n] = other.x[:n]
        moved, mwork, mjac = fit(prob, trial.at(x), iters=COMMON_ITERS, hold=hold)
        mpred = prob.whole(moved, mwork)
        mverdict = pays_off(prob, pred0, moved, mpred, model, cand)
        log("on the other's base", cand.label, cand.report(moved.params()), mverdict)
        if mverdict["dbic"] < verdict["dbic"]:
            # One step with all free: the Jacobian of every parameter (differenced at `moved`)
            # for the screens to come. The step fits the fit blocks and may lose on the held-out
            # ones; then `moved` stays, or the step would decide between the contenders.
            strial, swork, tjac = fit(prob, moved, iters=1, pred0=mwork)
            spred = prob.whole(strial, swork)
            sverdict = pays_off(prob, pred0, strial, spred, model, cand)
            log("one step on", cand.label, cand.report(strial.params()), sverdict)
            trial, twork, tpred, verdict = ((strial, swork, spred, sverdict) if sverdict["dbic"] <= mverdict["dbic"]
                                            else (moved, mwork, mpred, mverdict))
        out.append((cand, verdict, trial, twork, tjac, tpred))
    return out


def _restarts(model: Model, x0: np.ndarray, xn: np.ndarray) -> list[Model]:
    """Where a refit with a new effect starts: the current fit with its pinned parameters sent
    back (to where the search started them, or to nominal where that start was itself a bound:
    a spool the fit pinned slow to stand in for a lag goes to its typical 150 Hz, not back to
    static, from where the flat cost between them would never lead it), and the base
    parameters anew from where the search started them."""
    restart = model.x.copy()
    restart[: len(x0)] = x0
    return [model.unpinned(x0, xn), model.at(restart)]


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
                models.append(start.at(x))
    preds = prob.predict([m.params() for m in models])
    costs = []
    for p in preds:
        r = prob.residual(p, prob.fit_mask)
        r = r - q @ (q.T @ r)
        costs.append(float(r @ r))
    return models[int(np.argmin(costs))]


def pays_off(prob: Problem, pred0: dict, trial: Model, tpred: dict, before: Model, cand: Candidate) -> dict[str, Any]:
    """Does the effect pay off on the held-out data? It must beat the model without it by the
    information criterion and by MIN_GAIN of the cost, and so must it against its own refit
    with the effect switched off (else it only helped the base parameters converge); and it
    must remove MIN_SHARE of some channel's systematic residual (its own signature, not a
    sliver of a misfit it does not account for)."""
    k = max(1, len(cand.frees))
    dbic, dcost = prob.bic_delta(pred0, tpred, k)
    abl = prob.predict([trial.ablated(before, cand).params()], whole=True)[0]
    abic, acost = prob.bic_delta(abl, tpred, k)
    # A sensor's fault is in its own reading: there is its signature. (Through the restarts from the
    # measured state it also moves the other channels, so there it can buy a fit it does not explain.)
    own = cand.channel if cand.effect in SENSOR_EFFECTS and cand.channel in prob.channels else None
    share = prob.explained(pred0, tpred, only=own)
    big = cand.claimable is None or cand.claimable(cand.report(trial.params()))
    ok = dbic < 0 and dcost < -MIN_GAIN and abic < 0 and acost < -MIN_GAIN and share >= MIN_SHARE and big
    return {"ok": bool(ok), "dbic": dbic, "dcost": dcost, "ablation_dcost": acost, "explained": share, "claimable": bool(big)}


def screen(prob: Problem, model: Model, work_pred: dict, jac: np.ndarray,
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
    for c, p in zip(pool, preds):
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
            if gain > SCREEN_CHI2 and gain > SCREEN_FRACTION * cost and (c.key not in best or gain / cost > best[c.key][1]):
                best[c.key] = (c, gain / cost, step)
    return sorted(best.values(), key=lambda g: -g[1])


def finding(prob: Problem, cand: Candidate, before: Model, pred0: dict, after: Model, pred1: dict,
            verdict: dict[str, Any], rate: float) -> Finding:
    """The finding of `cand` between two models, with its evidence in words."""
    rb, ra = prob.rmse(pred0), prob.rmse(pred1)
    # The channel the effect shows in: its own for a sensor effect, else the one it improves most.
    ch = cand.channel if cand.channel in prob.channels else min(prob.channels, key=lambda c: ra[c] / rb[c] if rb[c] > 0 else 1.0)
    resid = np.asarray(pred0[ch]) - prob.meas[ch]
    name, signal = signature(prob, cand, pred0, ch, rate)
    corr = ft.correlations(resid, {name: signal}).get(name, float("nan"))
    unit = ft.UNITS[ch]
    what = "mean/RMS" if cand.signature == "constant" else f"correlation with {name}"
    params = cand.report(after.params())
    ptxt = ", ".join(f"{k} = {v:.4g}" for k, v in params.items())
    evidence = (f"Before: the {ch} residual (RMS {rb[ch]:.3g} {unit}, noise floor {prob.sigma[ch]:.2g} {unit}) has "
                f"{what} {corr:+.2f}. Adding {cand.label} ({ptxt or 'no parameters'}) brings it to "
                f"{ra[ch]:.3g} {unit} and cuts the held-out cost by {-verdict['dcost']:.0%} (ΔBIC {verdict['dbic']:.0f}); "
                f"switched off again, other parameters kept, the held-out cost would be "
                f"{1 / max(1 + verdict['ablation_dcost'], 1e-9):.3g}x higher." + verdict.get("alternative", ""))
    # An offset shows best against the reading itself (a shift; a gain would be a slope).
    feature = (f"measured {ch}", prob.meas[ch]) if cand.signature == "constant" else (name, signal)
    return Finding(cand, params, rb, ra, evidence, before, pred0, pred1, ch, feature, verdict)


def signature(prob: Problem, cand: Candidate, pred0: dict, ch: str, rate: float) -> tuple[str, np.ndarray]:
    """The signal named by a candidate's signature, over the whole record."""
    if cand.signature.startswith("d(predicted"):
        return cand.signature, np.gradient(np.asarray(pred0[ch], dtype=float))
    if cand.signature.startswith("predicted"):
        return cand.signature, np.asarray(pred0[ch], dtype=float)
    regs = ft.regressors(prob.rec.columns, rate)
    return (cand.signature, regs[cand.signature]) if cand.signature in regs else ("constant", regs["constant"])
