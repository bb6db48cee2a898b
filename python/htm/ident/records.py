"""Measurement records per shared DATA_FORMAT.md: a table (CSV, CSV.GZ) plus JSON metadata."""
from __future__ import annotations

import csv
import gzip
import io
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from htm.errors import RecordError
from htm.inputs import missing
from htm.recordfile import FORMAT, locate, pyarrow_modules, read_meta, read_table

REQUIRED = ("t", "y")  # and `u`, unless the machine closes its own loop (`machine_position`)
MACHINE_POSITION = "machine_position"
# a specimen or load-train record: `t`, `f` and the displacement `y` or a clip gauge's `cod`
DISPLACEMENT_INPUT = "displacement_input"
KNOWN = ("t", "u", "y", "v", "p_a", "p_b", "p_s", "f", "y_ref", "f_ref")


@dataclass
class Record:
    """Columns (SI arrays of equal length) and metadata of one record."""

    columns: dict[str, np.ndarray]
    meta: dict[str, Any] = field(default_factory=dict)
    name: str = "record"

    def __post_init__(self) -> None:
        lengths = {k: len(v) for k, v in self.columns.items()}
        if len(set(lengths.values())) > 1:
            raise RecordError(f"record `{self.name}`: columns differ in length {lengths}")
        absent = _missing_column(self.columns, self.meta)
        if absent:
            raise RecordError(f"record `{self.name}`: required column {absent} is missing{_close(absent, self.columns)}")


def _missing_column(columns: dict[str, np.ndarray], meta: dict[str, Any]) -> str | None:
    """The first required column (DATA_FORMAT.md) a record lacks, quoted, or None."""
    ctrl = meta.get("controller")
    if isinstance(ctrl, dict) and ctrl.get("type") == DISPLACEMENT_INPUT:
        for col in ("t", "f"):
            if col not in columns:
                return f"`{col}`"
        return None if ("y" in columns or "cod" in columns) else "`y` or `cod` (the displacement of a displacement_input record)"
    return next((f"`{c}`" for c in REQUIRED if c not in columns), None)


def _close(absent: str, columns: dict[str, np.ndarray]) -> str:
    """The close match present for a missing column named by `_missing_column` (its first quoted name)."""
    name = absent.split("`")[1] if absent.startswith("`") else absent
    return missing(name, columns)


def write_record(record: Record, base: str | Path, *, compress: bool = False, parquet: bool = False) -> tuple[Path, Path]:
    """Write `BASE.csv` (`.csv.gz` with `compress`, `.parquet` with `parquet`) and `BASE.json`;
    returns both paths. Refuses to overwrite."""
    base = Path(base)
    suffix = ".parquet" if parquet else ".csv.gz" if compress else ".csv"
    table = base.with_name(base.name + suffix)
    meta_path = base.with_name(base.name + ".json")
    for p in (table, meta_path):
        if p.exists():
            raise RecordError(f"{p} exists; refusing to overwrite a record")
    base.parent.mkdir(parents=True, exist_ok=True)
    cols = list(record.columns)
    if parquet:
        pa, pq = pyarrow_modules()
        pq.write_table(pa.table({c: np.asarray(record.columns[c], dtype=float) for c in cols}), table)
        return table, _write_meta(record, meta_path)
    data = np.column_stack([np.asarray(record.columns[c], dtype=float) for c in cols])
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for row in data:
        w.writerow([repr(float(x)) if np.isfinite(x) else "nan" for x in row])
    text = buf.getvalue()
    if compress:
        with gzip.open(table, "wt", newline="") as fh:
            fh.write(text)
    else:
        table.write_text(text)
    return table, _write_meta(record, meta_path)


def _write_meta(record: Record, meta_path: Path) -> Path:
    meta = {"format": FORMAT, **{k: v for k, v in record.meta.items() if k != "format"}}
    meta_path.write_text(json.dumps(meta, indent=2) + "\n")
    return meta_path


def read_record(path: str | Path, meta: str | Path | None = None) -> Record:
    """Read a record from its table path (or base name) and metadata (default: beside it)."""
    table, meta_path, name = locate(path, meta)
    md = read_meta(meta_path)
    columns = read_table(table)
    absent = _missing_column(columns, md)
    if absent:
        raise RecordError(f"table {table}: required column {absent} is missing{_close(absent, columns)} "
                          f"(columns: {', '.join(columns)}; DATA_FORMAT.md)")
    return Record(columns=columns, meta=md, name=name)


# Plausible magnitudes of each SI channel, to catch a column written in mm, bar, mm/s or kN.
_UNIT_HINTS = {
    "y": ("position", "m", "mm"),
    "y_ref": ("position reference", "m", "mm"),
    "v": ("velocity", "m/s", "mm/s"),
    "p_a": ("pressure", "Pa", "bar or MPa"),
    "p_b": ("pressure", "Pa", "bar or MPa"),
    "p_s": ("pressure", "Pa", "bar or MPa"),
}


