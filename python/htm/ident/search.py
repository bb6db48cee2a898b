"""The effect search as an explicit selector: fit the base model, then add candidate effects one
at a time while one pays off on held-out data (greedy forward selection with a backward check).
Family-neutral: the problem's simulator and the candidates say what the model is.

Its stages, each a method of `Selector` returning typed values:

* **base fit** — the base model, in two stages (the details held first);
* **screen** (`screen`) — rank candidates by a linearised score test (`Screened`);
* **refit** (`Selector.refit`) — refit the best screened candidates (`Trial`), each judged;
* **judge** (`pays_off`) — does a trial pay off on the held-out data (`Verdict`, its rules named);
* **break ties** (`Selector.break_ties`) — polish close contenders, compare them on one base,
  name the more common effect when the record cannot tell them apart;
* **backward check** (`Selector.backward_check`) — drop a finding the others make redundant.

Every knob is a field of `settings.SearchSettings` (the problem's `prob.settings`); every decision
goes into a `trace.Trace` with the rule it applied and the numbers it compared.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Callable, NamedTuple

import numpy as np

from htm.ident import features as ft
from htm.ident.fit import Problem, fit, side_by_side
from htm.ident.model import Candidate, Model, get_value
from htm.ident.settings import DEFAULT, SearchSettings
from htm.ident.trace import Stages, Trace

# The knobs live in `settings.SearchSettings` (unit and reason there); these names are its defaults.
SYSTEMATIC = DEFAULT.systematic
MIN_GAIN = DEFAULT.min_gain
MIN_SHARE = DEFAULT.min_share
SCREEN_CHI2 = DEFAULT.screen_chi2
SCREEN_FRACTION = DEFAULT.screen_fraction
PROBE_GAIN = DEFAULT.probe_gain
PROBE_SHARE = DEFAULT.probe_share
REFIT_SHARE = DEFAULT.refit_share
BASE_ITERS, REFIT_ITERS, POLISH_ITERS = DEFAULT.base_iters, DEFAULT.refit_iters, DEFAULT.polish_iters
COMMON_ITERS = DEFAULT.common_iters
TONE_ITERS = DEFAULT.tone_iters
PREFERENCE = DEFAULT.preference

Log = Callable[..., None]


@dataclass
class Verdict:
    """Whether a trial pays off on the held-out data, with the numbers each rule compared:
    `dbic` (ΔBIC against the model without it), `dcost` (relative change of the held-out cost),
    `ablation_dcost` (against itself switched off, other parameters kept), `explained` (share of
    a channel's systematic residual removed), `claimable` (its size is worth claiming).
    `failed` names the rules it does not meet; `close`, whether a deciding number lies within
    the settings' close_margin of its threshold; `close_rules`, the rules it meets only by such a
    margin. A pass that close is no claim (`ok` false): the record's evidence for the effect is
    not clear of the search's own threshold, and the simpler model — without it — stands (a
    decision that rounding, a thread count or a seed could flip is not made for the effect).
    Indexable like the dict it replaces."""

    ok: bool
    dbic: float
    dcost: float
    ablation_dcost: float
    explained: float
    claimable: bool = True
    failed: tuple[str, ...] = ()
    close: bool = False
    close_rules: tuple[str, ...] = ()
    alternative: str = ""
    others_worse: float = 0.0
    own_level: float | None = None  # a phase fault's reading against the worst other before it (`phase_fault`), where asked
    shows: dict[str, float] | None = None  # where the effect stands apart from the base's form (`gains_where_it_shows`)
    still: dict[str, float] | None = None  # what it takes where the actuator stands still (`takes_at_standstill`)

    def __getitem__(self, key: str) -> Any:
        return getattr(self, key)

    def get(self, key: str, default: Any = None) -> Any:
        return getattr(self, key, default)

    def numbers(self) -> dict[str, Any]:
        out: dict[str, Any] = {"dbic": self.dbic, "dcost": self.dcost, "ablation_dcost": self.ablation_dcost, "explained": self.explained,
               "claimable": self.claimable}
        if self.others_worse:
            out["others_worse"] = self.others_worse
        if self.own_level is not None:
            out["own_level"] = self.own_level
        if self.shows is not None:
            out["where_it_shows"] = self.shows
        if self.still is not None:
            out["at_standstill"] = self.still
        return out

    @property
    def rule(self) -> str:
        if self.ok:
            return "pays off: " + ", ".join(RULES)
        if not self.failed:
            return "close: meets " + ", ".join(self.close_rules) + " only within close_margin: the model without it stands"
        return "fails: " + ", ".join(self.failed)

    def __repr__(self) -> str:
        return (f"Verdict(ok={self.ok}, dbic={self.dbic:.4g}, dcost={self.dcost:+.4f}, ablation_dcost={self.ablation_dcost:+.4f}, "
                f"explained={self.explained:.3f}, claimable={self.claimable}{', failed=' + str(list(self.failed)) if self.failed else ''}"
                f"{', close on ' + str(list(self.close_rules)) if self.close_rules else ''})")


# The rules of `pays_off`, by the names the trace uses.
RULES = ("dBIC < 0", "dcost < -min_gain", "ablation dBIC < 0", "ablation dcost < -min_gain", "explained >= min_share",
         "claimable size", "others no worse than max_others_worse", "gains where it shows", "takes the error at standstill")
# The effects whose fault is one reading's and that trade with the loop's phase (every channel):
# judged also by what they do to the other readings (`phase_fault`).
PHASE_FAULTS = ("sensor_delay",)


class Screened(NamedTuple):
    """A screened candidate: the share of the fit cost its signature explains and the starting
    value of its first parameter (None for a switch)."""

    cand: Candidate
    gain: float
    step: float | None


@dataclass
class Trial:
    """A candidate refitted: the model with it, its working-window and whole-record predictions,
    the Jacobian at the fit (if known) and the verdict."""

    cand: Candidate
    model: Model
    work: dict[str, np.ndarray]
    pred: dict[str, np.ndarray]
    verdict: Verdict
    jac: np.ndarray | None = None
    jac_at: np.ndarray | None = None  # the point `jac` belongs to (None: not known to be `model`'s)

    def warm(self, st: SearchSettings) -> np.ndarray | None:
        """The Jacobian at the trial's model, if known there and warm starts are on."""
        return self.jac if st.warm_jacobian and _at(self.jac_at, self.model) else None


def _at(x: np.ndarray | None, model: Model) -> bool:
    return x is not None and x.shape == model.x.shape and bool(np.array_equal(x, model.x))


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
    verdict: Verdict | None = None

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


@dataclass
class _BetterBase:
    """A refit whose effect did nothing but that still cut the cost: its base parameters."""

    cost: float
    model: Model
    cand: str


def search(prob: Problem, base: Model, nominal: Any, pool: list[Candidate], rate: float, *, max_findings: int | None = None,
           max_refits: int | None = None, first: frozenset[str] = frozenset(), stated: frozenset[str] = frozenset(),
           log: Log = lambda *a: None, trace: Trace | None = None, stages: Stages | None = None) -> Result:
    """Fit the base model, then add effects from `pool` while one pays off on the held-out data
    (`Selector`; the settings are `prob.settings`, `max_findings`/`max_refits` override theirs).
    The base model is fitted in two stages: first with the parameters in `first` held (the
    details of a real rig — its spool, return line, orifice shape — that would otherwise wander
    into a wrong basin while the gross parameters are far off), then with all free. `stated`: the
    base parameters the metadata states (a rig's geometry, mass, valve rating): one of them at its
    bound when the search would end is a base in a wrong basin (`SearchSettings.widen_when_pinned`)."""
    st = prob.settings
    sel = Selector(prob, nominal, pool, rate, log=log, trace=trace if trace is not None else Trace(),
                   stages=stages if stages is not None else Stages(), stated=stated)
    return sel.run(base, first, st.max_findings if max_findings is None else max_findings,
                   st.max_refits if max_refits is None else max_refits)


