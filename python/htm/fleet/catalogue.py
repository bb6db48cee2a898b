"""The fleet table of the store's catalogue: one row per (machine, date, record, parameter), the
value `htm diagnose` identified (its final model), SI."""
from __future__ import annotations

import json
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
                          + (f" (machines: {', '.join(known)})" if known else " (`htm fleet diagnose FOLDER` adds them)"))
    out: dict[str, list[tuple[str, float]]] = {}
    for p, d, v in rows:
        out.setdefault(p, []).append((d, float(v)))
    return out
