"""`htm campaign CAMPAIGN.toml`: run a virtual test campaign into the store, on this machine or a Dask cluster."""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from htm.campaign import cluster
from htm.errors import HtmError, SpecError
from htm.terminal import add_json_flag, emit_json, path


def summary_lines(c: Any, rows: list[dict[str, Any]], s: dict[str, Any], where: str) -> list[str]:
    life = np.array([r["life_cycles"] for r in rows if r["valid"]], float)
    lines = [f"campaign {c.id}: {len(rows):,}/{len(c):,} tests in the store ({s['skipped']:,} already there, "
             f"{s['ran']:,} run now on {where} in {s['wall_s']:.1f} s, {s['tests_per_s']:.2f} tests/s)"]
    valid = sum(r["valid"] for r in rows)
    errors = sum(r["error"] is not None for r in rows)
    lines.append(f"valid {valid:,}, not valid {len(rows) - valid - errors:,}, engine errors {errors:,}")
    if len(life):
        q5, q50, q95 = np.percentile(life, [5, 50, 95])
        lines.append(f"life of valid tests: median {q50:,.0f} cycles, 5–95 % {q5:,.0f} .. {q95:,.0f}")
    return lines


def write_table(path: Path, rows: list[dict[str, Any]]) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    pq.write_table(pa.Table.from_pylist(rows), path)


def cmd_campaign(args: argparse.Namespace) -> int:
    from htm.campaign import engine, plot
    from htm.campaign import life as life_campaign
    from htm.campaign import spec as campaign_spec
    from htm.record.store import Store

    # everything that can be wrong is found before the first test: the file, every test's spec,
    # the store and the cluster
    lc = None
    if life_campaign.is_life_campaign(args.campaign):  # S-N, ε-N or staircase of life tests
        if args.model:
            raise SpecError(f"{args.campaign}: --model runs crack-growth campaigns on a rig's twin; a life campaign "
                           "runs the virtual round bar of its test spec")
        lc = life_campaign.load(args.campaign)
        c = lc.campaign
    else:
        c = campaign_spec.load(args.campaign)
    if args.model:  # every test on the rig's identified twin
        c = campaign_spec.on_model(c, args.model)
    out = Path(args.out or f"out/campaign-{c.id}")
    n = c.planned or len(c)
    with Store(args.store) as store:
        if args.cluster:
            client = cluster.connect(args.cluster)
            runner, where = cluster.runner(client), f"Dask {args.cluster} ({len(client.scheduler_info()['workers'])} workers)"
        else:
            client, runner, where = None, engine.local_runner(args.threads), "this machine"
        if not args.json:
            on = f" on the twin {args.model}" if args.model else ""
            how = "one at a time, each level after the last outcome" if lc and lc.kind == "staircase" else f"{c.chunk_tests} per chunk"
            print(f"campaign {c.id}{on}: {n:,} tests ({c.mode} mode, {how}) on {where}; "
                  f"store {path(store.path) if '://' not in str(store.path) else store.path}")
        try:
            s = life_campaign.run(lc, store, runner, progress=not args.quiet) if lc else engine.run(c, store, runner, progress=not args.quiet)
        except KeyboardInterrupt:
            held = len(engine.held(store, c.id))
            raise HtmError(f"interrupted with {held:,}/{n:,} tests in the store; the same command continues") from None
        finally:
            if client is not None:
                client.close()
        rows = engine.table(store, c.id)
    out.mkdir(parents=True, exist_ok=True)
    if lc is not None:
        write_table(out / "campaign.parquet", life_campaign.parquet_rows(rows))
        ls = life_campaign.outputs(lc, rows, out)
        if args.json:
            emit_json(dict(ls, session=s, where=where, outputs=[str(out / "campaign.parquet"), ls["data"], ls["fit"]]))
            return 0
        print(f"campaign {c.id}: {len(rows):,}/{n:,} tests in the store ({s['skipped']:,} already there, "
              f"{s['ran']:,} run now on {where} in {s['wall_s']:.1f} s)")
        for line in life_campaign.summary_lines(ls):
            print(line)
        return 0
    write_table(out / "campaign.parquet", rows)
    png = plot.life_plot(out / "life.png", rows, c.swept + c.scattered, f"{c.name}: life vs campaign fields")
    if args.json:
        life = [r["life_cycles"] for r in rows if r["valid"]]
        emit_json(dict(s, where=where, valid=sum(r["valid"] for r in rows), engine_errors=sum(r["error"] is not None for r in rows),
                       life_cycles_p5_p50_p95=[float(x) for x in np.percentile(life, [5, 50, 95])] if life else None,
                       outputs=[str(out / "campaign.parquet"), str(png)]))
        return 0
    for line in summary_lines(c, rows, s, where):
        print(line)
    print(f"outputs: {path(out / 'campaign.parquet')}, {path(png)}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("campaign", help="run a virtual test campaign (sweeps, Latin hypercube, material scatter; S-N, ε-N, "
                                        "staircase) into the store",
                       description="Expand a campaign file (a base test spec plus [grid], [lhs] and [scatter]; or a "
                                   "[life_campaign]: an S-N / ε-N campaign over levels with specimen scatter, or an ISO "
                                   "12107 staircase) into simulated tests, run them in chunks on all local cores or a Dask "
                                   "cluster (a staircase one specimen at a time), and write one table (inputs, life, end "
                                   "reason, validity) into the store; a life campaign also writes its data CSV and "
                                   "fit.json. Running it again continues where it stopped.",
                       epilog="see examples/campaign_ct.toml, campaign_sn.toml, campaign_en.toml, campaign_staircase.toml "
                              "and docs/guide/campaigns.md")
    p.add_argument("campaign", help="campaign file (TOML)")
    p.add_argument("--cluster", metavar="tcp://HOST:PORT", default=cluster.default_address(),
                   help="run the chunks on this Dask scheduler's workers (default $HTM_CLUSTER; unset: this machine)")
    p.add_argument("--store", help="test store: a folder, or postgresql://USER@HOST:PORT/DB (password from PGPASSWORD "
                                   "or ~/.pgpass); default $HTM_STORE or ~/.local/share/htm/store")
    p.add_argument("--out", help="folder for campaign.parquet and life.png, or a life campaign's CSV, fit.json and report "
                                 "(default out/campaign-ID)")
    p.add_argument("--model", metavar="MODEL.json",
                   help="run every test on the twin: an identified rig model (`htm rig identify`'s model.json) instead "
                        "of the nominal rig (the store keeps it as a campaign of its own)")
    p.add_argument("--threads", type=int, default=0, help="local threads (default all cores)")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    add_json_flag(p)
    p.set_defaults(func=cmd_campaign)