class Selector:
    """Greedy forward selection with a backward check over a pool of candidate effects, one
    stage per method; its state is the current model, its predictions and Jacobian."""

    def __init__(self, prob: Problem, nominal: Any, pool: list[Candidate], rate: float, *, log: Log, trace: Trace,
                 stages: Stages, stated: frozenset[str] = frozenset()) -> None:
        self.prob, self.nominal, self.pool, self.rate = prob, nominal, list(pool), rate
        self.stated = stated
        self.st: SearchSettings = prob.settings
        self.log, self.trace, self.stages = log, trace, stages
        self.findings: list[Finding] = []
        self.refitted: list[Trial] = []  # the last refit's trials, judged
        self.common: list[Finding] = []  # findings whose sibling reading showed the same fault since (sibling_check)
        self.mirror: float | None = None  # the last sibling check's refitted size over the chosen's (interchangeable)
        self.sibling_refits: dict[tuple, Trial] = {}  # the sibling checks' refits for the chosen fault (sibling_refit)
        # candidates chosen (they paid off) and polished away: out of the pool, still a sibling to weigh
        self.polished_away: dict[tuple, Candidate] = {}

    # --- the loop --------------------------------------------------------------------------
    def run(self, base: Model, first: frozenset[str], max_findings: int, max_refits: int) -> Result:
        prob, st, log, tr = self.prob, self.st, self.log, self.trace
        self.x0 = base.x.copy()
        # The nominal values (the spool at its typical value, not static as the fit starts it):
        # where a parameter pinned at the bound it started from goes back to (Model.unpinned).
        self.xn = base.start()
        with self.stages("base fit", f"{len(base.x)} parameters"):
            if first:
                base, _, _ = fit(prob, base, iters=st.base_iters, hold=first)
                log("first stage", {k: f"{v:.4g}" for k, v in base.values().items()})
            base, work_pred, jac = fit(prob, base, iters=st.base_iters)
            base_pred = prob.whole(base, work_pred)
        self.jac_at: np.ndarray | None = base.x  # where self.jac belongs
        log("baseline", {k: f"{v:.4g}" for k, v in base.values().items()}, prob.rmse(base_pred))
        self.base, self.base_pred = base, base_pred
        self.model, self.pred, self.work_pred, self.jac = base, base_pred, work_pred, jac
        self.settled_at: np.ndarray | None = None  # where a refit without a new effect last ended converged
        kept_base = False
        widened = False  # the rest of a round's screened candidates refitted (once per search)
        for rnd in range(2 * max_findings + 2):  # a round per finding, and one per better base
            tr.round = rnd + 1
            if len(self.findings) >= max_findings:
                tr.add("stop", None, "max_findings reached", "search ends", findings=len(self.findings), max_findings=max_findings)
                break
            if self.at_floor("before refit"):
                break  # at the noise floor: nothing left to explain
            # The same budget without a new effect: a candidate must beat a model merely fitted longer.
            if st.resettle and _at(self.settled_at, self.model):
                # Nothing changed since the last round's refit without a new effect ended converged
                # here: refitted again it would gain less than ftol an iteration; the round screens
                # the same point again (its simulations taken from the cache).
                tr.add("refit", None, "the model is where the last round's refit without a new effect converged (resettle)",
                       "not refitted again", ftol=st.ftol)
            else:
                with self.stages("refit", f"round {rnd + 1}: the model without a new effect"):
                    warm = self.jac if st.warm_jacobian and _at(self.jac_at, self.model) else None
                    info: dict[str, Any] = {}
                    self.model, self.work_pred, self.jac = fit(prob, self.model, iters=st.refit_iters, pred0=self.work_pred,
                                                               jac0=warm, info=info)
                    self.pred, self.jac_at = prob.whole(self.model, self.work_pred), self.model.x
                    self.settled_at = self.model.x if info["ended"] == "converged" else None
                if self.at_floor("refit without effect"):
                    break
            with self.stages("screen", f"round {rnd + 1}: {len(self.pool)} candidates"):
                ranked = screen(prob, self.model, self.work_pred, self.jac, [c for c in self.pool if not c.parts])
            log("screen", [(c.effect, c.channel, round(g, 3)) for c, g, _ in ranked[:6]])
            tr.add("screen", None, "signature explains > screen_chi2 and > screen_fraction of the fit cost",
                   f"{len(ranked)} of {len(self.pool)} carry evidence",
                   ranked={c.label: g for c, g, _ in ranked[:6]})
            with self.stages("refit", f"round {rnd + 1}: {', '.join(c.label for c, _, _ in ranked[:max_refits]) or 'none'}"):
                good, better_base, too_small = self.refit(ranked, max_refits)
            done = {t.cand.key for t in self.refitted}
            if composites := [c for c in self.pool if c.parts]:
                # effects that may pay off only together (a composite), refitted beside the single
                # candidates, every one from its starts with its first parameter scanned (a linearised
                # screen of several effects at once says little); the better by dBIC is chosen
                ranked = [Screened(c, 0.0, c.frees[0].step) for c in composites]
                with self.stages("refit", f"round {rnd + 1}: composites {', '.join(c.label for c in composites)}"):
                    good += self.refit(ranked, len(ranked))[0]
            if not good and not widened and st.widen_when_pinned and (pinned := self.stated_pins(self.model)):
                # The base sits in a wrong basin (a stated parameter at its bound standing in for an
                # effect it lacks), so the screen's ranking, read there, misleads: the candidates it
                # ranked lower are refitted too, once, before the search may end or refuse the record.
                widened = True
                rest = [sc for sc in ranked if sc.cand.key not in done and any(c.key == sc.cand.key for c in self.pool)]
                tr.add("refit", None, "no candidate pays off while a stated parameter sits at its bound (widen_when_pinned)",
                       f"the other {len(rest)} screened candidates refitted", pinned=pinned)
                if rest:
                    with self.stages("refit", f"round {rnd + 1}: widened to {', '.join(sc.cand.label for sc in rest)}"):
                        more, more_base, more_small = self.refit(rest, len(rest), share=0.0)
                    good, too_small = more, too_small or more_small
                    if more_base is not None and (better_base is None or more_base.cost < better_base.cost):
                        better_base = more_base
            if better_base is not None and good:
                good = self.settle(good, better_base)
            if good and st.delay_against_form and any(g.cand.form is not None for g in good):
                with self.stages("own form", ", ".join(g.cand.label for g in good if g.cand.form is not None)):
                    good, left, formed = self.own_form(good)
                too_small = too_small or left  # an effect left the pool as the base's own form: screen the others
                if formed is not None and (better_base is None or formed.cost < better_base.cost):
                    better_base = formed
            if not good:
                if (better_base is None or kept_base) and not too_small:
                    tr.add("stop", None, "no candidate pays off on the held-out data", "search ends")
                    break
                if better_base is None or kept_base:
                    tr.add("round", None, "a candidate too small to claim left the pool", "screen the others")
                    continue
                kept_base = True  # once per finding: a second time the search would only go round in circles
                self.model = better_base.model
                self.work_pred = prob.predict([self.model.params()])[0]
                self.pred = prob.whole(self.model, self.work_pred)
                log("kept better base parameters")
                tr.add("refit", better_base.cand, "a refit whose effect did nothing cut the fit cost",
                       "kept its base parameters (once per finding)", fit_cost=better_base.cost)
                continue
            with self.stages("break ties", ", ".join(g.cand.label for g in good)):
                chosen = self.break_ties(good)
            if chosen.verdict.ok and chosen.cand.sibling and self.st.sibling_ratio > 0:
                screened = {sc.cand.key: sc for sc in ranked}
                self.sibling_refits = {}
                with self.stages("sibling check", f"{chosen.cand.label} against {chosen.cand.sibling}"):
                    checked = self.sibling_check(chosen, screened)
                if checked is None:
                    continue
                chosen = checked
                if chosen.verdict.ok and chosen.cand.level and self.st.sibling_other_kind and self.interchangeable(chosen):
                    with self.stages("sibling check", f"{chosen.cand.label}: the other kind on {chosen.cand.sibling}"):
                        chosen = self.other_kind(chosen, screened)
            self.pool = [c for c in self.pool if not c.keys & chosen.cand.keys]
            if not chosen.verdict.ok:
                # Polished, the effect no longer matters: keep the better-fitted model without it.
                self.polished_away[chosen.cand.key] = chosen.cand
                self.model = chosen.model.truncated(len(self.model.x))
                self.work_pred = prob.predict([self.model.params()])[0]
                assert chosen.jac is not None
                self.pred, self.jac = prob.whole(self.model, self.work_pred), chosen.jac[:, : len(self.model.x)]
                log("polished away", chosen.cand.label, chosen.verdict)
                tr.add("break ties", chosen.cand.label, chosen.verdict.rule, "polished away: kept the model without it",
                       close=chosen.verdict.close, **chosen.verdict.numbers(), **_against(chosen.verdict, st))
                continue
            if not self.findings:  # the baseline is the base model as fitted just before the first finding
                self.base, self.base_pred = self.model, self.pred
            self.findings += self.found(chosen)
            tr.add("finding", chosen.cand.label, chosen.verdict.rule, "added", close=chosen.verdict.close,
                   params=chosen.cand.report(chosen.model.params()), **chosen.verdict.numbers())
            assert chosen.jac is not None
            self.model, self.pred, self.work_pred, self.jac = chosen.model, chosen.pred, chosen.work, chosen.jac
            self.jac_at = chosen.jac_at
            kept_base = False
        with self.stages("backward check", f"{len(self.findings)} findings"):
            self.backward_check()
        return self.result()

    def found(self, chosen: Trial) -> list[Finding]:
        """The findings a chosen trial adds: one, or one per part of a composite (each part's
        "before" the model with the parts ahead of it on, the later ones off)."""
        parts = chosen.cand.parts or (chosen.cand,)
        n0, x = len(self.model.x), chosen.model.x
        steps = [self.model] + [Model(chosen.model.nominal, chosen.model.frees,
                                      np.r_[x[:n0 + sum(len(c.frees) for c in parts[:i + 1])],
                                            np.zeros(len(x) - n0 - sum(len(c.frees) for c in parts[:i + 1]))])
                                for i in range(len(parts) - 1)] + [chosen.model]
        mids = self.prob.predict([m.params() for m in steps[1:-1]], whole=True) if len(parts) > 1 else []
        preds = [self.pred, *mids, chosen.pred]
        return [finding(self.prob, c, steps[i], preds[i], steps[i + 1], preds[i + 1], chosen.verdict, self.rate)
                for i, c in enumerate(parts)]

    def at_floor(self, when: str) -> bool:
        ratios = self.prob.ratios(self.pred, self.rate)
        self.log("systematic ratios" if when == "before refit" else when, {c: round(v, 2) for c, v in ratios.items()})
        worst = max(ratios, key=lambda c: ratios[c])
        if ratios[worst] <= self.st.systematic:
            self.trace.add("stop", None, "every channel's systematic ratio <= systematic", f"at the noise floor ({when})",
                           worst=worst, ratio=ratios[worst], systematic=self.st.systematic)
            return True
        return False

    # --- stages ----------------------------------------------------------------------------
    def stated_pins(self, model: Model) -> list[str]:
        """The stated base parameters (`stated`) `model` holds at a bound."""
        return [k for k in model.pinned(len(self.x0)) if k in self.stated]

    def refit(self, ranked: list[Screened], max_refits: int, share: float | None = None
              ) -> tuple[list[Trial], _BetterBase | None, bool]:
        """Refit the best screened candidates (those within refit_share, or `share`, of the best),
        each from the current fit and from the nominal base parameters at the best size of its
        parameter; judge each. Returns the trials that pay off, the better base parameters a
        refit that did not pay off found, and whether a candidate left the pool as too small to
        claim. Every trial is kept in `refitted` (the round's, until the next refit)."""
        prob, st, tr = self.prob, self.st, self.trace
        share = st.refit_share if share is None else share
        q = np.linalg.qr(self.jac)[0]  # what the base parameters can absorb, to first order
        good: list[Trial] = []
        better_base: _BetterBase | None = None
        too_small = False
        todo: list[Screened] = []
        for sc in ranked[:max_refits]:
            if sc.gain < share * ranked[0].gain:
                tr.add("refit", sc.cand.label, "screened gain >= refit_share x the best", "not refitted",
                       close=abs(sc.gain - share * ranked[0].gain) < st.close_margin * share * ranked[0].gain,
                       other=ranked[0].cand.label, gain=sc.gain, best=ranked[0].gain, refit_share=share)
                break
            todo.append(sc)

        # The candidates are refitted side by side (each from the same state), then judged in order.
        # Every candidate's fits (both coordinates of one with an alternate) side by side at once.
        jobs = [(i, c) for i, sc in enumerate(todo) for c in self.coordinates(sc.cand)]
        fits = side_by_side([lambda sc=todo[i], c=c: self.fit_one(sc, c, q) for i, c in jobs])
        self.refitted = [self.judged([f for (i, _), f in zip(jobs, fits) if i == k]) for k in range(len(todo))]
        for t in self.refitted:
            cand, trial, twork, verdict = t.cand, t.model, t.work, t.verdict
            self.log("refit", cand.label, cand.report(trial.params()), verdict)
            tr.add("judge", cand.label, verdict.rule, "pays off" if verdict.ok else "does not pay off", close=verdict.close,
                   params=cand.report(trial.params()), **verdict.numbers(), **_against(verdict, st))
            if verdict.ok:
                good.append(t)
                continue
            if not verdict.claimable:
                # The record wants it only at a size the base's form mimics: not an effect here,
                # and not to be screened again ahead of the others.
                self.pool = [c for c in self.pool if c.key != cand.key]
                too_small = True
                tr.add("judge", cand.label, "claimable size", "left the pool: too small to claim")
            elif RULES[7] in verdict.failed and verdict.dcost < -st.min_gain:
                # It gains, but only where the base's own parameters mimic it, not where it shows:
                # the base's form (its parameters left in a wrong basin), not to be screened again.
                # (One that does not gain at all fails as any other: the search may end there.)
                self.pool = [c for c in self.pool if c.key != cand.key]
                too_small = True
                tr.add("judge", cand.label, "gains where it shows (signature_contrast)",
                       "left the pool: it stands in for the base's own parameters", **(verdict.shows or {}),
                       signature_contrast=st.signature_contrast)
            if verdict.dcost < -st.min_gain and not {RULES[6], RULES[7], RULES[8]} & set(verdict.failed):
                # Not the effect but a better fit of the base parameters: remember those — not a
                # phase fault's, dropped for what it does to the other readings: its base
                # parameters were bent around it and would carry it into the next round. (A refit
                # whose effect is too small to claim does leave its base: a lag the spool's form
                # makes, and its base's spool is the better one — a clean record otherwise gains
                # a leak in the spool's place.)
                cost = prob.fit_cost(twork)
                if better_base is None or cost < better_base.cost:
                    better_base = _BetterBase(cost, trial.truncated(len(self.model.x)), cand.label)
        return good, better_base, too_small

    def refit_one(self, sc: Screened, q: np.ndarray) -> Trial:
        """Refit one screened candidate from the current fit and from the nominal base parameters
        (the current fit may have bent them to stand in for this very effect), each at the best
        size of the candidate's parameter; keep the better fit, judged."""
        return self.judged(side_by_side([lambda c=c: self.fit_one(sc, c, q) for c in self.coordinates(sc.cand)]))

    @staticmethod
    def coordinates(cand: Candidate) -> tuple[Candidate, ...]:
        """A candidate with an alternate coordinate (`Candidate.alternate`: a vertical rig's
        asymmetry with the weight it trades with held) is refitted both ways (side by side)."""
        return (cand, cand.alternate) if cand.alternate is not None else (cand,)

    def fit_one(self, sc: Screened, cand: Candidate, q: np.ndarray) -> tuple[Candidate, Model, dict, np.ndarray]:
        starts = [start.with_candidate(cand, sc.step) for start in _restarts(self.model, self.x0, self.xn)]
        if cand.restart:  # and from what the record itself shows of the effect (`Candidate.restart`)
            starts += [s.moved_to(dict(cand.restart)) for s in starts]
        trial, twork, tjac = fit(self.prob, _scan(self.prob, starts, cand, q), iters=self.st.refit_iters)
        return cand, trial, twork, tjac

    def judged(self, fits: list[tuple[Candidate, Model, dict, np.ndarray]]) -> Trial:
        """The better fit of a candidate's coordinates (the first on a tie) among those that hold at
        their fitted point (`Candidate.holds`), judged."""
        held = []
        for f in fits:
            if f[0].holds is None or f[0].holds(f[1].params()):
                held.append(f)
            else:
                self.trace.add("judge", f[0].label, "the coordinate holds at its fit (Candidate.holds)",
                               "that coordinate's fit left, the other judged", cost=self.prob.fit_cost(f[2]))
        cand, trial, twork, tjac = min(held or fits, key=lambda f: self.prob.fit_cost(f[2]))
        tpred, verdict = judge(self.prob, self.pred, trial, twork, self.model, cand)
        return Trial(cand, trial, twork, tpred, verdict, tjac, trial.x)

    def sibling_check(self, chosen: Trial, screened: dict[tuple[str, str | None], Screened]) -> Trial | None:
        """A sensor fault chosen on a reading with a sibling (the other chamber's pressure, measured
        alike) is weighed against the same fault on the sibling, refitted from its screened size
        (or, carrying no evidence in the screen, from the same size). The sibling pays off too,
        with the same sign and within sibling_ratio in size — or the sibling already holds that
        fault as a finding, alike: the fault is common to both readings, the plant's form (lines
        between valve and chambers, the valve's own), not two sensors failing alike, and neither
        is claimed (both leave the pool; an earlier finding goes at the backward check). The
        sibling pays off otherwise: the two are polished and compared on a common base, and the
        record decides the chamber (smaller ΔBIC). Returns the trial to add, or None."""
        st, tr, c = self.st, self.trace, chosen.cand
        mine = _size(chosen.model, c)
        self.mirror = None
        rule = "the same fault on the sibling reading pays off, same sign, sizes within sibling_ratio"
        sib_key = (c.effect, c.sibling)
        found = next((f for f in self.findings if f.cand.key == sib_key), None)
        if found is not None:
            theirs = _size(chosen.model, found.cand)
            ratio = _ratio(mine, theirs)
            if mine * theirs > 0 and ratio <= st.sibling_ratio:
                self.pool = [d for d in self.pool if d.key != c.key]
                self.common.append(found)
                tr.add("sibling check", c.label, rule + " (the sibling's finding)",
                       "common to both readings: the plant's form, neither claimed", close=_near_ratio(ratio, st),
                       other=found.cand.label, size=mine, sibling_size=theirs, ratio=ratio, sibling_ratio=st.sibling_ratio)
                return None
            return chosen
        # A sibling polished away in an earlier round paid off there: it is weighed again (its
        # leaving the pool says nothing of whether the chosen reading's fault is common to both).
        sib = next((d for d in self.pool if d.key == sib_key), None) or self.polished_away.get(sib_key)
        if sib is None or not sib.frees:
            return chosen
        f = sib.frees[0]
        sc = screened.get(sib.key) or Screened(sib, 0.0, float(np.clip(f.coord(f.origin + mine, 0.0), f.lo, f.hi)))
        t = self.sibling_refit(sc)
        self.log("sibling", sib.label, sib.report(t.model.params()), t.verdict)
        tr.add("judge", sib.label, t.verdict.rule, "pays off" if t.verdict.ok else "does not pay off", close=t.verdict.close,
               params=sib.report(t.model.params()), **t.verdict.numbers(), **_against(t.verdict, st))
        theirs = _size(t.model, sib)
        ratio = _ratio(mine, theirs)
        self.mirror = abs(theirs / mine) if mine else math.inf
        mine_pins, their_pins = self.stated_pins(chosen.model), self.stated_pins(t.model)
        if mine_pins and not their_pins and t.verdict.dbic < 0 and t.verdict.dcost < 0 and mine * theirs < 0:
            # Two offsets of opposite sign, one per chamber, trade with the weight a stated mass
            # carries: the one that needs a stated parameter at its bound contradicts the metadata,
            # the other keeps the whole stated rig inside its bounds. The metadata decides.
            won = self.polish(t)
            if won.verdict.ok and not self.stated_pins(won.model):
                tr.add("sibling check", won.cand.label, "the chosen fault needs a stated parameter at its bound, the "
                       "sibling's keeps the stated rig inside its bounds (the metadata decides the chamber)", "chosen",
                       other=c.label, pinned=mine_pins, size=mine, sibling_size=_size(won.model, sib),
                       dbic=won.verdict.dbic, other_dbic=chosen.verdict.dbic)
                return won
        # The own-reading share is no judge between the two readings: the base's pressure levels
        # (supply, tank) carry a chamber's offset over into its sibling's reading, so the true
        # chamber's fault may show more in the other reading. A sibling that meets every other rule,
        # not alike, contends on the whole record.
        only_share = not t.verdict.ok and t.verdict.failed == ("explained >= min_share",)
        if not t.verdict.ok and not (only_share and mine * theirs < 0):
            tr.add("sibling check", c.label, rule, "the sibling does not pay off: this reading's own fault",
                   other=sib.label, size=mine, sibling_size=theirs)
            return chosen
        if mine * theirs > 0 and ratio <= st.sibling_ratio:
            self.pool = [d for d in self.pool if d.key not in (c.key, sib.key)]
            tr.add("sibling check", c.label, rule, "common to both readings: the plant's form, neither claimed",
                   close=_near_ratio(ratio, st), other=sib.label, size=mine, sibling_size=theirs, ratio=ratio,
                   sibling_ratio=st.sibling_ratio)
            return None
        return self.chamber_decided(chosen, t, "not alike: the chambers compared on a common base, smaller dBIC "
                                    "(the own-reading share waived between them)", size=mine, sibling_size=theirs)

    def sibling_refit(self, sc: Screened) -> Trial:
        """`refit_one` of a candidate the sibling checks weigh, once per chosen fault: the model
        they refit from does not change between them (a fault that moves chamber meets its
        reading's other kind again, already refitted by `sibling_check`)."""
        key = (sc.cand.key, sc.step)
        if key not in self.sibling_refits:
            self.sibling_refits[key] = self.refit_one(sc, np.linalg.qr(self.jac)[0])
        return self.sibling_refits[key]

    def interchangeable(self, chosen: Trial) -> bool:
        """Whether the chambers' readings are interchangeable for `chosen`'s level fault on this
        record: the same fault refitted on the sibling (`sibling_check`) came to a size within
        sibling_ratio of the chosen one's, of either sign (the base's levels then carry one
        chamber's fault into the other's reading); unknown (no such refit) counts as yes. A
        sibling that fits only a small fault leaves the chosen reading's own, and the other kind
        is not weighed (`other_kind`: a refit saved)."""
        if self.mirror is None or self.mirror * self.st.sibling_ratio >= 1.0:
            return True
        self.trace.add("sibling check", chosen.cand.label, "the same fault on the sibling fits within sibling_ratio of "
                       "its size (the chambers interchangeable: the other kind weighed too)",
                       "it does not: the other kind not weighed", mirror=self.mirror, sibling_ratio=self.st.sibling_ratio)
        return False

    def other_kind(self, chosen: Trial, screened: dict[tuple[str, str | None], Screened]) -> Trial:
        """A level fault (offset, gain) chosen on a reading with a sibling is weighed also against
        the sibling's other level fault (the same kind is `sibling_check`'s): the base's pressure
        levels (supply, tank) move both chambers together, so an offset on one chamber can be
        fitted, nearly as well, as a gain (or offset) on the other. The other kind is refitted
        from its screened size when the screen found evidence for it; if it contends (`contends`)
        the two are compared on a common base and the smaller ΔBIC decides the chamber. Where the
        fault moves, that reading's own two level faults are then weighed as one sensor's (tied
        within min_gain, the preference names it). Returns the trial to add."""
        c = chosen.cand
        t = self.contends(chosen, screened, c.sibling, lambda e: e != c.effect, "the sibling's other level fault pays "
                          "off too", "it does not: this reading's own fault")
        if t is None:
            return chosen
        won = self.chamber_decided(chosen, t, "the sibling's other level fault: the chambers compared on a common "
                                   "base, smaller dBIC (the own-reading share waived between them)")
        if won.cand is c or not won.verdict.ok:
            return won
        t = self.contends(won, screened, won.cand.channel, lambda e: e == c.effect, "that reading's other level "
                          "fault pays off too", "it does not: the fault moved")
        if t is None:
            return won
        return self.chamber_decided(won, t, "one sensor's two level faults compared on a common base: tied within "
                                    "min_gain, the preference names it, else smaller dBIC", prefer=True)

    def contends(self, chosen: Trial, screened: dict[tuple[str, str | None], Screened], channel: str | None,
                 kind: Callable[[str], bool], rule: str, outcome: str) -> Trial | None:
        """The level fault on `channel` whose effect id passes `kind`, refitted from its screened
        size (None where the screen found no evidence for it), judged: it contends with `chosen`
        if it pays off or misses only the own-reading share (no judge between two readings)."""
        alt = next((d for d in self.pool if d.level and d.channel == channel and kind(d.effect) and d.frees), None)
        sc = screened.get(alt.key) if alt is not None else None
        if sc is None:
            return None
        t = self.sibling_refit(sc)
        self.log("sibling", sc.cand.label, sc.cand.report(t.model.params()), t.verdict)
        self.trace.add("judge", sc.cand.label, t.verdict.rule, "pays off" if t.verdict.ok else "does not pay off",
                       close=t.verdict.close, params=sc.cand.report(t.model.params()), **t.verdict.numbers(),
                       **_against(t.verdict, self.st))
        if not t.verdict.ok and t.verdict.failed != ("explained >= min_share",):
            self.trace.add("sibling check", chosen.cand.label, rule, outcome, other=sc.cand.label)
            return None
        return t

    def chamber_decided(self, chosen: Trial, t: Trial, rule: str, prefer: bool = False, **numbers: float) -> Trial:
        """`chosen` against `t`, a fault on the sibling reading refitted (or, `prefer`, the other
        fault of the same reading), both polished and compared on a common base: the smaller ΔBIC
        is added; a pair tied within min_gain is reported as close with the other named (and with
        `prefer`, the more common effect of the two is the one added)."""
        st = self.st
        both = on_common_base(self.prob, self.pred, self.model, [chosen, self.polish(t)], self.log)
        won = min(both, key=lambda g: g.verdict.dbic)
        lost = both[1] if won is both[0] else both[0]
        tied = _tied(dataclasses.replace(won.verdict, ok=True), dataclasses.replace(lost.verdict, ok=True), st.min_gain)
        if tied and prefer and _rank(lost.cand.effect, st) < _rank(won.cand.effect, st):
            won, lost = lost, won
        v = won.verdict
        if not v.ok and v.failed == ("explained >= min_share",) and not v.close_rules:
            v = dataclasses.replace(v, ok=True, failed=())  # judged against its sibling on the whole record
        if tied:
            v.alternative = (f" {lost.cand.label} ({', '.join(f'{k} = {x:.4g}' for k, x in lost.cand.report(lost.model.params()).items())})"
                             " explains the record about as well; this record barely tells the two "
                             + ("faults" if won.cand.channel == lost.cand.channel else "chambers") + " apart.")
        won = Trial(won.cand, won.model, won.work, won.pred, v, won.jac, won.jac_at)
        self.trace.add("sibling check", won.cand.label, rule, "chosen" if v.ok else "chosen, but no longer pays off",
                       other=lost.cand.label, close=tied, **numbers, dbic=v.dbic, other_dbic=lost.verdict.dbic,
                       dcost=v.dcost, other_dcost=lost.verdict.dcost)
        return won

    def settle(self, good: list[Trial], better_base: _BetterBase) -> list[Trial]:
        """A refit whose effect did nothing still cut the cost: the current fit had not settled.
        An effect must pay off against those base parameters too, or it is only getting the
        credit for their convergence."""
        bpred = self.prob.predict([better_base.model.params()], whole=True)[0]
        settled = []
        for g in good:
            v = pays_off(self.prob, bpred, g.model, g.pred, self.model, g.cand)
            if v.ok:
                settled.append(g)
            else:
                self.log("not against the better base", g.cand.label)
            self.trace.add("judge", g.cand.label, "pays off against the better base parameters of " + better_base.cand,
                           "kept" if v.ok else "dropped: only the base's convergence", close=v.close, **v.numbers(),
                           **_against(v, self.st))
        return settled

    def own_form(self, good: list[Trial]) -> tuple[list[Trial], bool, _BetterBase | None]:
        """A trial whose effect the base's own form can also make (`Candidate.form`: a reading's
        delay, the spool slowed by it) must pay off also against the model without it refitted
        from that form; where it does not, it is the base's form, not an effect: it leaves the
        pool. Returns the trials kept, whether one left, and the best such refit that cut the
        fit cost (a better base)."""
        prob, st, tr = self.prob, self.st, self.trace
        kept: list[Trial] = []
        left = False
        formed: _BetterBase | None = None
        cost0 = prob.fit_cost(self.work_pred)
        for g in good:
            form = g.cand.form(self.model.params(), g.cand.report(g.model.params())) if g.cand.form is not None else None
            if not form or _at((start := self.model.moved_to(form)).x, self.model):  # no form, or the model already there
                kept.append(g)
                continue
            m, work, _ = fit(prob, start, iters=st.refit_iters)
            cost = prob.fit_cost(work)
            # The record as a whole must prefer the effect (ΔBIC, min_gain), and its own reading
            # must be no worse with it than that form leaves it (by more than min_share of the
            # reading's systematic error): a delay whose gain against the form lies in the other
            # readings while its own gets worse is not that reading's fault.
            dbic, dcost = prob.bic_delta(fpred := prob.whole(m, work), g.pred, max(1, len(g.cand.frees)))
            share = own_share(prob, fpred, g.pred, g.cand)
            ok = dbic < 0 and dcost < -st.min_gain and share >= -st.min_share
            close = abs(dcost + st.min_gain) < st.close_margin * st.min_gain or abs(share + st.min_share) < st.close_margin * st.min_share
            tr.add("own form", g.cand.label, "against the model without it refitted from the base's own form that makes it: "
                   "dBIC < 0, dcost < -min_gain, its own reading no worse by more than min_share (delay_against_form)",
                   "kept" if ok else "left the pool: the base's own form", close=close, form=dict(form),
                   refitted={k: v for k, v in m.values().items() if k in form}, fit_cost=cost, fit_cost_before=cost0,
                   dbic=dbic, dcost=dcost, explained=share, min_gain=st.min_gain, min_share=st.min_share)
            self.log("own form", g.cand.label, "kept" if ok else "the base's form", dbic, dcost, share)
            if ok:
                kept.append(g)
                continue
            self.pool = [c for c in self.pool if c.key != g.cand.key]
            left = True
            if cost < cost0 and (formed is None or cost < formed.cost):
                formed = _BetterBase(cost, m, g.cand.label + " as the base's own form")
        return kept, left, formed

    def polish(self, g: Trial) -> Trial:
        prob, st = self.prob, self.st
        trial, twork, tjac = fit(prob, g.model, iters=st.polish_iters, pred0=g.work, jac0=g.warm(st))
        again = trial.unpinned(self.x0, self.xn)
        if not np.array_equal(again.x, trial.x):
            # Stuck with base parameters at a bound: polish once more from their nominal values.
            retry = fit(prob, again, iters=st.polish_iters)
            if prob.fit_cost(retry[1]) < prob.fit_cost(twork):
                trial, twork, tjac = retry
        tpred, verdict = judge(prob, self.pred, trial, twork, self.model, g.cand)
        return Trial(g.cand, trial, twork, tpred, verdict, tjac, trial.x)

    def break_ties(self, good: list[Trial]) -> Trial:
        """Of the trials that pay off, the one to add: close contenders (the second within
        contender_dbic of the best's ΔBIC) are polished and compared on a common base; two the
        record cannot tell apart (both at the noise floor, or two faults of one sensor tied
        within min_gain) are named by preference, and the verdict says so."""
        prob, st, tr = self.prob, self.st, self.trace
        good = sorted(good, key=lambda g: g.verdict.dbic)
        contenders = [g for g in good[:2] if g.verdict.dbic <= st.contender_dbic * good[0].verdict.dbic]
        if len(good) > 1:
            tr.add("break ties", good[1].cand.label, "dBIC <= contender_dbic x the best's",
                   "polished beside the best" if len(contenders) == 2 else "not a contender", other=good[0].cand.label,
                   dbic=good[1].verdict.dbic, best_dbic=good[0].verdict.dbic, contender_dbic=st.contender_dbic)
        polished = side_by_side([lambda g=g: self.polish(g) for g in contenders])
        for g in polished:
            self.log("polished", g.cand.label, g.cand.report(g.model.params()), g.verdict)
        if len(polished) == 2:
            polished = on_common_base(prob, self.pred, self.model, polished, self.log)
        # Both at the noise floor, or two faults of one sensor whose held-out costs are apart by
        # less than the min_gain that makes a refit count at all (a reading that moves little
        # about its mean is scaled or shifted alike): the record cannot tell them apart; name
        # the more common effect (preference: an offset before a gain before a delay...) and say so.
        at_floor = [g for g in polished if max(prob.ratios(g.pred, self.rate).values()) <= st.systematic]
        rule = "both at the noise floor: preference"
        if len(polished) == 2 and polished[0].cand.channel is not None and polished[0].cand.channel == polished[1].cand.channel \
                and _tied(polished[0].verdict, polished[1].verdict, st.min_gain):
            at_floor = polished
            rule = "one sensor's faults tied within min_gain: preference"
        if len(at_floor) == 2:
            at_floor.sort(key=lambda g: _rank(g.cand.effect, st))
            chosen, other = at_floor
            chosen.verdict.alternative = (
                f" {other.cand.label} ({', '.join(f'{k} = {v:.4g}' for k, v in other.cand.report(other.model.params()).items())}) "
                "explains the record as well; this record cannot tell the two apart.")
            tr.add("break ties", chosen.cand.label, rule, "named (the more common effect)", close=True, other=other.cand.label,
                   dbic=chosen.verdict.dbic, other_dbic=other.verdict.dbic, dcost=chosen.verdict.dcost,
                   other_dcost=other.verdict.dcost)
            return chosen
        chosen = min(polished, key=lambda g: g.verdict.dbic)
        if len(polished) == 2:
            other = polished[1] if chosen is polished[0] else polished[0]
            tr.add("break ties", chosen.cand.label, "smaller dBIC on a common base", "chosen",
                   close=_tied(chosen.verdict, other.verdict, st.close_margin * st.min_gain) or not other.verdict.ok,
                   other=other.cand.label, dbic=chosen.verdict.dbic, other_dbic=other.verdict.dbic,
                   dcost=chosen.verdict.dcost, other_dcost=other.verdict.dcost)
        return chosen

    def backward_check(self) -> None:
        """Latest first: a finding the others make redundant is dropped. Without it the model is
        refitted from where the search left it and from the base parameters anew: a finding
        added late may only have led the fit out of a basin it had settled in."""
        prob, st, tr = self.prob, self.st, self.trace
        tr.round += 1

        def goes(f: Finding) -> str | None:
            """Why a finding goes whatever the model without it would give, or None. Refits after a
            finding move its parameters too: one that ends below a claimable size goes; so does one
            whose sibling reading wanted the same fault since (sibling_check), and one whose
            coordinate no longer holds where the model now stands (`Candidate.holds`: the weighed
            asymmetry's mass moved to its floor) — as its fit would not have been judged there."""
            params = self.model.params()
            if f in self.common:
                return "common to both sibling readings (sibling_ratio)"
            if f.cand.claimable is not None and not f.cand.claimable(f.cand.report(params)):
                return "below a claimable size"
            if f.cand.holds is not None and not f.cand.holds(params):
                return "its coordinate no longer holds at the model (Candidate.holds)"
            return None

        def refit_all(fs: list[Finding], early: list[bool]) -> list[tuple[Model, dict, dict, np.ndarray, list[int]]]:
            """The model without each of `fs` refitted from both restarts, the better kept, every
            fit side by side; with `early`, a start stops once it can no longer come near the
            model with the finding (`_far_above`, backward_stop). Per finding: the model, its
            whole-record and working-window predictions, its Jacobian and the iterations at which
            starts were stopped early."""
            with_cost, n_data = prob.fit_cost(self.work_pred), int(prob.fit_mask.sum()) * len(prob.channels)

            def one(s: Model, stopping: bool) -> tuple[tuple[Model, dict, np.ndarray], int | None]:
                info: dict[str, Any] = {}
                stop = (lambda costs, left: _far_above(costs, left, with_cost, n_data, st.backward_stop, st.backward_rate)) \
                    if stopping and st.backward_stop > 0 else None
                out = fit(prob, s, iters=st.refit_iters, stop=stop, info=info)
                return out, (info["iterations"] if info["ended"] == "stopped" else None)

            starts = [_restarts(self.model.without(f.cand, self.nominal), self.x0, self.xn) for f in fs]
            flat = side_by_side([lambda s=s, e=e: one(s, e) for ss, e in zip(starts, early) for s in ss])
            best, stopped, k = [], [], 0
            for ss in starts:
                got = flat[k:k + len(ss)]
                k += len(ss)
                best.append(min((g[0] for g in got), key=lambda g: prob.fit_cost(g[1])))
                stopped.append([n for _, n in got if n is not None])
            wholes = prob.predict([m.params() for m, _, _ in best], whole=True) if prob.truncated or prob.sparse \
                else [w for _, w, _ in best]
            return [(m, wp, ww, wj, st_) for (m, ww, wj), wp, st_ in zip(best, wholes, stopped)]

        def refit_without(f: Finding) -> tuple[Model, dict, dict, np.ndarray]:
            return refit_all([f], [False])[0][:4]

        # With two findings or more, every one's refit without it runs side by side at once (each
        # from the model as it stands): used while no drop has moved the model.
        order = list(reversed(self.findings))
        ahead = dict(zip(map(id, order), refit_all(order, [goes(f) is None for f in order]))) if len(order) >= 2 else {}
        for f in order:
            why = goes(f)
            small = why is not None
            if len(self.findings) < 2 and not small:
                break  # a single finding was weighed against the model without it when it was made
            got = ahead.pop(id(f), None)
            wmodel, wpred, wwork, wjac, early = got if got is not None else refit_all([f], [not small])[0]
            dbic, dcost = prob.bic_delta(wpred, self.pred, max(1, len(f.cand.frees)))
            if early and not (dbic < 0 and dcost < -st.min_gain * (1.0 + st.close_margin)):
                # The early stop's projection failed (the finding would go): the refits without it
                # run to their end, and the decision is made on those.
                tr.add("backward check", f.cand.label, "backward_stop: projection not borne out", "refitted without it in full",
                       dbic=dbic, dcost=dcost)
                early = []
                wmodel, wpred, wwork, wjac = refit_without(f)
                dbic, dcost = prob.bic_delta(wpred, self.pred, max(1, len(f.cand.frees)))
            self.log("backward check", f.cand.label, f"dBIC {dbic:.0f} dcost {dcost:+.3f}")
            # As in `pays_off`: a finding kept only by a margin within close_margin of min_gain is
            # a close decision, and the simpler model (without it) stands.
            close = not small and abs(dcost + st.min_gain) < st.close_margin * st.min_gain
            keep = not small and dbic < 0 and dcost < -st.min_gain and not close
            rule = why or "dBIC < 0 and dcost < -min_gain (by more than close_margin) against the model refitted without it"
            if early:
                rule += (f"; its refit stopped early at {', '.join(map(str, early))} iteration(s) of {st.refit_iters} "
                         "(backward_stop: it could no longer come near the model with it)")
            tr.add("backward check", f.cand.label, rule, "kept" if keep else "dropped", close=close,
                   other="the model refitted without it" if close else None, dbic=dbic, dcost=dcost, min_gain=st.min_gain,
                   **({"close_margin": st.close_margin} if close else {}),
                   **({"backward_stop": st.backward_stop, "stopped_at": early} if early else {}))
            if not keep:
                self.findings.remove(f)
                self.model, self.pred, self.work_pred, self.jac = wmodel, wpred, wwork, wjac
                self.jac_at = wmodel.x
                ahead.clear()  # the model moved: the refits run ahead of the drop no longer apply
        # A drop refits the model, which moves the findings checked before it: one it left below a
        # claimable size (a leak gone to zero once the dead band beside it went), or where its
        # coordinate no longer holds, goes too.
        while gone := [(f, why) for f in self.findings if (why := goes(f)) is not None]:
            f, why = gone[-1]
            self.log(f"{why} after a drop", f.cand.label)
            tr.add("backward check", f.cand.label, f"{why} after a drop", "dropped")
            self.model, self.pred, self.work_pred, self.jac = refit_without(f)
            self.jac_at = self.model.x
            self.findings.remove(f)

    def result(self) -> Result:
        findings, prob = self.findings, self.prob
        base, base_pred = self.base, self.base_pred
        if findings and findings[0].pred_before is not base_pred:
            first = findings[0]  # after a drop, the first remaining finding starts from the baseline
            first.pred_before = base_pred
            first.rmse_before = prob.rmse(base_pred)
        if not findings:
            base, base_pred = self.model, self.pred
        else:  # refits after the last finding belong to it: its "after" is the final model
            last = findings[-1]
            last.pred_after = self.pred
            last.rmse_after = prob.rmse(self.pred)
            last.params = last.cand.report(self.model.params())
        return Result(base, base_pred, self.model, self.pred, findings, self.work_pred, self.jac)


