"""Identified models that travel: `model.json` (DATA_FORMAT.md), written by a diagnosis for
either model family, and `predict`, the model re-simulating another record of the same rig
(`htm predict MODEL RECORD [--meta META] [--tare S] --out DIR`)."""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from htm.core import LoopParams, Params, SpecimenParams
from htm.errors import RecordError
from htm.ident import features as ft
from htm.ident.records import Record, clean_record, displacement_input, machine_position, validate_record
from htm.ident.search import Result
from htm.inputs import missing, read_text

FORMAT = "htm-model/1"
PREDICTION_FORMAT = "htm-prediction/1"
FAMILIES = ("valve", "machine_position", "displacement_input")
# A record rests during its tare window when its command and position move (low-passed) by at
# most this many noise floors, or this share of the record's own travel.
REST_NOISE, REST_SHARE = 20.0, 0.02


class ModelError(RecordError):
    """A model.json that cannot be read or does not fit the record: says why."""


@dataclass
class Model:
    """A model read from model.json: its family, parameter set and what it was identified on."""

    family: str
    params: Any  # Params (valve) or LoopParams (machine_position)
    channels: list[str]
    meta: dict[str, Any] = field(default_factory=dict)  # the model.json content
    path: str = "model.json"


def model_json(rec: Record, res: Result, family: str) -> dict[str, Any]:
    """The model.json content of a diagnosis' final model (DATA_FORMAT.md, plus `family`, the
    channels it was fitted on and the record's specimen and controller)."""
    effects = [{"effect": f.effect, "channel": f.channel, "params": f.params} for f in res.findings]
    return model_dict(family, res.model.params(), rec, effects)


def model_dict(family: str, params: Any, rec: Record, effects: list[dict[str, Any]] = ()) -> dict[str, Any]:
    """model.json content for a parameter set (`Params` or `LoopParams`) identified on `rec`."""
    if family not in FAMILIES:
        raise ModelError(f"unknown model family {family!r}; known: {', '.join(FAMILIES)}")
    out: dict[str, Any] = {
        "format": FORMAT,
        "family": family,
        "record": rec.name,
        "sample_rate_hz": rec.meta.get("sample_rate_hz"),
        "channels": ft.measured_channels(rec.columns),
        "rig": rec.meta.get("rig") or {},
        "specimen": rec.meta.get("specimen"),
        "controller": rec.meta.get("controller"),
        "params": {k: float(v) for k, v in params.to_dict().items()},
        "effects": list(effects),
        "sensors": rec.meta.get("sensors") or {},
    }
    if family == "valve":
        knots = params.valve_map
        if knots[0]:
            out["valve_map"] = [list(knots[0]), list(knots[1])]
    return out


def write_model(path: Path, rec: Record, res: Result, family: str) -> None:
    path.write_text(json.dumps(model_json(rec, res, family), indent=2) + "\n")


