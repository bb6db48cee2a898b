"""`diagnose`: fit a record's base model by simulation error, trace what it still gets wrong to
effects that pay off on held-out data, and say whether structure remains unexplained."""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from htm.errors import RecordError
from htm.ident import features as ft
from htm.ident.family import Family, for_record
from htm.ident.fit import Problem, blocks
from htm.ident.floor import loop_floor, unexplained
from htm.ident.model import Model, get_value
from htm.ident.records import Record, clean_record, validate_record
from htm.ident.search import SYSTEMATIC, Finding, Result, search
from htm.ident.sim import DEFAULT_HORIZON_S

FORMAT = "htm-diagnosis/1"
MIN_SAMPLES = 200
# A fit that pins a metadata parameter at its bound and still misses a channel by this many noise
# floors says the record is not of the stated rig.
RIG_MISS = 3.0


class IdentificationError(RecordError):
    """The record cannot be identified (no excitation, wrong rig, too short): says why."""


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
    t_start = time.perf_counter()
    rec, warnings = clean_record(rec)
    try:
        warnings += validate_record(rec, min_samples=MIN_SAMPLES)
    except RecordError as e:
        raise IdentificationError(f"cannot identify: {e}") from None
    rate = float(rec.meta.get("sample_rate_hz") or 1.0 / float(np.median(np.diff(rec.columns["t"]))))
    channels = ft.measured_channels(rec.columns)
    # A declared sensor noise (datasheet) is the floor; else it is estimated from the record.
    sigma = {c: ft.declared_noise(rec.meta, c) or ft.noise_floor(rec.columns[c], ft.declared_resolution(rec.meta, c))
             for c in channels}
    _check_excitation(rec, sigma)
    scales = {c: max(sigma[c] * 10, 1e-6 * float(np.nanmax(np.abs(rec.columns[c])) or 1.0)) for c in channels}
    n = len(rec.columns["t"])
    family = for_record(rec, channels, horizon_s)
    # a family whose simulation is cheap fits the whole record (a chirp's high end comes last)
    n_work = n if getattr(family, "whole_record", False) else min(n, int(round(work_s * rate)))
    fit_mask, val_mask = blocks(n_work, n, rate)
    prob = Problem(rec, family.simulate, channels, sigma, n_work, fit_mask, val_mask, dict(family.opts))
    log: Callable[..., None] = (lambda *a: print(f"[{time.perf_counter() - t_start:6.1f}s {prob.simulations:4d} sims]", *a)) if verbose else (lambda *a: None)

    nominal = family.nominal
    for f in family.base_frees:
        if f.log and get_value(nominal, f.key) <= 0:
            raise IdentificationError(f"cannot identify: nominal {f.key} is {get_value(nominal, f.key)}; need > 0")
    base = Model(nominal, list(family.base_frees), np.zeros(0))
    base = base.at(base.start())
    pool = family.candidates(scales, rate)
    quantum = {c: ft.declared_resolution(rec.meta, c) or 0.0 for c in channels}

    res = search(prob, base, nominal, pool, rate, max_findings=max_findings, max_refits=max_refits, log=log)
    misfit = _rig_misfit(rec, prob, family, res, rate)
    fitted_on = "closed loop" if family.closed_loop else "recorded command"
    closed = family.closed_loop
    floor = {c: 0.0 for c in channels} if misfit or not closed else loop_floor(prob, res.model, res.pred, rate, quantum)
    left = unexplained(prob, res.pred, floor, rate)
    if closed and family.has_command and (misfit or left or max(floor.values()) > SYSTEMATIC):
        # The closed loop hunts on its own sensor noise (or the free-run fit is stuck): a free
        # run cannot follow the record's particular hunt, so its fit is not to be trusted. Fit
        # again by the prediction error from the recorded command (well posed however the loop
        # hunts), then judge that model by its free run as the record's contract asks.
        log("free run noise floor", {c: round(v, 2) for c, v in floor.items()}, "-> refit on the recorded command")
        cprob = prob.variant(command=True)
        cres = search(cprob, base, nominal, pool, rate, max_findings=max_findings, max_refits=max_refits, log=log)
        free = _restate_free_run(prob, cres, rate)
        cfloor = loop_floor(prob, free.model, free.pred, rate, quantum)
        why = ("the fitted closed loop hunts on its sensor noise, so no free run follows the record's own hunt"
               if max(cfloor.values()) > SYSTEMATIC else "the free-run fit of the closed loop did not reach the record")
        for f in free.findings:
            f.evidence += f" Fitted on the recorded command ({why}); the errors are of the free-run closed loop."
        good = _rig_misfit(rec, cprob, family, cres, rate) is None and not unexplained(prob, free.pred, cfloor, rate)
        log("on the recorded command", [f.effect for f in free.findings], "explained" if good else "not explained")
        prob.simulations += cprob.simulations
        if good:
            res, misfit, left, floor, fitted_on = free, None, False, cfloor, f"recorded command: {why}"
    if misfit:
        raise IdentificationError(misfit)
    ratios = prob.ratios(res.pred, rate)
    report: dict[str, Any] = {
        "format": FORMAT,
        "record": rec.name,
        "baseline": {"params": res.base.values(), "rmse": prob.rmse(res.base_pred)},
        "findings": [f.to_json() for f in res.findings],
        "final": {"params": res.model.values(), "rmse": prob.rmse(res.pred)},
        "unexplained": left,
        "predictions": "predictions.csv",
    }
    if warnings:  # samples dropped or tolerated: a reader of the report must know
        report["warnings"] = warnings
    if not closed and family.has_command:  # open loop on the recorded command, restarted every horizon
        report["horizon_s"] = family.opts.get("horizon_s", DEFAULT_HORIZON_S)
    log("done", report["final"]["rmse"], "unexplained" if left else "")
    info = {"simulations": prob.simulations, "seconds": time.perf_counter() - t_start,
            "noise_floor": sigma, "systematic_ratio": ratios, "loop_floor": floor, "fitted_on": fitted_on,
            "family": family.name}  # model.json says which simulator re-runs the model
    if out_dir is not None:
        from htm.ident.report import write_diagnosis

        write_diagnosis(Path(out_dir), rec, report, res, info)
    if stats is not None:
        stats.update(info, before=res.base_pred, after=res.pred, seconds=time.perf_counter() - t_start)
    return report


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


