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

FORMAT = "htm-record/1"
REQUIRED = ("t", "u", "y")
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
        for col in REQUIRED:
            if col not in self.columns:
                raise RecordError(f"record `{self.name}`: required column `{col}` is missing")


def _table_path(base: Path) -> Path:
    for suffix in (".csv", ".csv.gz", ".parquet"):
        p = base.with_name(base.name + suffix)
        if p.exists():
            return p
    raise RecordError(f"no table for record {base} (looked for .csv, .csv.gz, .parquet)")


def write_record(record: Record, base: str | Path, *, compress: bool = False) -> tuple[Path, Path]:
    """Write `BASE.csv` (or `.csv.gz`) and `BASE.json`; returns both paths. Refuses to overwrite."""
    base = Path(base)
    table = base.with_name(base.name + (".csv.gz" if compress else ".csv"))
    meta_path = base.with_name(base.name + ".json")
    for p in (table, meta_path):
        if p.exists():
            raise RecordError(f"{p} exists; refusing to overwrite a record")
    base.parent.mkdir(parents=True, exist_ok=True)
    cols = list(record.columns)
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
    meta = {"format": FORMAT, **{k: v for k, v in record.meta.items() if k != "format"}}
    meta_path.write_text(json.dumps(meta, indent=2) + "\n")
    return table, meta_path


def read_record(path: str | Path, meta: str | Path | None = None) -> Record:
    """Read a record from its table path (or base name) and metadata (default: beside it)."""
    p = Path(path)
    name = p.name
    for suffix in (".csv.gz", ".csv", ".parquet", ".json"):
        if name.endswith(suffix):
            name = name[: -len(suffix)]
            break
    base = p.with_name(name)
    table = p if p.exists() and not p.name.endswith(".json") else _table_path(base)
    meta_path = Path(meta) if meta else base.with_name(name + ".json")
    if not meta_path.exists():
        raise RecordError(f"no metadata file {meta_path} for record {table}")
    try:
        md = json.loads(meta_path.read_text())
    except json.JSONDecodeError as e:
        raise RecordError(f"metadata {meta_path} is not valid JSON: {e}") from None
    if md.get("format") != FORMAT:
        raise RecordError(f"metadata {meta_path}: format is {md.get('format')!r}, expected {FORMAT!r}")
    if table.name.endswith(".parquet"):
        try:
            import pyarrow.parquet as pq
        except ImportError:
            raise RecordError("reading Parquet records needs pyarrow (pip install pyarrow)") from None
        t = pq.read_table(table)
        columns = {c: np.asarray(t.column(c).to_numpy(zero_copy_only=False), dtype=float) for c in t.column_names}
    else:
        opener = gzip.open if table.name.endswith(".gz") else open
        with opener(table, "rt", newline="") as fh:  # type: ignore[operator]
            rows = list(csv.reader(fh))
        if len(rows) < 2:
            raise RecordError(f"table {table} has no data rows")
        header = [h.strip() for h in rows[0]]
        try:
            data = np.array([[float(x) if x.strip() else np.nan for x in r] for r in rows[1:] if r], dtype=float)
        except ValueError as e:
            raise RecordError(f"table {table}: non-numeric value ({e})") from None
        if data.ndim != 2 or data.shape[1] != len(header):
            raise RecordError(f"table {table}: rows do not match the {len(header)} header columns")
        columns = {h: data[:, i] for i, h in enumerate(header)}
    return Record(columns=columns, meta=md, name=name)
