"""`diagnose`: fit a record's base model by simulation error, trace what it still gets wrong to
effects that pay off on held-out data, and say whether structure remains unexplained."""
from __future__ import annotations

import dataclasses
import functools
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from htm.errors import RecordError
from htm.ident import features as ft
from htm.ident.family import for_record
from htm.ident.fit import Problem, blocks, simulations_so_far, spread_blocks
from htm.ident.floor import form_ratios, own_floor, unexplained
from htm.ident.model import Model, get_value
from htm.ident.records import Record, clean_record, force_controlled, validate_record
from htm.ident.search import Finding, Result, probe, search
from htm.ident.settings import DEFAULT, SearchSettings
from htm.ident.sim import DEFAULT_HORIZON_S
from htm.ident.specimen import displacement_record
from htm.ident.trace import Progress, Stages, Trace

FORMAT = "htm-diagnosis/1"
# The knobs live in `settings.SearchSettings` (unit and reason there); these names are its defaults.
MIN_SAMPLES = DEFAULT.min_samples
CANNOT_FOLLOW = DEFAULT.cannot_follow


class IdentificationError(RecordError):
    """The record cannot be identified (no excitation, wrong rig, too short): says why."""


def _one_blas_thread(f: Callable[..., Any]) -> Callable[..., Any]:
    """Run `f` with the linear algebra on one BLAS thread: a multi-threaded BLAS splits the sums
    of its products (the normal equations of every fit step, the QR of the screen) over its
    threads, so their rounding — and with it a close decision of the search — would depend on the
    machine's core count and load. The simulations, where the time goes, stay parallel (the core
    runs each one whole on one thread, a batch over all cores)."""
    @functools.wraps(f)
    def pinned(*args: Any, **kw: Any) -> Any:
        from threadpoolctl import threadpool_limits

        with threadpool_limits(limits=1, user_api="blas"):
            return f(*args, **kw)

    return pinned


