"""Crack size and closure from a raw record (`htm crack measure`): a load–opening record (`cod`,
`f`, `cycle`; bursts of cycles) or a potential-drop record (`dcpd_v`, `cycle`) reduced to one
a–N row per burst or interval, by the Rust core (`crack_measure.rs`, the one copy of the
expressions). The record's metadata (DATA_FORMAT.md, `specimen`) names the method's constants.
"""
from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from htm import core, recordfile
from htm.errors import InputError, ParameterError, RecordError
from htm.recordfile import locate, read_meta

METHODS = ("compliance", "potential_drop")

# extra columns of a_n.csv after `cycles`, `a_m`, `opening_force_n` (core names → file names)
_EXTRA = (("a_std_m", "a_std_m"), ("fmin_n", "fmin_n"), ("fmax_n", "fmax_n"),
          ("opening_force_1pct_n", "opening_force_1pct_n"), ("opening_force_4pct_n", "opening_force_4pct_n"),
          ("opening_force_segments_n", "opening_force_x2_segments_n"), ("dk_pa_sqrt_m", "delta_k_pa_sqrt_m"),
          ("dk_eff_pa_sqrt_m", "delta_k_eff_pa_sqrt_m"), ("opening_resolved", "opening_resolved"), ("offset_noise", "offset_noise"),
          ("closure_pooled", "closure_pooled"))
# integer columns, and the closure columns a potential-drop row leaves empty
_INT = {"opening_resolved", "closure_pooled"}
_CLOSURE = {"opening_resolved", "offset_noise", "closure_pooled"}


@dataclass(frozen=True)
class Measurement:
    """A reduced record: the expression used, the method's constants and one row per interval."""

    method: str
    expression: str
    constants: dict[str, Any]
    columns: dict[str, np.ndarray]
    resolution_m: float

    def __len__(self) -> int:
        return len(self.columns["a_m"])

    def opening_not_resolved(self) -> np.ndarray | None:
        """Rows whose opening force the gauge's noise left undetermined (compliance only; None else)."""
        return self.columns["opening_resolved"] == 0 if self.method == "compliance" else None


