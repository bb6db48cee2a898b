"""Running a campaign: chunks of tests through the core's `run_batch` (GIL released), on local
threads or on a Dask cluster, each chunk's rows written to the store as it comes back.

What makes it safe to stop and start again: the plan is fixed by the campaign file, every row is
keyed by (campaign id, test index) and written with `ON CONFLICT DO NOTHING` in one transaction per
chunk, and a re-started campaign only submits the indices the store does not hold yet. A chunk lost
with its worker is simply run again (Dask reschedules it); it cannot be written twice.

Life-test campaigns (`life.py`: S-N, ε-N, staircase) go through the same chunks, runners and table:
`run_chunk` runs their specimens through the core's life engine, and a staircase, whose next level
follows the last outcome, sends one specimen per chunk and writes it before choosing the next.
"""
from __future__ import annotations

import json
import math
import os
import socket
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor, as_completed
from typing import Any

from htm.campaign.spec import Campaign
from htm.errors import HtmError, RecordError
from htm.terminal import Progress

# ISO 12108 / E647 force band used across htm (`htm run`'s summary): ±2 % of the force range
FORCE_BAND_PCT = 2.0
RESULT_COLUMNS = ("life_cycles", "end_reason", "a_end_m", "max_abs_df_err_pct", "max_abs_peak_err_pct",
                  "size_criterion_cycle", "valid", "error", "wall_s", "worker")
LIFE_MODES = ("force_life", "strain_life")  # campaigns of life tests (htm.campaign.life): core.run_life
# how a life test may end with a result: a failure (by its criterion) or a run-out
LIFE_ENDS = ("runout", "separation", "load_drop", "modulus_ratio")


def _row(idx: int, out: Any, error: str | None, wall_s: float, worker: str) -> dict[str, Any]:
    """The result row of test `idx`: `out` its `core.Outcome`, or None with the engine's `error`."""
    if out is None:
        return {"idx": idx, "life_cycles": None, "end_reason": "engine_error", "a_end_m": None, "max_abs_df_err_pct": None,
                "max_abs_peak_err_pct": None, "size_criterion_cycle": None, "valid": False, "error": error,
                "wall_s": wall_s, "worker": worker}
    # a valid test reached its target crack length inside the force band with the E647 size
    # criterion met throughout
    valid = (out.end_reason == "target_crack_length" and out.size_criterion_cycle is None
             and out.max_abs_df_err_pct <= FORCE_BAND_PCT and out.max_abs_peak_err_pct <= FORCE_BAND_PCT)
    return {"idx": idx, "life_cycles": int(out.cycles), "end_reason": out.end_reason, "a_end_m": float(out.a_end_m),
            "max_abs_df_err_pct": float(out.max_abs_df_err_pct), "max_abs_peak_err_pct": float(out.max_abs_peak_err_pct),
            "size_criterion_cycle": out.size_criterion_cycle, "valid": bool(valid), "error": None,
            "wall_s": wall_s, "worker": worker}


def _finite(v: Any) -> Any:
    return None if isinstance(v, float) and not math.isfinite(v) else v


def _life_row(idx: int, out: dict[str, Any] | None, error: str | None, wall_s: float, worker: str) -> dict[str, Any]:
    """The result row of life test `idx` (`out` the core's `run_life` result): its life, how it
    ended, and in `results` what an S-N / ε-N fit and a staircase need (run-out, the drop cycles,
    the stabilised loop) with the virtual specimen's hidden milestones."""
    from htm.fatigue.lifetest import stabilised

    if out is None:
        return _row(idx, None, error, wall_s, worker) | {"results": None}
    res = {"runout": out["end_reason"] == "runout", "failed": bool(out["failed"]),
           **{k: _finite(out[k]) for k in ("n_drop10", "n_drop50", "n_modulus", "cycles_simulated")},
           "stabilised": stabilised(out), "truth": {k: _finite(float(v)) for k, v in out["truth"].items()}}
    return {"idx": idx, "life_cycles": int(out["cycles"]), "end_reason": out["end_reason"], "a_end_m": None,
            "max_abs_df_err_pct": None, "max_abs_peak_err_pct": None, "size_criterion_cycle": None,
            "valid": out["end_reason"] in LIFE_ENDS, "error": None, "wall_s": wall_s, "worker": worker, "results": res}


def run_chunk(items: list[tuple[int, dict[str, Any]]], mode: str, threads: int = 1) -> list[dict[str, Any]]:
    """Run one chunk of tests (index, spec document) in the core; one result row per test.

    This is the unit a cluster worker runs: plain data in and out (specs are rebuilt here, the
    core's objects do not travel). A test the engine rejects gets a row with its error rather than
    failing its neighbours. Life tests (`mode` force_life / strain_life) carry the core's life
    config (validated when the campaign was planned) and run through `core.run_life_batch`."""
    from htm import core
    from htm import spec as test_spec

    worker = f"{socket.gethostname()}:{os.getpid()}"
    if mode in LIFE_MODES:
        t0 = time.perf_counter()
        louts = core.run_life_batch([doc for _, doc in items], None, threads)
        wall = (time.perf_counter() - t0) / len(items)
        return [_life_row(i, None, str(o), wall, worker) if isinstance(o, BaseException) else _life_row(i, o, None, wall, worker)
                for (i, _), o in zip(items, louts, strict=True)]
    cfgs = [test_spec.parse(doc, f"test-{i}").config for i, doc in items]
    t0 = time.perf_counter()
    outs = core.run_batch(cfgs, mode, threads)  # each an Outcome, or the HtmError of a test that failed
    wall = (time.perf_counter() - t0) / len(items)
    return [_row(i, None, str(o), wall, worker) if isinstance(o, HtmError) else _row(i, o, None, wall, worker)
            for (i, _), o in zip(items, outs, strict=True)]


