"""A DATA_FORMAT.md record's files: finding the table and its metadata, reading the metadata
(checked to be a record's, not a model's or a spec's) and the table (CSV, CSV.GZ, Parquet). The one
reader under every command that takes a record (`htm diagnose`, `htm predict`, `htm crack
measure`, ...); what a record means is its readers' business (`htm.ident.records`,
`htm.fatigue.measure`)."""
from __future__ import annotations

import csv
import gzip
import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from htm.errors import RecordError
from htm.inputs import decode, missing, read_text

FORMAT = "htm-record/1"


def table_path(base: Path) -> Path:
    for suffix in (".csv", ".csv.gz", ".parquet"):
        p = base.with_name(base.name + suffix)
        if p.exists():
            return p
    raise RecordError(f"no table for record {base} (looked for .csv, .csv.gz, .parquet)")


def read_table(table: Path) -> dict[str, np.ndarray]:
    """The columns (SI arrays) of a record table: CSV, CSV.GZ or Parquet; every error names the
    file, the line and the column."""
    if not table.name.endswith(".parquet"):
        return _read_csv_table(table)
    _, pq = pyarrow_modules()
    try:
        t = pq.read_table(table)
    except Exception as e:  # pyarrow raises several types for a damaged file
        raise RecordError(f"table {table} is not a readable Parquet file: {e}") from None
    try:
        columns = {c: np.asarray(t.column(c).to_numpy(zero_copy_only=False), dtype=float) for c in t.column_names}
    except (TypeError, ValueError) as e:
        raise RecordError(f"table {table}: a column is not numeric ({e})") from None
    if not columns or not len(next(iter(columns.values()))):
        raise RecordError(f"table {table} has no data rows")
    for c, x in columns.items():
        bad = np.isinf(x)
        if bad.any():
            raise RecordError(f"table {table}: row {int(np.argmax(bad))}: column `{c}` = {x[bad][0]} is not a finite number")
    return columns


def locate(path: str | Path, meta: str | Path | None = None) -> tuple[Path, Path, str]:
    """A record's table, its metadata file and its name, from the table's path or the base name
    (the metadata defaults to the JSON beside the table)."""
    p = Path(path)
    name = p.name
    for suffix in (".csv.gz", ".csv", ".parquet", ".json"):
        if name.endswith(suffix):
            name = name[: -len(suffix)]
            break
    base = p.with_name(name)
    table = p if p.exists() and not p.name.endswith(".json") else table_path(base)
    meta_path = Path(meta) if meta else base.with_name(name + ".json")
    if not meta_path.exists():
        raise RecordError(f"no metadata file {meta_path} for record {table} (give it with --meta)")
    return table, meta_path, name


def read_meta(meta_path: Path) -> dict[str, Any]:
    """A record's metadata JSON, checked to be a DATA_FORMAT.md record's (not a model or a spec)."""
    text = read_text(meta_path, "record metadata (JSON)", RecordError)
    try:
        md = json.loads(text)
    except json.JSONDecodeError as e:
        raise RecordError(f"metadata {meta_path} is not valid JSON: {e}") from None
    if not isinstance(md, dict):
        raise RecordError(f"metadata {meta_path}: a JSON object is expected, found {type(md).__name__}")
    if md.get("format") != FORMAT:
        kind = _kind_of(md)
        if "format" not in md:
            what = f"has no `format` key{missing('format', md)}"
        else:
            what = f"format is {md.get('format')!r}"
        raise RecordError(f"metadata {meta_path}: {what}, expected {FORMAT!r}" + (f"; this looks like {kind}" if kind else ""))
    rate = md.get("sample_rate_hz")
    if isinstance(rate, float) and not np.isfinite(rate):
        raise RecordError(f"metadata {meta_path}: sample_rate_hz = {rate} is not a finite number")
    return md


def _kind_of(d: dict[str, Any]) -> str | None:
    """What a JSON file handed in as a record's metadata is instead (for the error)."""
    if "law" in d and "parameters" in d:
        return "a crack-growth model (`htm crack fit`'s model.json)"
    if "family" in d and "params" in d:
        return "an identified rig model (`htm diagnose`'s model.json)"
    if "findings" in d:
        return "a diagnosis report (`htm diagnose`'s report.json)"
    return None


def _read_csv_table(table: Path) -> dict[str, np.ndarray]:
    """A CSV (or CSV.GZ) record table: header of column names, then numbers (empty or `nan` is a
    dropped sample); errors name the file, the line and the column."""
    try:
        raw = table.read_bytes()
        if table.name.endswith(".gz"):
            raw = gzip.decompress(raw)
    except (OSError, EOFError, gzip.BadGzipFile) as e:
        raise RecordError(f"table {table} cannot be read ({getattr(e, 'strerror', None) or e})") from None
    rows = list(csv.reader(io.StringIO(decode(raw, table, "record table (CSV)", RecordError), newline="")))
    if not rows:
        raise RecordError(f"table {table} is empty (DATA_FORMAT.md: a header of column names, then a row per sample)")
    header = [h.strip() for h in rows[0]]
    if len(rows) < 2 or not any(rows[1:]):
        raise RecordError(f"table {table} has a header ({', '.join(header)}) but no data rows")
    fast = _numbers(rows[1:], header)
    if fast is not None:
        return fast
    # The slow path: row by row, to name the line and column of what is wrong (or empty).
    data = np.empty((len(rows) - 1, len(header)))
    n = 0
    for line, r in enumerate(rows[1:], start=2):
        if not r:
            continue
        if len(r) != len(header):
            raise RecordError(f"table {table}: line {line} has {len(r)} fields, the header {len(header)}")
        for j, x in enumerate(r):
            try:
                v = float(x) if x.strip() else np.nan
            except ValueError:
                raise RecordError(f"table {table}: line {line}: column `{header[j]}` = {x.strip()!r} is not a number") from None
            if np.isnan(v) and header[j] == "t":
                raise RecordError(f"table {table}: line {line}: column `t` = {x.strip()!r}: every sample needs its time "
                                  "(only a channel's sample can be dropped)")
            if np.isinf(v):
                raise RecordError(f"table {table}: line {line}: column `{header[j]}` = {x.strip()} is not a finite number "
                                  "(a dropped sample is written empty or nan)")
            data[n, j] = v
        n += 1
    return {h: np.ascontiguousarray(data[:n, i]) for i, h in enumerate(header)}


def _numbers(body: list[list[str]], header: list[str]) -> dict[str, np.ndarray] | None:
    """The columns of a table whose every field is a finite number or `nan` (not in `t`), parsed
    at once (a 60 s record at 500 Hz in a tenth of the row-by-row time); None when anything needs
    the row-by-row reading (an empty field, a short row, a bad value: it names the line)."""
    body = [r for r in body if r]
    if any(len(r) != len(header) for r in body):
        return None
    try:
        data = np.array(body, dtype=float)
    except ValueError:
        return None
    if data.ndim != 2 or np.isinf(data).any() or ("t" in header and np.isnan(data[:, header.index("t")]).any()):
        return None
    return {h: np.ascontiguousarray(data[:, i]) for i, h in enumerate(header)}


def pyarrow_modules():
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise RecordError("Parquet records need pyarrow (pip install pyarrow)") from None
    return pa, pq