def read_model(path: str | Path) -> Model:
    """Read and check a model.json; ModelError names what is wrong."""
    path = Path(path)
    text = read_text(path, "rig model (JSON)", ModelError)
    try:
        d = json.loads(text)
    except json.JSONDecodeError as e:
        raise ModelError(f"model {path} is not valid JSON: {e}") from None
    if not isinstance(d, dict):
        raise ModelError(f"model {path}: a JSON object is expected (`htm diagnose`'s model.json)")
    if d.get("format") != FORMAT:
        if "law" in d and "parameters" in d:
            raise ModelError(f"model {path} is a crack-growth model (`htm crack fit`, for `htm crack predict`), "
                             f"not an identified rig model (`htm diagnose`'s model.json)")
        if d.get("format") == "htm-record/1":
            raise ModelError(f"model {path} is a record's metadata, not an identified rig model (`htm diagnose`'s model.json)")
        what = f"has no `format` key{missing('format', d)}" if "format" not in d else f"format is {d['format']!r}"
        raise ModelError(f"model {path}: {what}, expected {FORMAT!r} (`htm diagnose`'s model.json)")
    family = d.get("family")
    if family not in FAMILIES:
        what = f"`family` is missing{missing('family', d)}" if "family" not in d else f"`family` is {family!r}"
        raise ModelError(f"model {path}: {what}; use one of {', '.join(FAMILIES)}")
    raw = d.get("params")
    if not isinstance(raw, dict) or not raw:
        raise ModelError(f"model {path}: `params` must be an object of parameter values")
    p: Any = Params("base") if family == "valve" else LoopParams() if family == "machine_position" else SpecimenParams()
    for k, v in raw.items():
        if k not in p:
            raise ModelError(f"model {path}: unknown {family} parameter `{k}`")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
            raise ModelError(f"model {path}: parameter `{k}` = {v!r} must be a finite number")
        p[k] = float(v)
    if family == "valve":
        knots = d.get("valve_map")
        try:
            p.valve_map = ([], []) if knots is None else (list(map(float, knots[0])), list(map(float, knots[1])))
        except (TypeError, ValueError, IndexError, KeyError):
            raise ModelError(f"model {path}: `valve_map` must be two lists of numbers (command V, spool V)") from None
    try:
        p.validate()
    except Exception as e:
        raise ModelError(f"model {path}: {e}") from None
    channels = d.get("channels")
    if not (isinstance(channels, list) and channels and all(c in ft.CHANNELS for c in channels)):
        raise ModelError(f"model {path}: `channels` must list the channels it was fitted on (of {', '.join(ft.CHANNELS)})")
    return Model(family, p, channels, d, str(path))


def _specimen_for(model: Model, rec: Record) -> Any:
    """The model's parameters, with the specimen the record declares where it declares a
    different one (stiffness, zero-force position) than the model's record did."""
    p = model.params.copy()
    new, old = rec.meta.get("specimen"), model.meta.get("specimen")
    if not isinstance(new, dict) or new == old:
        return p
    for key, field_ in (("stiffness_n_m", "specimen_stiffness_n_m"), ("zero_force_position_m", "specimen_zero_force_position_m")):
        v = new.get(key)
        if isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) and v != (old or {}).get(key):
            p[field_] = float(v)
    return p


def predict(model: Model, rec: Record, *, tare_s: float | None = None) -> dict[str, Any]:
    """Re-simulate `rec` with `model`: per predicted channel the readings `pred` and the RMS
    error, SI. `tare_s`: each channel's zero from the record's first `tare_s` seconds, which must
    be at rest (the model's prediction is shifted to the record's level there)."""
    from htm.ident.specimen import displacement_record

    rec, warnings = clean_record(displacement_record(rec))
    warnings += validate_record(rec)
    if (model.family == "displacement_input") != displacement_input(rec):
        what = {"displacement_input": "a specimen and load-train model (family displacement_input)",
                "machine_position": "a machine's displacement loop (family machine_position)", "valve": "a valve-level model"}
        raise ModelError(f"model {model.path} is {what[model.family]}; record `{rec.name}` "
                         + ("is a displacement_input record (displacement in, force out): predict it with a model diagnosed "
                            "from such a record" if displacement_input(rec) else
                            "is not a displacement_input record: predict it with a model of its own kind"))
    if model.family == "machine_position" and not machine_position(rec):
        raise ModelError(f"model {model.path} is a machine's displacement loop (family machine_position); record "
                         f"`{rec.name}` is a valve-level record: predict it with a model diagnosed from a valve-level record")
    if model.family == "valve" and machine_position(rec):
        raise ModelError(f"model {model.path} is a valve-level model; record `{rec.name}` is of a machine that closes its "
                         "own loop (machine_position, no `u`): predict it with a model diagnosed from such a record")
    channels = [c for c in ft.measured_channels(rec.columns) if c in model.channels]
    if not channels:
        raise ModelError(f"record `{rec.name}` measures none of the channels the model predicts ({', '.join(model.channels)})")
    p = _specimen_for(model, rec)
    if model.family == "displacement_input":
        from htm.ident.specimen import simulate as specimen_simulate

        pred = specimen_simulate([p], rec)[0]
        if not np.all(np.isfinite(pred["f"])):
            raise ModelError(f"the specimen model's force for `{rec.name}` is not finite")
    elif model.family == "machine_position":
        from htm.ident.loop import simulate

        pred = simulate([p], rec)[0]
        bad = [c for c in channels if not np.all(np.isfinite(pred[c]))]
        if bad:
            raise ModelError(f"the model's simulation of `{rec.name}` failed (non-finite {', '.join(bad)})")
    else:
        from htm.ident.sim import predict as sim_predict

        pred = sim_predict(p, rec)
    pred = {c: np.asarray(pred[c], dtype=float).copy() for c in channels}
    tare: dict[str, float] = {}
    if tare_s is not None:
        window = rest_window(rec, tare_s)
        for c in channels:
            m = np.asarray(rec.columns[c], dtype=float)[window]
            tare[c] = float(np.nanmean(m) - np.mean(pred[c][window]))
            pred[c] += tare[c]
    rmse = {}
    for c in channels:
        r = pred[c] - np.asarray(rec.columns[c], dtype=float)
        r = r[np.isfinite(r)]
        rmse[c] = float(np.sqrt(np.mean(r**2)))
    return {"record": rec, "pred": pred, "rmse": rmse, "tare": tare, "warnings": warnings}


