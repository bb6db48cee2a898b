"""`htm db list | show ID | export ID | delete ID`: the test store from the shell (`htm resume ID` is htm.run's)."""
from __future__ import annotations

import argparse
from pathlib import Path

from htm.errors import RecordError
from htm.record.store import Store


def cmd_list(args: argparse.Namespace) -> int:
    with Store(args.store) as store:
        rows = store.list_tests()
        if not rows:
            print(f"no tests in {store.root}")
            return 0
        print(f"{'id':<22} {'status':<9} {'kind':<10} {'mode':<5} {'cycles':>11} {'a_end mm':>9}  {'end reason':<24} name")
        for r in rows:
            a = f"{r['a_end_m'] * 1e3:9.3f}" if r["a_end_m"] is not None else " " * 9
            cyc = f"{r['cycles']:>11,}" if r["cycles"] is not None else " " * 11
            print(f"{r['id']:<22} {r['status']:<9} {r['kind']:<10} {r['mode'] or '':<5} {cyc} {a}  {r['end_reason'] or '':<24} {r['name']}")
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
        print(f"test {t['id']}: {t['name']} ({t['kind']}, mode {t['mode']}) — {t['status']}"
              + (f", {t['end_reason']}" if t["end_reason"] else ""))
        print(f"created {t['created_utc']}, updated {t['updated_utc']}, host {t.get('host') or '?'}")
        if t["cycles"] is not None:
            print(f"cycles {t['cycles']:,}" + (f", final a = {t['a_end_m'] * 1e3:.3f} mm" if t["a_end_m"] is not None else ""))
        for k, v in sorted(t["results"].items()):
            print(f"  {k} = {v}")
        print(f"events ({len(t['events'])}):")
        for e in t["events"][: args.events]:
            c = f"cycle {e['cycle']:,}" if e["cycle"] is not None else ""
            print(f"  {c:<16} {e['kind']:<20} {e['detail'] or ''}")
        if len(t["events"]) > args.events:
            print(f"  … {len(t['events']) - args.events} more (--events N)")
        print("files:")
        for role, f in sorted(t["files"].items()):
            print(f"  {role:<10} {f['path']} ({(f['bytes'] or 0) / 1e6:.2f} MB)")
        if t["status"] != "finished":
            print(resume_hint(t))
    return 0


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
    print("exported: " + ", ".join(str(p) for p in written))
    return 0


def cmd_delete(args: argparse.Namespace) -> int:
    with Store(args.store) as store:
        t = store.get(args.id)
        if not args.yes:
            raise RecordError(f"deleting test {args.id} ({t['name']}, {t['status']}) removes all its data; add --yes")
        store.delete(args.id)
        print(f"deleted {args.id}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    db = sub.add_parser("db", help="the test store: list, show, export, delete tests",
                        description="Query the test store (SQLite catalogue + Parquet tables + rerun recordings).")
    dsub = db.add_subparsers(dest="db_command", required=True, metavar="ACTION")
    p = dsub.add_parser("list", help="every test: id, status, cycles, end reason")
    p.set_defaults(func=cmd_list)
    p = dsub.add_parser("last", help="the newest test's id (for scripts: ID=$(htm db last))")
    p.set_defaults(func=cmd_last)
    p = dsub.add_parser("show", help="one test: status, results, events, files")
    p.add_argument("id")
    p.add_argument("--events", type=int, default=30, help="events to print (default 30)")
    p.set_defaults(func=cmd_show)
    p = dsub.add_parser("export", help="a test's tables (cycles, raw), metadata and spec into a folder")
    p.add_argument("id")
    p.add_argument("--out", required=True, help="folder to write (must be empty or missing)")
    p.add_argument("--format", choices=["parquet", "csv"], default="parquet")
    p.set_defaults(func=cmd_export)
    p = dsub.add_parser("delete", help="remove a test and its files")
    p.add_argument("id")
    p.add_argument("--yes", action="store_true", help="really delete")
    p.set_defaults(func=cmd_delete)
    for q in dsub.choices.values():
        q.add_argument("--store", help="test store folder (default $HTM_STORE or ~/.local/share/htm/store)")
