"""Several processes writing campaign rows into one catalogue at once, then counting what arrived:
the check that a shared catalogue (SQLite file or PostgreSQL) loses and duplicates nothing.

Each writer process opens its own `Store` on the same catalogue and writes its own rows of one
campaign, one transaction per row (the worst case for contention); the campaign's rows are then
counted against what was sent.
"""
from __future__ import annotations

import multiprocessing as mp
import time
from pathlib import Path
from typing import Any

from htm.campaign.spec import Campaign


def fake_campaign(campaign_id: str, n: int) -> Campaign:
    """A campaign of `n` planned tests with distinct inputs (nothing to run: rows are written directly)."""
    return Campaign(id=campaign_id, name=campaign_id, path=Path("stress"), text="", base_text="", mode="jump",
                    chunk_tests=1, swept=["x"], scattered=[], inputs=[{"x": float(i)} for i in range(n)], docs=[])


def _row(i: int, worker: str) -> dict[str, Any]:
    return {"idx": i, "life_cycles": 1000 + i, "end_reason": "target_crack_length", "a_end_m": 0.03,
            "max_abs_df_err_pct": 0.1, "max_abs_peak_err_pct": 0.1, "size_criterion_cycle": None, "valid": True,
            "error": None, "wall_s": 0.0, "worker": worker}


def _writer(where: str, campaign_id: str, n: int, k: int, writers: int, start: Any) -> None:
    from htm.campaign import engine
    from htm.record.store import Store

    c = fake_campaign(campaign_id, n)
    with Store(where) as store:
        start.wait()
        for i in range(k, n, writers):  # writer k writes every writers-th row
            engine.write(store, c, [_row(i, f"writer-{k}")])


def concurrent_writes(where: str, writers: int = 4, rows_per_writer: int = 100) -> dict[str, Any]:
    """`writers` processes write `rows_per_writer` rows each into the store at `where` (a folder or a
    PostgreSQL URL); returns rows sent, found, lost, duplicated and the writes/s of all together."""
    from htm.campaign import engine
    from htm.record.store import Store

    n = writers * rows_per_writer
    cid = f"stress-{time.time_ns()}"
    with Store(where) as store:  # created and migrated once, before the writers race
        engine.register(store, fake_campaign(cid, n))
    ctx = mp.get_context("spawn")  # a fresh interpreter per writer: no connection inherited across fork
    start = ctx.Event()
    procs = [ctx.Process(target=_writer, args=(where, cid, n, k, writers, start)) for k in range(writers)]
    for p in procs:
        p.start()
    time.sleep(0.5)  # let every writer open its store before the clock starts
    t0 = time.perf_counter()
    start.set()
    for p in procs:
        p.join(timeout=300)
    wall = time.perf_counter() - t0
    failed = [p.exitcode for p in procs if p.exitcode != 0]
    with Store(where) as store:
        idx = [r[0] for r in store.db.execute("SELECT idx FROM campaign_tests WHERE campaign_id = ?", (cid,)).fetchall()]
    return {"writers": writers, "rows_sent": n, "rows_found": len(idx), "rows_lost": n - len(set(idx)),
            "rows_duplicated": len(idx) - len(set(idx)), "writer_failures": len(failed), "writes_per_s": n / wall}