def probe(prob: Problem, res: Result, pool: list[Candidate], rate: float, log: Log = lambda *a: None,
          trace: Trace | None = None) -> Finding | None:
    """Structure outside the effect vocabulary: the probe of `pool` (a force over part of the
    stroke, a pump's ripple...) that pays off on the held-out data on top of the final model by
    probe_gain of the cost, or None. Not a finding of the record: evidence that structure
    remains which no effect of the vocabulary accounts for."""
    st = prob.settings
    tr = trace if trace is not None else Trace()
    if not pool or res.work_pred is None or res.jac is None:
        return None
    model, pred = res.model, res.pred
    best: tuple[float, Finding] | None = None
    # A tone (a pump's ripple) is small against a broadband residual but stands out in its band:
    # its amplitude is fitted with the model held, and it must remove probe_share of the
    # residual's power there and pay off on the held-out data.
    tones = {c.tone_hz: c for c in pool if c.tone_hz}
    for f_hz, cand in tones.items():
        trial, twork = _tone(prob, model, cand)
        tpred = prob.whole(trial, twork)
        dbic, dcost = prob.bic_delta(pred, tpred, len(cand.frees))
        share = prob.explained_in_band(pred, tpred, f_hz, rate)
        log("tone", f"{f_hz:.4f} Hz", cand.report(trial.params()), f"dBIC {dbic:.0f} dcost {dcost:+.4f} in band {share:.0%}")
        ok = dbic < 0 and share >= st.probe_share
        tr.add("probes", f"{cand.label} at {f_hz:.4f} Hz", "dBIC < 0 and explained in band >= probe_share",
               "pays off" if ok else "does not pay off", close=abs(share - st.probe_share) < st.close_margin * st.probe_share,
               dbic=dbic, dcost=dcost, explained_in_band=share, probe_share=st.probe_share)
        if ok and (best is None or dbic < best[0]):
            verdict = Verdict(True, dbic, dcost, dcost, share)
            best = (dbic, finding(prob, cand, model, pred, trial, tpred, verdict, rate))
    pool = [c for c in pool if not c.tone_hz]
    if not pool:
        return best[1] if best else None
    ranked = screen(prob, model, res.work_pred, res.jac, pool)
    log("probe screen", [(c.effect, round(g, 3)) for c, g, _ in ranked[:4]])
    q = np.linalg.qr(res.jac)[0]
    def refit_probe(cand: Candidate, step: float | None) -> tuple[Model, dict, Verdict]:
        trial, twork, _ = fit(prob, _scan(prob, [model.with_candidate(cand, step)], cand, q), iters=st.refit_iters)
        return trial, *judge(prob, pred, trial, twork, model, cand)

    # The probes are refitted side by side (each from the same state), then judged in order; or
    # (probe_one_first) one at a time, best screened first, until one pays off.
    top = ranked[: st.probe_refits]
    jobs = [lambda c=c, s=s: refit_probe(c, s) for c, _, s in top]
    fitted = side_by_side(jobs) if not st.probe_one_first else []
    for i, (cand, _, _) in enumerate(top):
        if st.probe_one_first:
            if best is not None:
                tr.add("probes", cand.label, "a probe before it in the screen pays off (probe_one_first)", "not refitted",
                       other=best[1].cand.label)
                continue
            fitted.append(jobs[i]())
        trial, tpred, verdict = fitted[i]
        log("probe", cand.label, cand.report(trial.params()), verdict)
        ok = verdict.ok and verdict.dcost < -st.probe_gain and verdict.explained >= st.probe_share
        tr.add("probes", cand.label, "pays off, dcost < -probe_gain and explained >= probe_share",
               "pays off" if ok else "does not pay off",
               close=verdict.ok and (abs(verdict.dcost + st.probe_gain) < st.close_margin * st.probe_gain
                                     or abs(verdict.explained - st.probe_share) < st.close_margin * st.probe_share),
               params=cand.report(trial.params()), **verdict.numbers())
        if ok and (best is None or verdict.dbic < best[0]):
            best = (verdict.dbic, finding(prob, cand, model, pred, trial, tpred, verdict, rate))
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
    trial, twork, _ = fit(prob, start, iters=prob.settings.tone_iters, hold=frozenset(f.key for f in model.frees))
    return trial, twork


