"""`htm db list | show ID | export ID | delete ID`: the test store from the shell (`htm resume ID` is htm.run's)."""
from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from htm.errors import RecordError
from htm.record.store import Store
from htm.terminal import add_json_flag, emit_json, eng, grid, label, path, si, size, table


def cmd_list(args: argparse.Namespace) -> int:
    with Store(args.store) as store:
        rows = store.list_tests()
        if args.json:
            emit_json(rows)
            return 0
        if not rows:
            print(f"no tests in {path(store.root)}")
            return 0
        print(grid(["id", "status", "kind", "mode", "cycles", "a end [mm]", "end reason", "name"],
                   [[r["id"], r["status"], r["kind"], r["mode"] or "", "" if r["cycles"] is None else f"{r['cycles']:,}",
                     "" if r["a_end_m"] is None else f"{r['a_end_m'] * 1e3:.3f}", r["end_reason"] or "", r["name"]] for r in rows],
                   right=[False, False, False, False, True, True, False, False]))
    return 0


def cmd_last(args: argparse.Namespace) -> int:
    with Store(args.store) as store:
        rows = store.list_tests()
        if not rows:
            raise RecordError(f"no tests in {store.root}")
        print(rows[-1]["id"])
    return 0


def cmd_show(args: argparse.Namespace) -> int:
    with Store(args.store) as store:
        t = store.get(args.id)
    if args.json:
        emit_json(t)
        return 0
    print(f"test {t['id']}: {t['name']} ({t['kind']}, mode {t['mode']}) — {t['status']}"
          + (f", {t['end_reason']}" if t["end_reason"] else ""))
    rows = [("created", f"{t['created_utc']}, updated {t['updated_utc']}, host {t.get('host') or '?'}")]
    if t["cycles"] is not None:
        rows.append(("cycles", f"{t['cycles']:,}"))
    if t["a_end_m"] is not None:
        rows.append(("final a", eng(t["a_end_m"] * 1e3, "mm")))
    print(table(rows))
    if t["results"]:
        print("results:")
        print(table(result_rows(t["results"]), indent="  "))
    print(f"events ({len(t['events'])}):")
    ev = t["events"][: args.events]
    if ev:
        print(grid(["cycle", "event", "detail"],
                   [["" if e["cycle"] is None else f"{e['cycle']:,}", e["kind"], e["detail"] or ""] for e in ev],
                   right=[True, False, False], indent="  "))
    if len(t["events"]) > args.events:
        print(f"  … {len(t['events']) - args.events} more (--events N)")
    if t["files"]:
        print("files:")
        print(grid(["role", "path", "size"], [[role, path(f["path"]), size(f["bytes"])]
                                             for role, f in sorted(t["files"].items())], right=[False, False, True], indent="  "))
    if t["status"] != "finished":
        print(resume_hint(t))
    return 0


def result_rows(results: dict[str, Any]) -> list[tuple[str, str]]:
    """A test's results (SI, as the store keeps them) as labelled rows in engineering units; a
    list of records (e.g. the convergence events) one row each."""
    rows: list[tuple[str, str]] = []
    for k, v in results.items():
        if isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            for i, x in enumerate(v):
                rows.append((f"{label(k)} {i + 1}" if len(v) > 1 else label(k),
                             ", ".join(f"{label(kk)} {si(kk, vv)}" for kk, vv in x.items())))
        elif isinstance(v, dict):
            rows.append((label(k), ", ".join(f"{label(kk)} {si(kk, vv)}" for kk, vv in v.items()) or "–"))
        else:
            rows.append((label(k), si(k, v)))
    return rows


def resume_hint(t: dict) -> str:
    """What can be done with a test that did not finish."""
    if t["kind"] == "simulated" and t["status"] != "running":
        return f"resume with: htm resume {t['id']}"
    if t["status"] == "running":
        return "the test is running (its writer holds it)"
    return (f"a {t['kind']} test does not resume (the physical test cannot be continued from the store); "
            f"every row recorded is kept: htm db export {t['id']} --out DIR")


def cmd_export(args: argparse.Namespace) -> int:
    with Store(args.store) as store:
        written = store.export(args.id, Path(args.out), args.format)
    if args.json:
        emit_json({"exported": [str(p) for p in written]})
        return 0
    print("exported: " + ", ".join(path(p) for p in written))
    return 0


def cmd_delete(args: argparse.Namespace) -> int:
    with Store(args.store) as store:
        t = store.get(args.id)
        if not args.yes:
            raise RecordError(f"deleting test {args.id} ({t['name']}, {t['status']}) removes all its data; add --yes")
        store.delete(args.id)
        print(f"deleted {args.id}")
    return 0


def register(sub: argparse._SubParsersAction,
             more: Sequence[Callable[[argparse._SubParsersAction], None]] = ()) -> None:
    """`htm db` and its actions; `more` adds actions that live in packages above the store's."""
    db = sub.add_parser("db", help="the test store: list, show, export, delete tests",
                        description="Query the test store (SQLite catalogue + Parquet tables + rerun recordings).")
    dsub = db.add_subparsers(dest="db_command", required=True, metavar="ACTION")
    p = dsub.add_parser("list", help="every test: id, status, cycles, end reason")
    add_json_flag(p)
    p.set_defaults(func=cmd_list)
    p = dsub.add_parser("last", help="the newest test's id (for scripts: ID=$(htm db last))")
    p.set_defaults(func=cmd_last)
    p = dsub.add_parser("show", help="one test: status, results, events, files")
    p.add_argument("id")
    p.add_argument("--events", type=int, default=30, help="events to print (default 30)")
    add_json_flag(p)
    p.set_defaults(func=cmd_show)
    p = dsub.add_parser("export", help="a test's tables (cycles, raw), metadata and spec into a folder")
    p.add_argument("id")
    p.add_argument("--out", required=True, help="folder to write (must be empty or missing)")
    p.add_argument("--format", choices=["parquet", "csv"], default="parquet")
    add_json_flag(p)
    p.set_defaults(func=cmd_export)
    p = dsub.add_parser("delete", help="remove a test and its files")
    p.add_argument("id")
    p.add_argument("--yes", action="store_true", help="really delete")
    p.set_defaults(func=cmd_delete)
    for q in dsub.choices.values():
        q.add_argument("--store", help="test store folder (default $HTM_STORE or ~/.local/share/htm/store)")
    for add in more:
        add(dsub)
