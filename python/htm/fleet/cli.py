"""`htm fleet add RECORD --machine M --date D`, `htm fleet diagnose FOLDER | --from-store` and `htm fleet trend MACHINE`."""
from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from htm.campaign import cluster
from htm.errors import HtmError, RecordError
from htm.terminal import add_json_flag, emit_json, si


def diagnose_one(table: str, work_s: float) -> dict[str, Any]:
    """Diagnose one record (the unit a cluster worker runs; the path must be readable there too).
    Returns what the fleet keeps: the final parameters, the findings' effects, unexplained."""
    from htm.ident.diagnose import diagnose
    from htm.ident.records import read_record

    rep = diagnose(read_record(table), work_s=work_s)
    return {"final": {"params": rep["final"]["params"]}, "findings": [{"effect": f.get("effect")} for f in rep["findings"]],
            "unexplained": rep["unexplained"]}


def _local(jobs: list[tuple[str, str, Path]], work_s: float) -> Iterator[tuple[tuple[str, str, Path], dict[str, Any] | str]]:
    for job in jobs:
        try:
            yield job, diagnose_one(str(job[2]), work_s)
        except HtmError as e:
            yield job, str(e)


def _dask(client: Any, jobs: list[tuple[str, str, Path]], work_s: float) -> Iterator[tuple[tuple[str, str, Path], dict[str, Any] | str]]:
    from distributed import as_completed

    futs = {client.submit(diagnose_one, str(j[2]), work_s, pure=False, retries=1): j for j in jobs}
    for f in as_completed(list(futs), loop=client.loop):
        try:
            yield futs[f], f.result()
        except Exception as e:  # the record's own error, raised on the worker: reported, the others go on
            yield futs[f], " ".join(str(e).split())


def open_store(where: str | None, must_exist: bool) -> Any:
    """The store at `--store` (default $HTM_STORE...); with `must_exist`, a folder that holds no
    catalogue is refused instead of created (a mistyped path is named, not silently made empty)."""
    from htm.record import backend
    from htm.record.store import Store, default_root

    pg = backend.is_postgres(where) or (where is None and backend.is_postgres(os.environ.get("HTM_STORE")))
    if must_exist and not pg:
        root = Path(where) if where is not None else default_root()
        if not (root / "catalogue.sqlite").is_file():
            raise RecordError(f"--store {root}: no store there (no catalogue.sqlite); `htm fleet add` puts records into a new one")
    return Store(where)


def cmd_fleet_add(args: argparse.Namespace) -> int:
    from htm.fleet import catalogue
    from htm.ident.records import read_record

    if args.name and len(args.records) > 1:
        raise HtmError("--name names one record; give one RECORD with it")
    catalogue.check_name("--machine", args.machine)
    catalogue.check_date(args.date)
    recs = [read_record(r) for r in args.records]  # every record read before any is added
    with open_store(args.store, must_exist=False) as store:
        added = []
        for rec in recs:
            row = catalogue.put_record(store, rec, args.machine, args.date, args.name)
            added.append(row)
            if not args.json:
                print(f"fleet: added {row['machine']} {row['date']} {row['record']} ({row['samples']:,} samples: {row['columns']}) "
                      f"as {row['path']}")
    if args.json:
        emit_json(added)
    return 0


def cmd_fleet_identify(args: argparse.Namespace) -> int:
    """`htm rig identify` on a machine, its record and identified parameters added to the fleet
    catalogue under MACHINE and the date: re-identifying a rig trends it (`htm fleet trend`)."""
    import datetime
    import time

    from htm.control.identify import identify, plan_of
    from htm.fleet import catalogue
    from htm.ident.records import read_record

    catalogue.check_name("--machine", args.machine)
    date = catalogue.check_date(args.date or datetime.date.today().isoformat())
    res = identify(args.config, args.out, store=args.store, plan=plan_of(args))
    print(f"record: {res.record_base}.csv + .json ({res.samples} samples)")
    if res.tripped:
        print(f"experiment stopped safely: {'; '.join(res.tripped)}; the record is kept, nothing added to the fleet")
        return 1
    rec = read_record(f"{res.record_base}.csv")
    name = f"identify-{time.strftime('%H%M%S', time.gmtime())}"
    with open_store(args.store, must_exist=False) as store:
        catalogue.put_record(store, rec, args.machine, date, name)
        n = catalogue.add(store, args.machine, date, name, res.report)
    found = ", ".join(f["effect"] for f in res.report.get("findings", [])) or "none"
    print(f"fleet: {args.machine} {date} {name}: {n} parameters kept (findings: {found}); `htm fleet trend {args.machine}`")
    return 0