def _far_above(costs: list[float], left: int, with_cost: float, n_data: int, backward_stop: float,
               rate: float = DEFAULT.backward_rate) -> bool:
    """Can a refit without a finding no longer come near the model with it? Its fit-block cost
    (`costs` so far, the start's first), even gaining on each of the `left` iterations twice the
    best share of its cost that any iteration so far gained (no less than `rate`, at most half),
    would stay above the
    model with it (`with_cost`) by more than `backward_stop` as a held-out dcost reads it (the
    geometric mean of the channels' mean squares: exp(-difference / samples) - 1)."""
    best = max((a - b) / a for a, b in zip(costs, costs[1:]) if a > 0) if len(costs) > 1 else 0.0
    reach = costs[-1] * (1.0 - min(0.5, max(2.0 * best, rate))) ** left
    return math.exp(-(reach - with_cost) / max(n_data, 1)) - 1.0 < -backward_stop


def _size(model: Model, cand: Candidate) -> float:
    """The size of a candidate's first parameter in `model` (its value less its "off" value)."""
    f = cand.frees[0]
    return float(get_value(model.params(), f.key)) - f.origin


def _rank(effect: str, st: SearchSettings) -> int:
    """An effect's place in the preference (more common first; unlisted last)."""
    return st.preference.index(effect) if effect in st.preference else len(st.preference)