@_one_blas_thread
def diagnose(rec: Record, *, out_dir: str | Path | None = None, max_findings: int | None = None,
             max_refits: int | None = None, work_s: float | None = None, horizon_s: float | None = None,
             verbose: bool = False, stats: dict[str, Any] | None = None, settings: SearchSettings | None = None,
             progress: Progress | None = None) -> dict[str, Any]:
    """Diagnose a record: base-model fit, residual diagnostics, effects kept only if they pay off
    on held-out segments. Returns the report.json content (DATA_FORMAT.md); with `out_dir` also
    writes report.json, predictions.csv, report.md and plots there. `stats`, if given, receives
    `simulations`, `seconds`, per-channel `noise_floor` and `systematic_ratio` and the whole-record
    predictions `before`/`after` (SI arrays per channel) and per stage the wall time
    (`stage_seconds`), the process's CPU time (`stage_cpu_seconds`) and the simulations run
    (`stage_simulations`).

    `settings` holds every knob of the search (`settings.SearchSettings`; default `DEFAULT`);
    `max_findings`, `max_refits` and `work_s`, if given, override its fields. The report carries
    the settings used (`settings`) and the decision trace (`trace`). `progress`, if given, is
    called with one line as each stage begins.

    Fits use the first `work_s` seconds (interleaved fit/validation blocks); the rest of a longer
    record is held out too.

    Raises IdentificationError ("cannot identify ...: why") for a record that carries no
    information (too short, no excitation) or that does not belong to its metadata's rig.
    """
    t_start = time.perf_counter()
    if out_dir is not None:  # the plots' library loads while the core simulates
        from htm.report import preload

        preload()
    st = settings if settings is not None else DEFAULT
    over = {k: v for k, v in (("max_findings", max_findings), ("max_refits", max_refits), ("work_s", work_s)) if v is not None}
    if over:
        st = dataclasses.replace(st, **over)
    trace = Trace()
    stages = Stages(progress, t_start, simulations_so_far)
    rec, warnings = clean_record(displacement_record(rec))  # a clip gauge's `cod` drives a specimen like `y`
    try:
        warnings += validate_record(rec, min_samples=st.min_samples)
    except RecordError as e:
        raise IdentificationError(f"cannot identify: {e}") from None
    rate = float(rec.meta.get("sample_rate_hz") or 1.0 / float(np.median(np.diff(rec.columns["t"]))))
    channels = ft.measured_channels(rec.columns)
    # A declared sensor noise (datasheet) with its quantum is the floor; else it is estimated from the record.
    sigma = {c: ft.reading_noise(rec.meta, c, rec.columns[c]) for c in channels}
    _check_excitation(rec, sigma, st)
    with stages("prepare", f"{rec.name}: {len(rec.columns['t'])} samples at {rate:g} Hz, channels {', '.join(channels)}"):
        fitting = every = _Fitting(rec, channels, sigma, rate, horizon_s, verbose, t_start, st)
    fitted = fitting.search(trace, stages)
    bad = _not_followed(fitting.prob, fitted, st.cannot_follow)
    dropped: dict[str, float] = {}
    if bad and "y" not in bad and len(bad) == 1 and len(channels) > 2:
        # One channel the model cannot follow while the position and the others fit (a velocity
        # sampled below its motion's bandwidth, a sensor of another form): diagnose without it,
        # say so, and leave the record unexplained — refusing would throw away what does fit.
        dropped = bad
        channels = [c for c in channels if c not in bad]
        warnings.append(_refusal(rec, bad, left_out=True))
        trace.add("verdict", None, "the model cannot follow one channel (error > cannot_follow x its variation)",
                  "left it out and diagnosed again", ratio=bad, cannot_follow=st.cannot_follow)
        with stages("prepare", f"again without {', '.join(bad)}"):
            fitting = _Fitting(rec, channels, {c: sigma[c] for c in channels}, rate, horizon_s, verbose, t_start, st)
        fitted = fitting.search(trace, stages)
        bad = _not_followed(fitting.prob, fitted, st.cannot_follow)
    unfollowed: dict[str, float] = {}
    if bad:
        pinned_rig = [k for k in fitted.model.pinned(len(fitting.family.base_frees)) if k in fitting.family.rig_keys]
        if "y" in bad or pinned_rig:
            # The motion itself missed, or a stated rig parameter at its bound: another rig.
            raise IdentificationError(_refusal(rec, bad))
        # The position followed with the stated rig inside its bounds, a channel not: structure
        # outside the model over part of the record (an end cushion's pressure, a force over part
        # of the stroke) or a sensor of another form. The channel is kept and the record reported,
        # unexplained — refusing would throw away what does fit.
        unfollowed = bad
        warnings.append(_refusal(rec, bad, kept=True))
        trace.add("verdict", None, "the model cannot follow a channel (error > cannot_follow x its variation) while it "
                  "follows the position with the stated rig inside its bounds", "kept it: the record is unexplained",
                  ratio=bad, cannot_follow=st.cannot_follow)
    prob, free, family, nominal, log, closed = (fitting.prob, fitting.free, fitting.family, fitting.nominal, fitting.log,
                                               fitting.closed)
    quantum = {c: ft.declared_resolution(rec.meta, c) or 0.0 for c in channels}
    # Structure left, judged where the fit was made: beyond the model's form, above its own floor.
    with stages("floor", "the model's own floor and form"):
        floor = own_floor(prob, fitted.model, fitted.pred, rate, quantum)
        form = form_ratios(prob, fitted.pred, rate)
    left = unexplained(form, floor, settings=st)
    gross = unexplained(form, floor, st.gross, settings=st)
    trace.round += 1
    trace.add("verdict", None, "beyond form > unexplained and > margin x own floor", "structure left on " + ", ".join(left)
              if left else "no structure left", close=any(abs(form[c] - max(st.unexplained, st.margin * floor[c]))
                                                         < st.close_margin * max(st.unexplained, st.margin * floor[c]) for c in form),
              beyond_form=form, own_floor=floor, unexplained=st.unexplained, margin=st.margin)
    log("own floor", {c: round(v, 2) for c, v in floor.items()}, "beyond form", {c: round(v, 2) for c, v in form.items()},
        "structure left on " + ", ".join(left) if left else "")
    pinned = [k for k in fitted.model.pinned(len(family.base_frees)) if k in family.rig_keys]
    if "y" in gross and pinned:
        vals = fitted.model.values()
        pins = ", ".join(f"{k} = {vals[k]:.4g} (nominal {get_value(nominal, k):.4g})" for k in pinned)
        misses = ", ".join(f"{c} by {form[c]:.0f}x its noise floor" for c in gross)
        if force_controlled(rec):
            # Under force control the loop holds the force and the specimen sets the motion: a
            # position missed so is a specimen's form the model lacks (a closure the search did
            # not find), not another rig. Reported, unexplained, the pins named.
            warnings.append(f"the fit pins {pins} at its bound and still misses {misses}: under force control the "
                            "specimen sets the motion, so the record is reported unexplained, not refused (a specimen's "
                            "form outside the model, or check the `rig` and `specimen` metadata)")
            trace.add("verdict", None, "a position missed grossly with a rig parameter at its bound is another rig only "
                      "where the rig sets the motion", "force control: the specimen sets it; the record is unexplained",
                      pinned=pinned, beyond_form={c: form[c] for c in gross})
            unfollowed = unfollowed or {c: form[c] for c in gross}
        else:
            # The declared rig sets the motion: a position missed grossly with a rig parameter at
            # its bound is another rig. Pressures missed so are the details real rigs add (lines,
            # seals, the valve's form): that is reported, unexplained, not refused.
            raise IdentificationError(
                f"cannot identify `{rec.name}`: the record does not match its metadata's rig — the fit pins {pins}"
                f" at its bound and still misses {misses}; check the `rig` metadata (geometry, valve rating, mass)")
    outside = None
    if family.has_probes:
        # Structure left: is it of a kind outside the vocabulary (a force over part of the stroke,
        # a pump's ripple...)? Only a probe that pays off well makes it unexplained; what no probe
        # reproduces either is the model's form, not an effect it lacks. A tone is looked for
        # whatever the broadband verdict: it shows in its own band only.
        residual = {c: np.asarray(fitted.pred[c]) - prob.meas[c] for c in channels}
        probes = [c for c in family.probes(residual, rate) if left or c.tone_hz]
        if probes:
            with stages("probes", f"{len(probes)} probes for structure outside the vocabulary"):
                outside = probe(prob, fitted, probes, rate, log=log, trace=trace)
        if left or outside is not None:
            trace.add("verdict", outside.cand.label if outside is not None else None,
                      "structure left is unexplained only where a probe outside the vocabulary reproduces it",
                      "unexplained on " + ", ".join(left or [outside.focus]) if outside is not None
                      else "no probe reproduces it: the model's form, explained")
        left = (left or [outside.focus]) if outside is not None else []
    with stages("report", "restating and writing"):
        res = _restate_free_run(free, fitted, rate) if free is not prob else fitted
        if dropped:  # the channel left out is still predicted and reported (DATA_FORMAT.md: every measured channel)
            both = every.free.predict([res.base.params(), res.model.params()], whole=True)
            for c in dropped:
                res.base_pred[c], res.pred[c] = both[0][c], both[1][c]
    fitted_on = "recorded command" if family.has_command else "free run"
    simulations = sum(f.prob.simulations + (f.free.simulations if f.free is not f.prob else 0) for f in {every, fitting})
    ratios = every.free.ratios(res.pred, rate)
    report: dict[str, Any] = {
        "format": FORMAT,
        "record": rec.name,
        "baseline": {"params": res.base.values(), "rmse": every.prob.rmse(res.base_pred)},
        "findings": [f.to_json() for f in res.findings],
        "final": {"params": res.model.values(), "rmse": every.prob.rmse(res.pred)},
        "unexplained": bool(left) or bool(dropped) or bool(unfollowed),
        "predictions": "predictions.csv",
        "settings": st.to_json(),
        "trace": trace.to_json(),
    }
    if warnings:  # samples dropped or tolerated: a reader of the report must know
        report["warnings"] = warnings
    if not closed and family.has_command:  # open loop on the recorded command, restarted every horizon
        report["horizon_s"] = fitting.horizon
    log("done", report["final"]["rmse"], "unexplained" if left else "")
    info = {"simulations": simulations, "seconds": time.perf_counter() - t_start, "noise_floor": sigma,
            "systematic_ratio": ratios, "own_floor": floor, "form_ratio": form,
            "unexplained_channels": sorted(set(left) | set(dropped) | set(unfollowed)),
            "outside": outside, "fitted_on": fitted_on, "trace": trace,
            "family": family.name}  # model.json says which simulator re-runs the model
    if out_dir is not None:
        from htm.ident.report import write_diagnosis

        with stages("report", f"writing {out_dir}"):
            write_diagnosis(Path(out_dir), rec, report, res, info)
    if stats is not None:
        stats.update(info, before=res.base_pred, after=res.pred, seconds=time.perf_counter() - t_start,
                     stage_seconds=stages.rounded(), stage_cpu_seconds=stages.cpu_rounded(),
                     stage_simulations=dict(stages.simulations))
    return report


