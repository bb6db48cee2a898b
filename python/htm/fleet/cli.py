"""`htm fleet diagnose FOLDER` and `htm fleet trend MACHINE`."""
from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from htm.campaign import cluster
from htm.errors import HtmError


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


def cmd_fleet_diagnose(args: argparse.Namespace) -> int:
    from htm.fleet import catalogue
    from htm.record.store import Store

    jobs = catalogue.records_in(Path(args.folder))
    with Store(args.store) as store:
        done = catalogue.held(store)
        todo = [j for j in jobs if (j[0], j[1], catalogue.record_name(j[2])) not in done]
        client = None
        if args.cluster:
            client = cluster.connect(args.cluster)
        print(f"fleet: {len(jobs)} records in {args.folder}, {len(jobs) - len(todo)} already in the store, diagnosing {len(todo)}")
        failed = 0
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
                print(f"  {machine} {date} {name}: {n} parameters kept; findings: {found}")
        finally:
            if client is not None:
                client.close()
    return 1 if failed else 0


def cmd_fleet_trend(args: argparse.Namespace) -> int:
    from htm.fleet import catalogue, drift
    from htm.record.store import Store

    with Store(args.store) as store:
        hist = catalogue.history(store, args.machine)
    verdicts = drift.judge_all(hist, args.k_sigma)
    params = [p for p in (args.param or sorted(hist)) if p in hist]
    if args.param and len(params) < len(args.param):
        raise HtmError(f"machine {args.machine} has no parameter {', '.join(set(args.param) - set(hist))} (it has: {', '.join(sorted(hist))})")
    w = max(len(p) for p in params)
    flagged = []
    for p in params:
        v = verdicts[p]
        n = len(hist[p])
        if v["drift"] is None:
            state = f"{n} date(s): too little history to judge"
        else:
            state = f"{v['z']:+.1f} σ from {v['mean']:.4g} (scatter {v['scatter']:.3g})" + ("  DRIFT" if v["drift"] else "")
        print(f"{p:<{w}}  {v['latest']:.6g} on {v['date']}  {state}")
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
    f = sub.add_parser("fleet", help="diagnose records of several machines into the catalogue; trend a machine's parameters",
                       description="Fleet diagnosis: identified parameters per machine and date, and their drift.")
    fs = f.add_subparsers(dest="fleet_command", required=True, metavar="SUBCOMMAND")
    d = fs.add_parser("diagnose", help="run `htm diagnose` on every record of FOLDER/MACHINE/DATE/ and keep the parameters",
                      description="Diagnose every record laid out as FOLDER/MACHINE/DATE/NAME.csv (NAME.json beside it) and "
                                  "keep its identified parameters per machine and date in the store; records already "
                                  "there are skipped.")
    d.add_argument("folder")
    d.add_argument("--cluster", metavar="tcp://HOST:PORT", default=cluster.default_address(),
                   help="diagnose on this Dask scheduler's workers (FOLDER must be readable there; default $HTM_CLUSTER)")
    d.add_argument("--store", help="test store: a folder or postgresql://USER@HOST:PORT/DB")
    d.add_argument("--work-s", type=float, default=20.0, help="search effort per record (diagnose's work_s, default 20)")
    d.set_defaults(func=cmd_fleet_diagnose)
    t = fs.add_parser("trend", help="a machine's identified parameters by date, flagging drift beyond their own scatter",
                      description="Print (and plot with --out) every identified parameter of MACHINE by date; the latest "
                                  "value is flagged DRIFT when it lies more than K σ from the mean of the earlier dates "
                                  "(σ their scatter; at least 3 earlier dates).")
    t.add_argument("machine")
    t.add_argument("--store", help="test store: a folder or postgresql://USER@HOST:PORT/DB")
    t.add_argument("--param", action="append", help="only this parameter (repeatable)")
    t.add_argument("--k-sigma", type=float, default=3.0, help="drift threshold in units of the earlier scatter (default 3)")
    t.add_argument("--out", help="PNG of the history")
    t.set_defaults(func=cmd_fleet_trend)