def _ratio(a: float, b: float) -> float:
    """The larger of two sizes over the smaller (inf when one is 0)."""
    lo = min(abs(a), abs(b))
    return max(abs(a), abs(b)) / lo if lo > 0 else float("inf")


def _near_ratio(ratio: float, st: SearchSettings) -> bool:
    return abs(ratio - st.sibling_ratio) < st.close_margin * st.sibling_ratio


def _tied(a: Verdict | dict, b: Verdict | dict, min_gain: float = MIN_GAIN) -> bool:
    """Two verdicts whose held-out costs after (1 + dcost of the cost before) differ by less than
    `min_gain` of the larger: no evidence for either over the other by the search's own standard."""
    ca, cb = 1.0 + a["dcost"], 1.0 + b["dcost"]
    return bool(a["ok"] and b["ok"] and abs(ca - cb) < min_gain * max(ca, cb))


def on_common_base(prob: Problem, pred0: dict, model: Model, polished: list[Trial], log: Log) -> list[Trial]:
    """Two contenders polished apart may have settled their base parameters in different basins
    (a flat cost lets them wander), and the better base would then decide between the effects.
    Each contender is also fitted on the other's base (its own parameters only, the base held)
    and keeps the better of the two by the information criterion: the effects are compared on
    the same base."""
    n = len(model.x)
    hold = frozenset(f.key for f in model.frees)

    def on_other(i: int) -> tuple[Trial, list[tuple]]:
        g = polished[i]
        cand, verdict, trial, twork, tjac, tpred, tat = g.cand, g.verdict, g.model, g.work, g.jac, g.pred, g.jac_at
        other = polished[1 - i].model
        x = trial.x.copy()
        x[:n] = other.x[:n]
        moved, mwork, mjac = fit(prob, trial.at(x), iters=prob.settings.common_iters, hold=hold)
        mpred, mverdict = judge(prob, pred0, moved, mwork, model, cand)
        logs: list[tuple] = [("on the other's base", cand.label, cand.report(moved.params()), mverdict)]
        if mverdict.dbic < verdict.dbic:
            # One step with all free: the Jacobian of every parameter (differenced at `moved`)
            # for the screens to come. The step fits the fit blocks and may lose on the held-out
            # ones; then `moved` stays, or the step would decide between the contenders.
            strial, swork, tjac = fit(prob, moved, iters=1, pred0=mwork)
            spred, sverdict = judge(prob, pred0, strial, swork, model, cand)
            logs.append(("one step on", cand.label, cand.report(strial.params()), sverdict))
            trial, twork, tpred, verdict = ((strial, swork, spred, sverdict) if sverdict.dbic <= mverdict.dbic
                                            else (moved, mwork, mpred, mverdict))
            tat = strial.x
        return Trial(cand, trial, twork, tpred, verdict, tjac, tat), logs

    out = []
    for trial, logs in side_by_side([lambda i=i: on_other(i) for i in range(len(polished))]):
        for line in logs:
            log(*line)
        out.append(trial)
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
        octaves = prob.settings.scan_octaves
        values = sorted({float(np.clip(v, f.lo, f.hi)) for v in (sign * f.step * 2.0**k for k in octaves)} - {x_lin})
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