class _Fitting:
    """One record's fitting problem on a set of its channels: the model family, the fit and
    validation samples (and the free-run variant a closed loop is reported by), the base model
    and the candidate effects."""

    def __init__(self, rec: Record, channels: list[str], sigma: dict[str, float], rate: float,
                 horizon_s: float | None, verbose: bool, t_start: float, settings: SearchSettings) -> None:
        self.rate = rate
        self.settings = st = settings
        work_s = st.work_s
        n = len(rec.columns["t"])
        family = self.family = for_record(rec, channels, horizon_s, st)
        self.closed = closed = family.closed_loop
        if family.has_command:
            # Fitted by the prediction error from the recorded command (open loop, restarted from the
            # measurement every horizon): well posed whatever a closed loop does with its sensor
            # noise (a free run cannot follow the record's own hunt around a hold), and the restarts
            # make horizons independent, so a fit simulates only its horizons, spread over the record.
            self.horizon = float(family.opts.get("horizon_s", DEFAULT_HORIZON_S))
            fit_mask, val_mask = spread_blocks(n, rate, self.horizon, work_s)
            prob = Problem(rec, family.simulate, channels, sigma, n, fit_mask, val_mask, {**family.opts, "command": closed},
                           sparse=True, settings=st)
        else:
            # a family whose simulation is cheap fits the whole record (a chirp's high end comes last)
            n_work = n if family.whole_record else min(n, int(round(work_s * rate)))
            fit_mask, val_mask = blocks(n_work, n, rate, st.block_s)
            prob = Problem(rec, family.simulate, channels, sigma, n_work, fit_mask, val_mask, dict(family.opts), settings=st)
        self.prob = prob
        # A closed loop's predictions are free runs from the reference (DATA_FORMAT.md).
        self.free = free = prob.variant(command=False) if closed and family.has_command else prob
        self.log: Callable[..., None] = (
            (lambda *a: print(f"[{time.perf_counter() - t_start:6.1f}s {prob.simulations + free.simulations:4d} sims]", *a))
            if verbose else (lambda *a: None))
        nominal = self.nominal = family.nominal
        for f in family.base_frees:
            if f.log and get_value(nominal, f.key) <= 0:
                raise IdentificationError(f"cannot identify: nominal {f.key} is {get_value(nominal, f.key)}; need > 0")
        base = Model(nominal, list(family.base_frees), np.zeros(0))
        self.base = base.at(family.start(base))
        scales = {c: max(sigma[c] * st.screen_scale_noise, 1e-6 * float(np.nanmax(np.abs(rec.columns[c])) or 1.0)) for c in channels}
        self.pool = family.candidates(scales, rate)

    def search(self, trace: Trace, stages: Stages) -> Result:
        return search(self.prob, self.base, self.nominal, self.pool, self.rate, first=self.family.first_stage,
                      stated=frozenset(self.family.rig_keys), log=self.log, trace=trace, stages=stages)