def cmd_fleet_diagnose(args: argparse.Namespace) -> int:
    from htm.fleet import catalogue

    if (args.folder is None) == (not args.from_store):
        raise HtmError("give either FOLDER (records as FOLDER/MACHINE/DATE/NAME.csv) or --from-store (the records "
                       "`htm fleet add` put into the store), not both")
    jobs = [] if args.from_store else catalogue.records_in(Path(args.folder))
    with open_store(args.store, must_exist=args.from_store) as store:
        source = args.folder
        if args.from_store:
            jobs = [(m, d, table) for (m, d, _), table in catalogue.stored(store).items()]
            source = f"the store {catalogue.store_label(store)}"
            if not jobs:
                raise RecordError(f"{source} holds no records (`htm fleet add RECORD --machine M --date D --store ...` puts them there)")
        done = catalogue.held(store)
        todo = [j for j in jobs if (j[0], j[1], catalogue.record_name(j[2])) not in done]
        client = None
        if args.cluster:
            client = cluster.connect(args.cluster)
        say = (lambda *a, **k: None) if args.json else print
        say(f"fleet: {len(jobs)} records in {source}, {len(jobs) - len(todo)} already diagnosed in the store, diagnosing {len(todo)}")
        failed = 0
        done_now: list[dict[str, Any]] = []
        try:
            results = _dask(client, todo, args.work_s) if client else _local(todo, args.work_s)
            for (machine, date, table), rep in results:
                name = catalogue.record_name(table)
                if isinstance(rep, str):
                    failed += 1
                    print(f"  {machine} {date} {name}: not diagnosed: {rep}", file=sys.stderr)
                    continue
                n = catalogue.add(store, machine, date, name, rep)
                found = ", ".join(f["effect"] for f in rep["findings"]) or "none"
                done_now.append({"machine": machine, "date": date, "record": name, "parameters": n,
                                 "findings": [f["effect"] for f in rep["findings"]], "unexplained": rep["unexplained"]})
                say(f"  {machine} {date} {name}: {n} parameters kept; findings: {found}")
        finally:
            if client is not None:
                client.close()
    if args.json:
        emit_json({"records": len(jobs), "already_diagnosed": len(jobs) - len(todo), "diagnosed": done_now, "failed": failed})
    return 1 if failed else 0


def cmd_fleet_trend(args: argparse.Namespace) -> int:
    from htm.fleet import catalogue, drift

    with open_store(args.store, must_exist=True) as store:
        hist = catalogue.history(store, args.machine)
    verdicts = drift.judge_all(hist, args.k_sigma)
    params = [p for p in (args.param or sorted(hist)) if p in hist]
    if args.param and len(params) < len(args.param):
        raise HtmError(f"machine {args.machine} has no parameter {', '.join(set(args.param) - set(hist))} (it has: {', '.join(sorted(hist))})")
    w = max(len(p) for p in params)
    flagged = [p for p in params if verdicts[p]["drift"]]
    if args.json:
        if args.out:
            _plot(Path(args.out), args.machine, {p: hist[p] for p in params}, verdicts)
        emit_json({"machine": args.machine, "params": {p: dict(verdicts[p], history=hist[p]) for p in params}, "drift": flagged})
        return 0
    flagged = []
    for p in params:
        v = verdicts[p]
        n = len(hist[p])
        if v["drift"] is None:
            state = f"{n} date(s): too little history to judge"
        else:
            state = f"{v['z']:+.1f} σ from {si(p, v['mean'])} (scatter {si(p, v['scatter'], 2)})" + ("  DRIFT" if v["drift"] else "")
        print(f"{p:<{w}}  {si(p, v['latest']):>14} on {v['date']}  {state}")
        if v["drift"]:
            flagged.append(p)
    if args.out:
        _plot(Path(args.out), args.machine, {p: hist[p] for p in params}, verdicts)
        print(f"plot: {args.out}")
    print(f"{args.machine}: " + (f"drift in {', '.join(flagged)}" if flagged else "no drift beyond its own scatter"))
    return 0


def _plot(path: Path, machine: str, hist: dict[str, list[tuple[str, float]]], verdicts: dict[str, dict[str, Any]]) -> None:
    import math

    from htm.report import pyplot, save

    ncol = min(3, len(hist))
    nrow = math.ceil(len(hist) / ncol)
    fig, axes = pyplot().subplots(nrow, ncol, figsize=(4.2 * ncol, 2.8 * nrow), squeeze=False)
    for ax, (p, pts) in zip(axes.flat, hist.items()):
        dates, vals = zip(*pts)
        v = verdicts[p]
        ax.plot(range(len(vals)), vals, "o-", color="C3" if v["drift"] else "C0")
        if v["scatter"] is not None:
            ax.axhspan(v["mean"] - 3 * v["scatter"], v["mean"] + 3 * v["scatter"], alpha=0.15, color="C2")
        ax.set_xticks(range(len(dates)), dates, rotation=30, fontsize=7)
        ax.set_title(p + ("  DRIFT" if v["drift"] else ""), fontsize=9)
        ax.grid(True, alpha=0.3)
    for ax in list(axes.flat)[len(hist):]:
        ax.set_visible(False)
    fig.suptitle(f"{machine}: identified parameters by date (band: earlier mean ± 3 σ)")
    fig.tight_layout()
    save(fig, path, dpi=100)