def judge(prob: Problem, pred0: dict, trial: Model, twork: dict, before: Model, cand: Candidate) -> tuple[dict, Verdict]:
    """A fitted trial's whole-record prediction and its verdict (`pays_off`), the two
    whole-record simulations they need (the trial, and the trial with its effect switched off)
    in one batch."""
    if prob.truncated or prob.sparse:
        tpred, abl = prob.predict([trial.params(), trial.ablated(before, cand).params()], whole=True)
    else:
        tpred, abl = twork, None
    return tpred, pays_off(prob, pred0, trial, tpred, before, cand, abl=abl)


def pays_off(prob: Problem, pred0: dict, trial: Model, tpred: dict, before: Model, cand: Candidate,
             abl: dict | None = None) -> Verdict:
    """Does the effect pay off on the held-out data? It must beat the model without it by the
    information criterion and by min_gain of the cost, and so must it against its own refit
    with the effect switched off (else it only helped the base parameters converge); and it
    must remove min_share of some channel's systematic residual (its own signature, not a
    sliver of a misfit it does not account for). The rules are named in `RULES`. Each graded
    rule must be met by more than close_margin of its threshold: a pass within it is close
    and no claim (`Verdict`)."""
    st = prob.settings
    k = max(1, len(cand.frees))
    dbic, dcost = prob.bic_delta(pred0, tpred, k)
    if abl is None:  # the ablated model's whole-record prediction, unless the caller batched it (`judge`)
        abl = prob.predict([trial.ablated(before, cand).params()], whole=True)[0]
    abic, acost = prob.bic_delta(abl, tpred, k)
    # A sensor's fault is in its own reading: there is its signature. (Through the restarts from the
    # measured state it also moves the other channels, so there it can buy a fit it does not explain.)
    share = own_share(prob, pred0, tpred, cand)
    big = cand.claimable is None or cand.claimable(cand.report(trial.params()))
    worse, level = phase_fault(prob, pred0, tpred, cand)
    # The others worse: still the reading's own fault where it takes most of the systematic error
    # of the model's worst reading away and leaves it far below where the model stands on the others.
    if not (worse > st.max_others_worse and share > st.delay_own_share):
        level = None
    shown, shows = gains_where_it_shows(prob, pred0, tpred, cand)
    stood, still = takes_at_standstill(prob, pred0, tpred, cand)
    met = (dbic < 0, dcost < -st.min_gain, abic < 0, acost < -st.min_gain, share >= st.min_share, big,
           worse <= st.max_others_worse or (level is not None and level <= st.delay_own_level), shown, stood)
    near = _near(st, dcost, acost, share)
    failed = [i for i, ok in enumerate(met) if not ok]
    # Close: a graded number within close_margin of its threshold (the ΔBIC and the size are not
    # graded). A verdict that fails only by such margins, or that passes with one of them, is
    # close; a close pass is no claim (`close_rules`): the model without the effect stands.
    close = any(near) if not failed else all(near[i] for i in failed)
    close_rules = tuple(RULES[i] for i, n in enumerate(near) if n and met[i])
    return Verdict(all(met) and not close_rules, dbic, dcost, acost, share, bool(big), tuple(RULES[i] for i in failed),
                   bool(close), close_rules=close_rules, others_worse=worse, own_level=level, shows=shows, still=still)