def _check_excitation(rec: Record, sigma: dict[str, float]) -> None:
    y = np.asarray(rec.columns["y"], dtype=float)
    cmd, unit = ("u", "V") if "u" in rec.columns or "y_ref" not in rec.columns else ("y_ref", "m")  # a machine_position record's command
    u = np.asarray(rec.columns[cmd], dtype=float) if cmd in rec.columns else np.zeros(1)
    span_y = float(np.nanmax(y) - np.nanmin(y))
    span_u = float(np.nanmax(u) - np.nanmin(u))
    stroke = float((rec.meta.get("rig") or {}).get("stroke_m") or 0.0)
    if span_y < max(50 * sigma["y"], 1e-4 * stroke):
        raise IdentificationError(
            f"cannot identify `{rec.name}`: no excitation — position y moves only {span_y:.3g} m "
            f"(noise {sigma['y']:.2g} m) and command {cmd} spans {span_u:.3g} {unit}; record a moving experiment "
            "(ramps, sines, steps)")


def _rig_misfit(rec: Record, prob: Problem, family: Family, res: Result, rate: float) -> str | None:
    """Why the record is not of its metadata's rig, or None: rig parameters pinned at their
    bounds while the residual stays far above the noise floor."""
    base = res.model
    pinned = [k for k in base.pinned(len(family.base_frees)) if k in family.rig_keys]
    ratios = prob.ratios(res.pred, rate)
    worst = max(ratios, key=ratios.get)
    if not (pinned and ratios[worst] > RIG_MISS):
        return None
    vals = base.values()
    return (f"cannot identify `{rec.name}`: the record does not match its metadata's rig — the model fit pins "
            + ", ".join(f"{k} = {vals[k]:.4g} (nominal {get_value(base.nominal, k):.4g})" for k in pinned)
            + f" at its bound and still misses {worst} by {ratios[worst]:.0f}x its noise floor, and no EFFECTS.md effect "
            "closes the gap; check the `rig` metadata (or the record holds an effect outside the table)")