# ---- where chunks run --------------------------------------------------------------------------

Chunk = list[tuple[int, dict[str, Any]]]


def local_runner(threads: int = 0) -> Callable[[list[Chunk], str], Iterator[list[dict[str, Any]]]]:
    """Chunks on this machine's cores: one chunk per thread, each through the core with the GIL
    released (no barrier between chunks: a long test holds one core, not all)."""
    n = threads or os.cpu_count() or 1

    def run(chunks: list[Chunk], mode: str) -> Iterator[list[dict[str, Any]]]:
        with ThreadPoolExecutor(max_workers=n) as pool:
            futs = [pool.submit(run_chunk, c, mode, 1) for c in chunks]
            try:
                for f in as_completed(futs):
                    yield f.result()
            finally:
                for f in futs:
                    f.cancel()

    return run


# ---- the catalogue side --------------------------------------------------------------------------

TABLE_COLUMNS = ("campaign_id", "idx", "inputs_hash", "inputs", *RESULT_COLUMNS, "written_utc", "results")


def register(store: Any, c: Campaign) -> None:
    """Record the campaign itself (once; a re-start finds it)."""
    with store._tx():
        store.db.execute("INSERT INTO campaigns VALUES (?, ?, ?, ?, ?, ?, ?, ?) ON CONFLICT(id) DO NOTHING",
                         (c.id, c.name, time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), c.mode, c.planned or len(c),
                          json.dumps({"swept": c.swept, "scattered": c.scattered}), c.text, c.base_text))


def held(store: Any, campaign_id: str) -> dict[int, str]:
    """The tests the store holds for a campaign: index -> the hash of its inputs."""
    rows = store.db.execute("SELECT idx, inputs_hash FROM campaign_tests WHERE campaign_id = ?", (campaign_id,)).fetchall()
    return {int(i): h for i, h in rows}


def check_held(c: Campaign, idx: int, h: str) -> None:
    """The store's test `idx` (inputs hash `h`) is the plan's, or a RecordError says nothing ran."""
    if idx >= len(c) or h != c.inputs_hash(idx):
        raise RecordError(f"campaign {c.id}: the store's test {idx} has other inputs than this plan; "
                          "nothing was run (was the campaign file changed without changing its name?)")


def done(store: Any, c: Campaign) -> set[int]:
    """Indices of the tests the store already holds for this campaign (checked against the plan)."""
    have = held(store, c.id)
    for idx, h in have.items():
        check_held(c, idx, h)
    return set(have)


def write(store: Any, c: Campaign, rows: list[dict[str, Any]]) -> int:
    """Write one chunk's rows in one transaction; a row already there is kept. Returns rows added."""
    now = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    vals = [(c.id, r["idx"], c.inputs_hash(r["idx"]), json.dumps(c.inputs[r["idx"]], sort_keys=True),
             r["life_cycles"], r["end_reason"], r["a_end_m"], r["max_abs_df_err_pct"], r["max_abs_peak_err_pct"],
             r["size_criterion_cycle"], int(r["valid"]), r["error"], r["wall_s"], r["worker"], now,
             None if r.get("results") is None else json.dumps(r["results"], sort_keys=True)) for r in rows]
    with store._tx():
        before = store.db.execute("SELECT COUNT(*) FROM campaign_tests WHERE campaign_id = ?", (c.id,)).fetchone()[0]
        store.db.executemany(f"INSERT INTO campaign_tests({', '.join(TABLE_COLUMNS)}) VALUES ({', '.join('?' * len(TABLE_COLUMNS))}) "
                             "ON CONFLICT(campaign_id, idx) DO NOTHING", vals)
        after = store.db.execute("SELECT COUNT(*) FROM campaign_tests WHERE campaign_id = ?", (c.id,)).fetchone()[0]
    return int(after - before)


def table(store: Any, campaign_id: str) -> list[dict[str, Any]]:
    """The campaign's table: one dict per test in plan order (its input fields, then the results;
    a life test's own results under `results`)."""
    cur = store.db.execute(f"SELECT idx, inputs, {', '.join(RESULT_COLUMNS)}, results FROM campaign_tests "
                           "WHERE campaign_id = ? ORDER BY idx", (campaign_id,))
    out = []
    for r in cur.fetchall():
        d = {"idx": int(r[0]), **json.loads(r[1])}
        d.update(zip(RESULT_COLUMNS, r[2:-1]))
        d["valid"] = bool(d["valid"])
        if r[-1] is not None:
            d["results"] = json.loads(r[-1])
        out.append(d)
    return out


# ---- the driver ------------------------------------------------------------------------------------

def run(c: Campaign, store: Any, runner: Callable[[list[Chunk], str], Iterable[list[dict[str, Any]]]],
        progress: bool = True) -> dict[str, Any]:
    """Run what the store does not hold yet; returns counts and throughput of this session."""
    register(store, c)
    have = done(store, c)
    todo = [i for i in range(len(c)) if i not in have]
    chunks = [[(i, c.docs[i]) for i in ch] for ch in c.chunks(todo)]
    t0 = time.perf_counter()
    added = 0
    bar = Progress(len(c), "tests", f"campaign {c.id}", start=len(have)) if progress else None
    if bar:
        bar.update(len(have))
    try:
        for rows in runner(chunks, c.mode):
            added += write(store, c, rows)
            if bar:
                bar.update(len(have) + added)
    finally:
        if bar:
            bar.close()
    wall = time.perf_counter() - t0
    return {"campaign": c.id, "tests": len(c), "skipped": len(have), "ran": added, "wall_s": wall,
            "tests_per_s": added / wall if wall > 0 and added else 0.0}