def rest_window(rec: Record, tare_s: float) -> np.ndarray:
    """Mask of the record's first `tare_s` seconds; RecordError unless the record rests there
    (its command and position, low-passed, move by at most `REST_NOISE` noise floors or
    `REST_SHARE` of their whole travel)."""
    if not (isinstance(tare_s, (int, float)) and np.isfinite(tare_s) and tare_s > 0):
        raise RecordError(f"--tare {tare_s!r}: give the seconds at rest at the record's start (> 0)")
    t = np.asarray(rec.columns["t"], dtype=float)
    window = t - t[0] <= tare_s
    if window.sum() < 10:
        raise RecordError(f"--tare {tare_s} s holds only {int(window.sum())} samples of `{rec.name}`; at least 10 are needed")
    if tare_s > 0.5 * (t[-1] - t[0]):
        raise RecordError(f"--tare {tare_s} s is more than half of record `{rec.name}` ({t[-1] - t[0]:.3g} s)")
    rate = 1.0 / float(np.median(np.diff(t)))
    for c in ("y_ref", "y", "u"):
        if c not in rec.columns:
            continue
        x = np.asarray(rec.columns[c], dtype=float)
        noise = ft.noise_floor(x)
        s = ft.smooth(x[window], max(1, int(round(ft.SMOOTH_S * rate))))
        moved = float(np.nanmax(s) - np.nanmin(s))
        travel = float(np.nanpercentile(x, 99.5) - np.nanpercentile(x, 0.5))
        allowed = max(REST_NOISE * noise, REST_SHARE * travel)
        if moved > allowed:
            raise RecordError(f"record `{rec.name}` does not rest during its first {tare_s:g} s: `{c}` moves by {moved:.3g} "
                              f"(allowed {allowed:.3g}: {REST_NOISE:g}x its noise or {REST_SHARE:.0%} of its travel); "
                              "give a shorter --tare or none")
    return window


def write_prediction(out: Path, model: Model, result: dict[str, Any], tare_s: float | None) -> dict[str, Any]:
    """DIR/predictions.csv (`t`, `c_pred` per channel) and DIR/report.json (`rmse` per channel)."""
    rec = result["record"]
    out.mkdir(parents=True, exist_ok=True)
    cols = ["t"] + [f"{c}_pred" for c in result["pred"]]
    data = np.column_stack([np.asarray(rec.columns["t"], dtype=float)] + list(result["pred"].values()))
    np.savetxt(out / "predictions.csv", data, delimiter=",", header=",".join(cols), comments="", fmt="%.12g")
    report: dict[str, Any] = {"format": PREDICTION_FORMAT, "model": model.path, "family": model.family, "record": rec.name,
                              "rmse": result["rmse"], "tare_s": tare_s, "predictions": "predictions.csv"}
    if result["tare"]:
        report["tare"] = result["tare"]
    if result["warnings"]:
        report["warnings"] = result["warnings"]
    (out / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    return report