def _restate_free_run(prob: Problem, res: Result, rate: float) -> Result:
    """Findings made on the recorded command, restated by free runs of the closed loop (the
    record's contract): the baseline's prediction, the findings with the errors just before and
    after each (the model before the next finding, the final model after the last) and the final
    prediction."""
    from htm.ident.search import finding

    chain = [res.base] + [f.before for f in res.findings[1:]] + [res.model]
    preds = prob.predict([m.params() for m in chain], whole=True)
    out: list[Finding] = []
    for i, f in enumerate(res.findings):
        g = finding(prob, f.cand, chain[i], preds[i], chain[i + 1], preds[i + 1], f.verdict, rate)
        g.params = f.params
        out.append(g)
    return Result(res.base, preds[0], res.model, preds[-1], out)


def _check_excitation(rec: Record, sigma: dict[str, float], st: SearchSettings) -> None:
    y = np.asarray(rec.columns["y"], dtype=float)
    cmd, unit = ("u", "V") if "u" in rec.columns or "y_ref" not in rec.columns else ("y_ref", "m")  # a machine_position record's command
    u = np.asarray(rec.columns[cmd], dtype=float) if cmd in rec.columns else np.zeros(1)
    span_y = float(np.nanmax(y) - np.nanmin(y))
    span_u = float(np.nanmax(u) - np.nanmin(u))
    stroke = float((rec.meta.get("rig") or {}).get("stroke_m") or 0.0)
    if span_y < max(st.excitation_noise * sigma["y"], st.excitation_stroke * stroke):
        raise IdentificationError(
            f"cannot identify `{rec.name}`: no excitation — position y moves only {span_y:.3g} m "
            f"(noise {sigma['y']:.2g} m)" + (f" and command {cmd} spans {span_u:.3g} {unit}" if cmd in rec.columns else "") + "; record a moving experiment "
            "(ramps, sines, steps)")