def own_share(prob: Problem, pred0: dict, tpred: dict, cand: Candidate) -> float:
    """The share of the systematic error that going from `pred0` to `tpred` removes: in the
    candidate's own reading for a sensor's fault (`Candidate.own_reading`, the reading measured),
    else the largest over the channels (`Problem.explained`)."""
    own = cand.channel if cand.own_reading and cand.channel in prob.channels else None
    return prob.explained(pred0, tpred, only=own)


def gains_where_it_shows(prob: Problem, pred0: dict, tpred: dict, cand: Candidate) -> tuple[bool, dict[str, float] | None]:
    """For an effect with samples where it stands apart from the base's form (`Candidate.shows`:
    entrained air where a chamber's pressure runs low): does it cut the held-out error there
    (noise-scaled squares summed over the channels, `pred0` -> `tpred`)? An effect that gains
    only where the base's own parameters could have done the same (entrained air at the
    chambers' typical pressure: a bulk modulus or dead volumes set wrong) and not, or worse,
    where its own signature is, stands in for them; a record that never gets there cannot tell
    it from them. (True, None) for an effect without such samples to test."""
    if cand.shows is None:
        return True, None
    where = np.asarray(cand.shows(), dtype=bool)[: len(prob.val_mask)]
    mask = prob.val_mask & where
    n = int(mask.sum())
    if n == 0:
        return False, {"samples": 0}
    s0 = sum(v for v, _ in prob.channel_ssr(pred0, mask).values())
    s1 = sum(v for v, _ in prob.channel_ssr(tpred, mask).values())
    out = {"samples": n, "before": s0 / n, "after": s1 / n}
    ok = s1 < s0
    rest = prob.val_mask & ~where
    ratio = prob.settings.shows_ratio
    if cand.shows_against_rest and ratio > 0 and rest.any() and s0 > 0:
        # ...and there about as well as elsewhere: the share of the error it leaves where it shows
        # at most shows_ratio times the share it leaves on the other held-out samples — or, where
        # it takes nearly all of the error everywhere (both shares left near the floor, their
        # ratio the floor's scatter), a share taken there at least shows_gain times the one taken
        # elsewhere.
        e0 = sum(v for v, _ in prob.channel_ssr(pred0, rest).values())
        e1 = sum(v for v, _ in prob.channel_ssr(tpred, rest).values())
        left, left_rest = s1 / s0, (e1 / e0 if e0 > 0 else 1.0)
        gain = prob.settings.shows_gain
        out.update(left=left, left_elsewhere=left_rest, shows_ratio=ratio, shows_gain=gain)
        ok = ok and (left <= ratio * left_rest or (gain > 0 and 1.0 - left >= gain * (1.0 - left_rest)))
    return ok, out