def read_table(path: str | Path, meta: str | Path | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The columns (SI arrays) and metadata of a record (`htm.recordfile`, the one reader);
    RecordError names what is wrong."""
    table, meta_path, _ = locate(path, meta)
    md = read_meta(meta_path)
    return recordfile.read_table(table), md


def _num(spec: dict[str, Any], key: str, where: str, required: bool = True) -> float | None:
    v = spec.get(key)
    if v is None:
        if required:
            raise RecordError(f"{where}: `specimen.{key}` is required for this measurement")
        return None
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise RecordError(f"{where}: `specimen.{key}` = {v!r} is not a number") from None
    if not math.isfinite(x):
        raise RecordError(f"{where}: `specimen.{key}` = {v!r} is not finite")
    return x


def _constants(spec: dict[str, Any], method: str, geometry: str, where: str) -> dict[str, Any]:
    """The method's constants from the specimen entry, as `core.crack_reduce` keywords."""
    if method == "compliance":
        e = _num(spec, "effective_modulus_pa", where, required=False)
        nu = _num(spec, "poisson_ratio", where, required=False)
        nu = 0.3 if nu is None else nu
        if e is None:
            e = _num(spec, "youngs_modulus_pa", where)
            state = spec.get("compliance_modulus", "plane_stress")
            if state == "plane_strain":
                e = e / (1 - nu * nu)
            elif state != "plane_stress":
                raise RecordError(f"{where}: `specimen.compliance_modulus` = {state!r}: use plane_stress (E647) or plane_strain")
        kw: dict[str, Any] = {"modulus_pa": e, "poisson_ratio": nu}
        if geometry == "ct":
            x = _num(spec, "cod_x_over_w", where, required=False)
            if x is None:
                try:
                    x = core.ct_gauge_x_over_w(str(spec.get("cod_at", "crack_mouth")))
                except InputError as err:
                    raise RecordError(f"{where}: {err}") from None
            kw["cod_x_over_w"] = x
        else:
            kw["cod_y_m"] = _num(spec, "cod_y_m", where)
        return kw
    kw = {"dcpd_v_ref": _num(spec, "dcpd_v_ref", where, required=False)}
    cal = spec.get("dcpd_calibration")
    if cal is not None:
        try:
            kw["calibration"] = ([float(x) for x in cal["v_over_vref"]], [float(x) for x in cal["a_m"]])
        except (TypeError, KeyError, ValueError):
            raise RecordError(f"{where}: `specimen.dcpd_calibration` must be {{\"v_over_vref\": [...], \"a_m\": [...]}}") from None
    else:
        kw["dcpd_probe_y_m"] = _num(spec, "dcpd_probe_y_m", where)
        kw["dcpd_a_ref_m"] = _num(spec, "dcpd_a_ref_m", where)
    return kw


def measure(columns: dict[str, np.ndarray], meta: dict[str, Any], *, method: str = "auto", cycles_per_interval: int | None = None,
            name: str = "record") -> Measurement:
    """Reduce a record's columns to crack sizes and opening forces per burst or interval.

    Parameters
    ----------
    columns, meta : the record (DATA_FORMAT.md): `cycle` and `cod` + `f` (compliance) or `dcpd_v`.
    method : ``auto`` (compliance when `cod` is present, else potential drop), ``compliance`` or
        ``potential_drop``.
    cycles_per_interval : cycles pooled per row; default one row per burst (a continuous record
        of more than 50 cycles: 10 cycles per row).
    """
    where = f"record `{name}`"
    spec = meta.get("specimen")
    if not isinstance(spec, dict):
        raise RecordError(f"{where}: metadata needs a `specimen` entry (geometry, width_m, thickness_m and the method's constants)")
    geometry = str(spec.get("geometry", "")).lower().replace("(", "").replace(")", "")
    if geometry not in ("ct", "mt"):
        raise RecordError(f"{where}: `specimen.geometry` = {spec.get('geometry')!r}: use ct or mt")
    w, b = _num(spec, "width_m", where), _num(spec, "thickness_m", where)
    if method == "auto":
        method = "compliance" if "cod" in columns else "potential_drop" if "dcpd_v" in columns else ""
        if not method:
            raise RecordError(f"{where}: no `cod` or `dcpd_v` column: nothing to measure the crack from")
    if method not in METHODS:
        raise RecordError(f"{where}: method {method!r}: use auto, compliance or potential_drop")
    signal_col = "cod" if method == "compliance" else "dcpd_v"
    need = ["cycle", signal_col] + (["f"] if method == "compliance" else [])
    for c in need:
        if c not in columns:
            raise RecordError(f"{where}: column `{c}` is required for {method.replace('_', ' ')} (found: {', '.join(columns)})")
    cycle = columns["cycle"]
    bad = ~np.isfinite(cycle)
    if bad.any():
        raise RecordError(f"{where}: column `cycle` has a non-finite value at row {int(np.argmax(bad)) + 2}")
    if np.any(np.diff(cycle) < 0):
        i = int(np.argmax(np.diff(cycle) < 0))
        raise RecordError(f"{where}: column `cycle` decreases at row {i + 3} ({cycle[i]:g} → {cycle[i + 1]:g})")
    if cycles_per_interval is None:
        jumps = np.count_nonzero(np.diff(cycle) > 1)
        cycles_per_interval = 10 if jumps == 0 and cycle[-1] - cycle[0] > 50 else 0
    kw = _constants(spec, method, geometry, where)
    f = columns.get("f")
    try:
        expression, cols = core.crack_reduce(geometry, w, b, method, np.ascontiguousarray(cycle, float),
                                             np.ascontiguousarray(columns[signal_col], float),
                                             None if f is None else np.ascontiguousarray(f, float),
                                             cycles_per_interval=int(cycles_per_interval), **kw)
    except (InputError, ParameterError) as e:
        raise RecordError(f"{where}: {e}") from None
    return Measurement(method, expression, {k: v for k, v in kw.items() if v is not None}, dict(cols), core.crack_resolution_m(w))


def write_a_n(m: Measurement, out: Path) -> Path:
    """`out/a_n.csv`: `cycles`, `a_m`, `opening_force_n` (the 2 % offset; empty for potential
    drop), then the other columns; and `out/measure.json` with the expression and constants."""
    out.mkdir(parents=True, exist_ok=True)
    c = m.columns
    path = out / "a_n.csv"
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        value_col = "compliance_m_per_n" if m.method == "compliance" else "dcpd_v"
        w.writerow(["cycles", "a_m", "opening_force_n", value_col, *(n for _, n in _EXTRA)])

        def fmt(x: float, k: str = "") -> str:
            if not np.isfinite(x) or (k in _CLOSURE and m.method != "compliance"):
                return ""
            return str(int(x)) if k in _INT else repr(float(x))

        for i in range(len(m)):
            w.writerow([str(int(c["cycles"][i])), fmt(c["a_m"][i]), fmt(c["opening_force_n"][i]), fmt(c["value"][i]),
                        *(fmt(c[k][i], k) for k, _ in _EXTRA)])
    a_std = c["a_std_m"]
    coarse = int(np.count_nonzero(np.isfinite(a_std) & (a_std > m.resolution_m)))
    un = m.opening_not_resolved()
    (out / "measure.json").write_text(json.dumps({
        "format": "htm-crack-measure/1", "method": m.method, "expression": m.expression, "constants": m.constants,
        "rows": len(m), "resolution_m": m.resolution_m, "rows_coarser_than_resolution": coarse,
        "opening_force": "compliance offset 2 % (E647 X2) on a closure curve fitted to each interval's loading branches; "
                         "1 % and 4 % beside it, and E647's 10 % segments (x2_segments); a closure one interval does not "
                         "show is fitted on the loading curves of the last intervals pooled (closure_pooled); the opening force "
                         "is empty (opening_resolved 0, ΔK_eff not claimed) where the noise leaves it undetermined: curves as "
                         "good as the best opening more than ±5 % of Fmax apart, or no closure shown while the offset noise "
                         "(offset_noise) exceeds 0.05" if m.method == "compliance" else None,
        "rows_opening_not_resolved": None if un is None else int(un.sum()),
    }, indent=1) + "\n")
    return path