def _not_followed(prob: Problem, res: Result, cannot_follow: float = CANNOT_FOLLOW) -> dict[str, float]:
    """The channels the fitted model does not even follow, with its error as a share of their
    variation: a channel that moves well above its noise and whose error is over CANNOT_FOLLOW
    of that — a geometry, polarity or channel that does not belong to this record."""
    bad = {}
    for c in prob.channels:
        m = prob.meas[c][prob.val_mask]
        spread = float(np.nanstd(m))
        if spread < 10 * prob.sigma[c]:
            continue
        err = float(np.sqrt(np.nanmean((np.asarray(res.pred[c])[prob.val_mask] - m) ** 2)))
        if not np.isfinite(err) or err > cannot_follow * spread:
            bad[c] = err / spread if np.isfinite(err) else float("inf")
    return bad


def _refusal(rec: Record, bad: dict[str, float], left_out: bool = False, kept: bool = False) -> str:
    what = ", ".join(f"{c} (its error is {r:.0%} of the signal's variation)" for c, r in bad.items())
    if kept:
        return (f"the model of the declared rig cannot follow {what} even with every base parameter and effect "
                "fitted, while it follows the position: kept, and the record reported unexplained (structure the "
                "model lacks over part of the record, or check that channel's units, sign and bandwidth)")
    if left_out:
        return (f"the model of the declared rig cannot follow {what} even with every base parameter and effect "
                "fitted: left out of the fit, and the record reported unexplained; check that channel's units, "
                "sign and bandwidth against the sample rate")
    return (f"cannot identify `{rec.name}`: the model of the declared rig cannot follow {what}"
            " even with every base parameter and effect fitted; check the declared geometry (area_a_m2, area_b_m2, "
            "stroke_m, orientation), the valve polarity and the channels' units and signs")