# Channels whose samples are checked for plausibility (SI), and the largest share of a column that
# may be dropped as bad samples (more than that is a wrong unit or a broken sensor: refused).
_PHYSICAL = ("y", "y_ref", "v", "p_a", "p_b", "p_s", "f", "f_ref", "u")
MAX_BAD_FRACTION = 0.01


def clean_record(rec: Record) -> tuple[Record, list[str]]:
    """A copy of `rec` with bad samples dropped (set to NaN, a dropped sample in DATA_FORMAT.md),
    and a warning per column that had any: non-finite values, readings outside a sensor's declared
    range (`sensors.<ch>.range_*`), and isolated samples no rig can produce (a position beyond the
    stroke by more than a stroke, a pressure below vacuum or above five times the supply, a velocity
    above 20 m/s, a command beyond ten times the valve's rating). A column with more than
    `MAX_BAD_FRACTION` implausible samples is left as it is for `validate_record` to judge (a wrong
    unit, not a few bad samples)."""
    rig = rec.meta.get("rig") if isinstance(rec.meta.get("rig"), dict) else {}
    sensors = rec.meta.get("sensors") if isinstance(rec.meta.get("sensors"), dict) else {}

    def num(key: str) -> float | None:
        v = rig.get(key)
        return float(v) if isinstance(v, (int, float)) and np.isfinite(v) and v > 0 else None

    stroke, supply, umax = num("stroke_m"), num("supply_pressure_pa"), num("valve_max_command_v")
    area = max(num("area_a_m2") or 0.0, num("area_b_m2") or 0.0)
    limits: dict[str, tuple[float, float]] = {"v": (-20.0, 20.0)}
    if stroke:
        limits["y"] = limits["y_ref"] = (-stroke, 2.0 * stroke)
    if supply:
        for c in ("p_a", "p_b", "p_s"):
            limits[c] = (-1.5e5, 5.0 * supply)
        if area:
            limits["f"] = limits["f_ref"] = (-10.0 * area * supply, 10.0 * area * supply)
    if umax:
        limits["u"] = (-10.0 * umax, 10.0 * umax)
    cols = dict(rec.columns)
    warnings: list[str] = []
    for c in _PHYSICAL:
        if c not in cols:
            continue
        x = np.array(cols[c], dtype=float)
        why = []
        bad = ~np.isfinite(x) & ~np.isnan(x)
        if bad.any():
            why.append(f"{int(bad.sum())} non-finite")
        x[bad] = np.nan
        rng = (sensors.get(c) or {}).get("range_pa", (sensors.get(c) or {}).get("range_n")) if isinstance(sensors.get(c), dict) else None
        if isinstance(rng, (list, tuple)) and len(rng) == 2 and all(isinstance(r, (int, float)) for r in rng):
            out = (x < rng[0]) | (x > rng[1])
            if out.any():
                why.append(f"{int(out.sum())} outside the declared range [{rng[0]:g}, {rng[1]:g}]")
                x[out] = np.nan
        if c in limits:
            lo, hi = limits[c]
            with np.errstate(invalid="ignore"):
                out = (x < lo) | (x > hi)
            if out.any() and out.mean() <= MAX_BAD_FRACTION:
                why.append(f"{int(out.sum())} implausible (outside [{lo:.4g}, {hi:.4g}] SI)")
                x[out] = np.nan
        if why:
            warnings.append(f"column `{c}`: dropped {' and '.join(why)} samples")
            cols[c] = x
    return (Record(cols, rec.meta, rec.name) if warnings else rec), warnings