def takes_at_standstill(prob: Problem, pred0: dict, tpred: dict, cand: Candidate) -> tuple[bool, dict[str, float] | None]:
    """For an effect with samples where it acts alone (`Candidate.still`: an internal leak where
    the actuator stands still, its flow with no motion or line dynamics beside it): does it take
    at least `still_share` of the held-out error there (noise-scaled squares summed over the
    channels, `pred0` -> `tpred`)? A leak standing in for the dynamics a foreign rig's base form
    misses (line damping, a valve lag) gains in motion and little at rest. Not tested (True) where
    fewer than `still_min_samples` of the held-out samples stand still or the model without it
    has no error there; (True, None) for an effect without such samples."""
    st = prob.settings
    if cand.still is None or st.still_share <= 0:
        return True, None
    where = np.asarray(cand.still(), dtype=bool)[: len(prob.val_mask)]
    mask = prob.val_mask & where
    n, n_val = int(mask.sum()), int(prob.val_mask.sum())
    out: dict[str, float] = {"samples": n, "share_of_held_out": n / max(n_val, 1), "still_share": st.still_share}
    s0 = sum(v for v, _ in prob.channel_ssr(pred0, mask).values()) if n else 0.0
    if n < st.still_min_samples * n_val or s0 <= 0:
        return True, out
    s1 = sum(v for v, _ in prob.channel_ssr(tpred, mask).values())
    out.update(before=s0 / n, after=s1 / n, taken=1.0 - s1 / s0)
    return bool(1.0 - s1 / s0 >= st.still_share), out


def phase_fault(prob: Problem, pred0: dict, tpred: dict, cand: Candidate) -> tuple[float, float | None]:
    """For a fault of one reading that trades with the loop's phase (`PHASE_FAULTS`), from the
    channels' held-out squares without it (`pred0`) and with it (`tpred`, noise-weighted):

    * how much the other readings' mean square rises, in units of their noise variance (summed
      over the other channels). A true delay of one reading reaches the others only through the
      loop (the controller acts on the delayed reading), and fitted there it leaves them as they
      were or fits them better (a refit's base parameters move them by a sliver of their noise);
      a delay that fits its own reading while the others get systematically worse stands in for
      the phase of something else — a valve's lag, a ripple, the base's form;
    * where its own reading was the model's worst (its mean square no less than any other's
      without it): its mean square with the fault against the worst of the others' without it,
      else None. A true delay of a moving reading is that reading's whole misfit, a time shift,
      which makes it the worst one; fitted, it takes the reading far below where the model stands
      on the others, whose rise is then the base's own form that parameters bent around the delay
      had hidden (a foreign rig's lines). A delay standing in for another phase leaves its reading
      about as far off as the others, or further: what was not a time shift remains. (Against the
      others as they were: their rise earns nothing.)

    (0, None) for other candidates."""
    if cand.effect not in PHASE_FAULTS or not cand.own_reading or cand.channel not in prob.channels:
        return 0.0, None
    s0 = prob.channel_ssr(pred0, prob.val_mask)
    s1 = prob.channel_ssr(tpred, prob.val_mask)
    others = [c for c in prob.channels if c != cand.channel]
    n = sum(s0[c][1] for c in others)
    worse = sum(s1[c][0] - s0[c][0] for c in others) / n if n > 0 else 0.0
    levels = [s0[c][0] / s0[c][1] for c in others if s0[c][1] > 0]
    (own0, n_own), own1 = s0[cand.channel], s1[cand.channel][0]
    if n_own == 0 or not levels or max(levels) <= 0 or own0 / n_own < max(levels):
        return worse, None
    return worse, own1 / n_own / max(levels)


def _against(v: Verdict, st: SearchSettings) -> dict[str, Any]:
    """For a close verdict's trace entry: the other side of the decision (the model without the
    effect, which its numbers are relative to) and the thresholds they were held against."""
    if not v.close:
        return {}
    return {"other": "the model without it", "min_gain": st.min_gain, "min_share": st.min_share,
            "close_margin": st.close_margin}


def _near(st: SearchSettings, dcost: float, acost: float, share: float) -> tuple[bool, ...]:
    """Per rule of `RULES`: does its graded number lie within close_margin of its threshold?"""
    m = st.close_margin
    return (False, abs(dcost + st.min_gain) < m * st.min_gain, False, abs(acost + st.min_gain) < m * st.min_gain,
            abs(share - st.min_share) < m * st.min_share, False, False, False, False)


def screen(prob: Problem, model: Model, work_pred: dict, jac: np.ndarray,
           pool: list[Candidate]) -> list[Screened]:
    """Rank candidates by how much of the fit residual their simulated signature explains beyond
    what the current free parameters absorb (a linearised score test, one simulation each).
    Returns `Screened` (candidate, explained fraction of the cost, starting value of its first
    parameter), best first, one entry per effect and channel."""
    st = prob.settings
    r0 = prob.residual(work_pred, prob.fit_mask)
    cost = float(r0 @ r0)
    trials = [model.with_candidate(c) for c in pool]
    preds = prob.predict([t.params() for t in trials])
    q = np.linalg.qr(jac)[0] if jac.size else np.zeros((len(r0), 0))
    pr = r0 - q @ (q.T @ r0)
    best: dict[tuple[str, str | None], Screened] = {}
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
            if gain > st.screen_chi2 and gain > st.screen_fraction * cost and (c.key not in best or gain / cost > best[c.key].gain):
                best[c.key] = Screened(c, gain / cost, step)
    return sorted(best.values(), key=lambda g: -g.gain)


def finding(prob: Problem, cand: Candidate, before: Model, pred0: dict, after: Model, pred1: dict,
            verdict: Verdict, rate: float) -> Finding:
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
                f"{ra[ch]:.3g} {unit} and cuts the held-out cost by {-verdict.dcost:.0%} (ΔBIC {verdict.dbic:.0f}); "
                f"switched off again, other parameters kept, the held-out cost would be "
                f"{1 / max(1 + verdict.ablation_dcost, 1e-9):.3g}x higher." + verdict.alternative)
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