def register(sub: argparse._SubParsersAction) -> None:
    from htm.control.identify import add_plan_args

    f = sub.add_parser("fleet", help="diagnose records of several machines into the catalogue; trend a machine's parameters",
                       description="Fleet diagnosis: identified parameters per machine and date, and their drift.")
    fs = f.add_subparsers(dest="fleet_command", required=True, metavar="SUBCOMMAND")
    a = fs.add_parser("add", help="put measurement records into the store for a machine and date",
                      description="Keep DATA_FORMAT records (NAME.csv / .csv.gz / .parquet with NAME.json) in the store "
                                  "for MACHINE on DATE: the table as Parquet with its metadata beside it under the store's "
                                  "path (fleet/MACHINE/DATE/NAME.parquet), a catalogue row naming it. Each record is "
                                  "validated first; one already held under that machine, date and name is refused. "
                                  "`htm fleet diagnose --from-store` then diagnoses them.")
    a.add_argument("records", nargs="+", metavar="RECORD", help="a record's table (or its .json)")
    a.add_argument("--machine", required=True, help="the machine (frame) that recorded it")
    a.add_argument("--date", required=True, help="the date it was recorded, YYYY-MM-DD")
    a.add_argument("--name", help="the record's name in the store (default: its file name; one RECORD only)")
    a.add_argument("--store", help="test store: a folder or postgresql://USER@HOST:PORT/DB (its files on $HTM_STORE_FILES)")
    add_json_flag(a)
    a.set_defaults(func=cmd_fleet_add)
    d = fs.add_parser("diagnose", help="run `htm diagnose` on every record of FOLDER/MACHINE/DATE/ or of the store, keep the parameters",
                      description="Diagnose every record laid out as FOLDER/MACHINE/DATE/NAME.csv (NAME.json beside it), "
                                  "or with --from-store every record `htm fleet add` put into the store, and keep its "
                                  "identified parameters per machine and date in the store; records already diagnosed "
                                  "there are skipped.")
    d.add_argument("folder", nargs="?", help="records as FOLDER/MACHINE/DATE/NAME.csv (or give --from-store)")
    d.add_argument("--from-store", action="store_true", help="diagnose the records the store holds (`htm fleet add`) instead of a folder")
    d.add_argument("--cluster", metavar="tcp://HOST:PORT", default=cluster.default_address(),
                   help="diagnose on this Dask scheduler's workers (FOLDER, or the store's path, must be readable there; "
                        "default $HTM_CLUSTER)")
    d.add_argument("--store", help="test store: a folder or postgresql://USER@HOST:PORT/DB")
    d.add_argument("--work-s", type=float, default=20.0, help="search effort per record (diagnose's work_s, default 20)")
    add_json_flag(d)
    d.set_defaults(func=cmd_fleet_diagnose)
    i = fs.add_parser("identify", help="identify a rig (`htm rig identify`) and add it to the fleet catalogue",
                      description="Run `htm rig identify` on the rig of CONFIG, keep its record in the store for MACHINE "
                                  "on DATE and its identified parameters in the fleet catalogue, so that each "
                                  "re-identification of the machine is trended by `htm fleet trend`.")
    i.add_argument("config", help="rig configuration TOML")
    i.add_argument("--machine", required=True, help="the machine (frame) identified")
    i.add_argument("--date", help="the date, YYYY-MM-DD (default today)")
    i.add_argument("--out", required=True, help="folder for the record, report.json and model.json")
    i.add_argument("--store", help="test store: a folder or postgresql://USER@HOST:PORT/DB")
    add_plan_args(i)
    i.set_defaults(func=cmd_fleet_identify)
    t = fs.add_parser("trend", help="a machine's identified parameters by date, flagging drift beyond their own scatter",
                      description="Print (and plot with --out) every identified parameter of MACHINE by date; the latest "
                                  "value is flagged DRIFT when it lies more than K σ from the mean of the earlier dates "
                                  "(σ their scatter; at least 3 earlier dates).")
    t.add_argument("machine")
    t.add_argument("--store", help="test store: a folder or postgresql://USER@HOST:PORT/DB")
    t.add_argument("--param", action="append", help="only this parameter (repeatable)")
    t.add_argument("--k-sigma", type=float, default=3.0, help="drift threshold in units of the earlier scatter (default 3)")
    t.add_argument("--out", help="PNG of the history")
    add_json_flag(t)
    t.set_defaults(func=cmd_fleet_trend)
