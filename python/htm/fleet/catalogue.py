"""The fleet tables of the store's catalogue: `fleet_params`, one row per (machine, date, record,
parameter), the value `htm diagnose` identified (its final model), SI; and `fleet_records`, the
measurement records put into the store (`htm fleet add`), one row per (machine, date, record) naming
its Parquet table under the store's root (`fleet/MACHINE/DATE/NAME.parquet`, `NAME.json` beside it:
the layout `htm fleet diagnose FOLDER` reads, so the same engine diagnoses both)."""
from __future__ import annotations

import datetime
import json
import os
import re
import tempfile
import time
from pathlib import Path
from typing import Any

from htm.errors import RecordError

TABLE_SUFFIXES = (".csv.gz", ".csv", ".parquet")


def records_in(folder: Path) -> list[tuple[str, str, Path]]:
    """(machine, date, table path) of every record laid out as FOLDER/MACHINE/DATE/NAME.csv[.gz] or
    .parquet with NAME.json beside it, in machine and date order."""
    if not folder.is_dir():
        raise RecordError(f"{folder}: no such folder (expected FOLDER/MACHINE/DATE/NAME.csv with NAME.json)")
    out = []
    for p in sorted(folder.glob("*/*/*")):
        if p.is_file() and p.name.endswith(TABLE_SUFFIXES):
            out.append((p.parent.parent.name, p.parent.name, p))
    if not out:
        raise RecordError(f"{folder}: no record found as MACHINE/DATE/NAME.csv (.csv.gz, .parquet) with NAME.json beside it")
    return out


def record_name(table: Path) -> str:
    for s in TABLE_SUFFIXES:
        if table.name.endswith(s):
            return table.name[: -len(s)]
    return table.stem


# a machine or record name is one path component of the store's shared folder
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}")
_DATE = re.compile(r"\d{4}-\d{2}-\d{2}")
FLEET_DIR = "fleet"


def check_name(what: str, value: str) -> str:
    if not _NAME.fullmatch(value):
        raise RecordError(f"{what} {value!r}: use letters, digits, `.`, `_`, `-` (starting with a letter or digit, "
                          "at most 100 characters)")
    return value


def check_date(value: str) -> str:
    try:
        ok = bool(_DATE.fullmatch(value)) and datetime.date.fromisoformat(value) is not None
    except ValueError:
        ok = False
    if not ok:
        raise RecordError(f"--date {value!r}: expected a calendar date YYYY-MM-DD")
    return value


def put_record(store: Any, record: Any, machine: str, date: str, name: str | None = None) -> dict[str, Any]:
    """Keep a measurement record (a validated `htm.ident.records.Record`) in the store for
    `machine` on `date`: its table as Parquet with its metadata JSON beside it under the store's
    root, and a `fleet_records` row naming it. A record already held under that machine, date and
    name raises RecordError (nothing changed). Returns the catalogue row."""
    from htm.ident.records import validate_record, write_record

    check_name("--machine", machine)
    check_date(date)
    name = check_name("record name", name or record.name)
    validate_record(record)  # what diagnosis would refuse is refused here, before anything is written
    if (machine, date, name) in stored(store):
        raise RecordError(f"record {machine} {date} {name} is already in the store {store_label(store)} "
                          "(give another --name, or another --machine / --date)")
    folder = store.root / FLEET_DIR / machine / date
    folder.mkdir(parents=True, exist_ok=True)
    row = {"machine": machine, "date": date, "record": name, "path": f"{FLEET_DIR}/{machine}/{date}/{name}.parquet",
           "columns": ",".join(record.columns), "samples": len(record.columns["t"]), "bytes": 0,
           "added_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    # the row first (a concurrent add of the same record fails on its key before any file is touched),
    # the files written aside and moved into place inside the same transaction: a failure leaves no
    # row, and at most files no row names, which the next add of that record replaces
    with store._tx(), tempfile.TemporaryDirectory(dir=folder, prefix=".adding-") as tmp:
        store.db.execute("INSERT INTO fleet_records VALUES (?, ?, ?, ?, ?, ?, ?, ?)", tuple(row.values()))
        table, meta = write_record(record, Path(tmp) / name, parquet=True)
        row["bytes"] = table.stat().st_size
        os.replace(meta, folder / meta.name)
        os.replace(table, folder / table.name)
        store.db.execute("UPDATE fleet_records SET bytes = ? WHERE machine = ? AND date = ? AND record = ?",
                         (row["bytes"], machine, date, name))
    return row


def stored(store: Any) -> dict[tuple[str, str, str], Path]:
    """The records the store holds for fleet diagnosis: (machine, date, record) -> table path, in
    machine, date and record order."""
    rows = store.db.execute("SELECT machine, date, record, path FROM fleet_records ORDER BY machine, date, record").fetchall()
    return {(m, d, r): store.root / p for m, d, r, p in rows}


def store_label(store: Any) -> str:
    """How the store is named in messages (a PostgreSQL URL holds no password: backend.check_url)."""
    return str(store.path) if isinstance(store.path, str) else str(store.root)


def held(store: Any) -> set[tuple[str, str, str]]:
    """(machine, date, record) already diagnosed into the catalogue."""
    return {(m, d, r) for m, d, r in store.db.execute("SELECT DISTINCT machine, date, record FROM fleet_params").fetchall()}


def add(store: Any, machine: str, date: str, record: str, report: dict[str, Any]) -> int:
    """Keep a diagnosis's identified parameters (one transaction; a record diagnosed again replaces its rows)."""
    params = {k: float(v) for k, v in report["final"]["params"].items() if isinstance(v, (int, float))}
    findings = json.dumps([f.get("effect") for f in report.get("findings", [])])
    now = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    with store._tx():
        store.db.execute("DELETE FROM fleet_params WHERE machine = ? AND date = ? AND record = ?", (machine, date, record))
        store.db.executemany("INSERT INTO fleet_params VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                             [(machine, date, record, k, v, findings, int(bool(report.get("unexplained"))), now)
                              for k, v in params.items()])
    return len(params)


def history(store: Any, machine: str) -> dict[str, list[tuple[str, float]]]:
    """Every parameter of a machine: [(date, value)] in date order (records of one date averaged)."""
    rows = store.db.execute("SELECT param, date, AVG(value) FROM fleet_params WHERE machine = ? "
                            "GROUP BY param, date ORDER BY param, date", (machine,)).fetchall()
    if not rows:
        known = [m for (m,) in store.db.execute("SELECT DISTINCT machine FROM fleet_params ORDER BY machine").fetchall()]
        raise RecordError(f"no diagnosis of machine `{machine}` in the store"
                          + (f" (machines: {', '.join(known)})" if known else " (`htm fleet diagnose FOLDER` or `--from-store` adds them)"))
    out: dict[str, list[tuple[str, float]]] = {}
    for p, d, v in rows:
        out.setdefault(p, []).append((d, float(v)))
    return out