def validate_record(rec: Record, *, max_nan_run_s: float = 0.5, max_nan_fraction: float = 0.2,
                    min_samples: int = 50) -> list[str]:
    """Check a record against DATA_FORMAT.md before anything is fitted to it.

    Raises RecordError for what makes the record unusable (missing columns, non-uniform or
    non-increasing time, a sample rate that disagrees with the metadata, a channel in the wrong
    unit by ~1e3, long NaN runs, too few samples). Returns warnings for what is tolerable (isolated
    dropped samples).
    """
    name = rec.name
    cols = rec.columns
    absent = _missing_column(cols, rec.meta)
    if absent:
        raise RecordError(f"record `{name}`: required column {absent} is missing{_close(absent, cols)} (DATA_FORMAT.md)")
    if displacement_input(rec):
        pass  # the displacement drives the model: no valve command, no reference
    elif machine_position(rec):
        if "y_ref" not in cols:
            raise RecordError(f"record `{name}` declares a machine that closes its own loop (controller type "
                              f"`{MACHINE_POSITION}`) but has no position reference column `y_ref` (DATA_FORMAT.md)")
    elif "u" not in cols:
        raise RecordError(f"record `{name}`: required column `u` (the valve command) is missing{missing('u', cols)}; a record of a machine "
                          f"that closes its own loop has no `u` but must declare \"controller\": {{\"type\": \"{MACHINE_POSITION}\"}} "
                          "and hold `y_ref` (DATA_FORMAT.md)")
    t = np.asarray(cols["t"], dtype=float)
    if len(t) < min_samples:
        raise RecordError(f"record `{name}`: only {len(t)} samples; at least {min_samples} are needed to identify anything")
    if not np.all(np.isfinite(t)):
        raise RecordError(f"record `{name}`: column `t` holds NaN/inf at row {int(np.argmax(~np.isfinite(t)))}")
    dt = np.diff(t)
    if np.any(dt <= 0):
        k = int(np.argmax(dt <= 0))
        raise RecordError(f"record `{name}`: time does not increase at row {k + 1} (t = {t[k]} then {t[k + 1]} s)")
    if "cycle" in cols:  # bursts of cycles: `t` is uniform within a burst and jumps between bursts
        cyc = np.asarray(cols["cycle"], dtype=float)
        dt = dt[np.abs(np.diff(cyc)) <= 1]
        if dt.size == 0:
            raise RecordError(f"record `{name}`: no two consecutive samples within a burst of cycles")
    dt0 = float(np.median(dt))
    worst = float(np.max(np.abs(dt - dt0)))
    if worst > 0.01 * dt0:
        k = int(np.argmax(np.abs(dt - dt0)))
        raise RecordError(f"record `{name}`: sampling is not uniform: step {dt[k]:.6g} s at row {k + 1} vs median {dt0:.6g} s "
                          "(DATA_FORMAT.md requires uniform sampling; resample first)")
    rate = rec.meta.get("sample_rate_hz")
    if rate is not None:
        if not (isinstance(rate, (int, float)) and rate > 0):
            raise RecordError(f"record `{name}`: metadata sample_rate_hz = {rate!r} must be a positive number")
        if abs(1.0 / dt0 - rate) > 0.01 * rate:
            raise RecordError(f"record `{name}`: metadata says {rate} Hz but the time column is sampled at {1.0 / dt0:.6g} Hz")
    rig = rec.meta.get("rig") or {}
    stroke = rig.get("stroke_m")
    supply = rig.get("supply_pressure_pa")
    warnings: list[str] = []
    max_run = max(1, int(round(max_nan_run_s / dt0)))
    for c, values in cols.items():
        x = np.asarray(values, dtype=float)
        bad = ~np.isfinite(x)
        if bad.all():
            raise RecordError(f"record `{name}`: column `{c}` holds no finite value")
        if bad.any():
            run = _longest_run(bad)
            if run > max_run or bad.mean() > max_nan_fraction:
                raise RecordError(f"record `{name}`: column `{c}` has {int(bad.sum())} NaN samples, the longest run {run} "
                                  f"samples ({run * dt0:.3g} s); allowed: runs up to {max_nan_run_s} s and {max_nan_fraction:.0%} in all")
            warnings.append(f"column `{c}`: {int(bad.sum())} dropped samples (NaN), longest run {run}")
        if c not in _UNIT_HINTS:
            continue
        what, si, other = _UNIT_HINTS[c]
        # the bulk of the column, not one stray sample, tells its unit
        peak = float(np.nanpercentile(np.abs(x), 99.5))
        if c in ("y", "y_ref") and stroke and peak > 5 * stroke:
            raise RecordError(f"record `{name}`: {what} `{c}` reaches {peak:g}, beyond 5x the stroke {stroke} m: "
                              f"the column looks like {other}; convert it to {si}")
        if c == "v" and peak > 20.0:
            raise RecordError(f"record `{name}`: velocity `v` reaches {peak:g} m/s: the column looks like {other}; convert it to {si}")
        if c.startswith("p_") and supply and peak < 1e-3 * supply:
            raise RecordError(f"record `{name}`: pressure `{c}` peaks at {peak:g} Pa against a {supply:g} Pa supply: "
                              f"the column looks like {other}; convert it to {si}")
    return warnings


def displacement_input(rec: Record) -> bool:
    """Does the record declare a specimen or load-train record (displacement in, force out)?"""
    ctrl = rec.meta.get("controller")
    return isinstance(ctrl, dict) and ctrl.get("type") == DISPLACEMENT_INPUT


def force_controlled(rec: Record) -> bool:
    """Was the record taken under force control (`force_p`)? Its loop regulates the force; the
    position follows from the specimen the force acts on, not from the rig alone."""
    ctrl = rec.meta.get("controller")
    return isinstance(ctrl, dict) and ctrl.get("type") == "force_p"


def machine_position(rec: Record) -> bool:
    """Does the record declare a machine that closes its own displacement loop (no `u`)?"""
    ctrl = rec.meta.get("controller")
    return isinstance(ctrl, dict) and ctrl.get("type") == MACHINE_POSITION


def _longest_run(mask: np.ndarray) -> int:
    best = cur = 0
    for m in mask:
        cur = cur + 1 if m else 0
        best = max(best, cur)
    return best
