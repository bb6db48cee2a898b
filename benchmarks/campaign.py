"""Campaign throughput in-process vs a local Dask cluster, and catalogue writes with 4 concurrent
writers on SQLite vs PostgreSQL. Prints one JSON object.

Needs the services of tools/services.sh (a 2-worker Dask cluster and a PostgreSQL server):

    bash tools/services.sh .venv/bin/python benchmarks/campaign.py [--campaign examples/campaign_ct.toml]

The same campaign runs into fresh stores: on this machine's cores (local threads), on one local
thread, on the cluster's two workers, and on one of them (tasks pinned to it) for the 1 → 2 scaling;
the in-process 1 → 2 thread scaling beside it tells what the machine itself gives a second core.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def timed(c, runner, store_dir: Path) -> float:
    from htm.campaign import engine
    from htm.record.store import Store

    with Store(store_dir) as store:
        s = engine.run(c, store, runner, progress=False)
        assert s["ran"] == len(c), s
    return s["tests_per_s"]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--campaign", default=str(ROOT / "examples" / "campaign_ct.toml"))
    ap.add_argument("--rows-per-writer", type=int, default=100)
    ap.add_argument("--repeat", type=int, default=2, help="runs of each setting, interleaved; the best counts "
                                                             "(other work on the machine only slows a run down)")
    args = ap.parse_args()
    pg, dask = os.environ.get("HTM_TEST_PG"), os.environ.get("HTM_TEST_DASK")
    if not (pg and dask):
        print("benchmarks/campaign.py: needs HTM_TEST_PG and HTM_TEST_DASK: run it through tools/services.sh", file=sys.stderr)
        return 2

    from htm.campaign import cluster, engine
    from htm.campaign import spec as campaign_spec
    from htm.campaign.stress import concurrent_writes

    c = campaign_spec.load(args.campaign)
    client = cluster.connect(dask)
    client.wait_for_workers(2, timeout=60)
    workers = sorted(client.scheduler_info()["workers"])
    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        client.run(lambda: __import__("htm.campaign.engine"))  # imports paid before the clock
        # in-process on one thread: what the machine gives one core now, the reference for both scalings
        runs: dict[str, list[float]] = {"inprocess": [], "inprocess1": [], "dask2": [], "dask1": []}
        for k in range(args.repeat):
            runs["inprocess"].append(timed(c, engine.local_runner(), t / f"inprocess{k}"))
            runs["inprocess1"].append(timed(c, engine.local_runner(1), t / f"inprocess1-{k}"))
            runs["dask2"].append(timed(c, cluster.runner(client), t / f"dask2-{k}"))
            runs["dask1"].append(timed(c, cluster.runner(client, workers=workers[:1]), t / f"dask1-{k}"))
        inproc, inproc1, dask2, dask1 = (max(runs[k]) for k in ("inprocess", "inprocess1", "dask2", "dask1"))
        sqlite = concurrent_writes(str(t / "writers"), 4, args.rows_per_writer)
        postgres = concurrent_writes(pg, 4, args.rows_per_writer)
    client.close()
    out = {
        "campaign": f"{Path(args.campaign).name}: {len(c)} tests, {c.chunk_tests} per chunk, mode {c.mode}",
        "cores": os.cpu_count(),
        "runs_tests_per_s": {k: [round(v, 3) for v in vs] for k, vs in runs.items()},
        "tests_per_s_inprocess": round(inproc, 3),
        "tests_per_s_dask": round(dask2, 3),
        "tests_per_s_dask_1_worker": round(dask1, 3),
        "dask_vs_inprocess": round(dask2 / inproc, 3),
        "dask_scaling_1_to_2_workers": round(dask2 / dask1, 3),
        "tests_per_s_inprocess_1_thread": round(inproc1, 3),
        "inprocess_scaling_1_to_2_threads": round(inproc / inproc1, 3),
        "catalogue_writers": 4,
        "catalogue_rows_per_store": sqlite["rows_sent"],
        "catalogue_writes_per_s_sqlite": round(sqlite["writes_per_s"], 1),
        "catalogue_writes_per_s_postgresql": round(postgres["writes_per_s"], 1),
        "catalogue_rows_lost_sqlite": sqlite["rows_lost"] + sqlite["rows_duplicated"],
        "catalogue_rows_lost_postgresql": postgres["rows_lost"] + postgres["rows_duplicated"],
        "load_average_1min": round(os.getloadavg()[0], 2),
        "measured_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
