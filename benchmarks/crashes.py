"""Crash campaign: SIGKILL at random moments of recorded tests, then what the store kept.

1. A simulated test (`htm run`, full mode) killed at `--kills` random moments, resumed after each
   (`htm resume`), compared with the same test run uninterrupted: cycles lost or duplicated, raw
   samples lost (in seconds of test time).
2. Live tests on the virtual rig (a `Session` in a child process, real-time paced, recorded)
   killed at random moments: they cannot resume, but the next start must find them marked
   `interrupted`, their rows contiguous from cycle 1, and the raw feed lost at the kill is the
   test time between the last sample the loop had and the last one stored.

    .venv/bin/python benchmarks/crashes.py [--kills 20] [--live-kills 5] [--seed 7]
"""
from __future__ import annotations

import argparse
import json
import random
import signal
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np

from htm import core
from htm.record import Store, journal
from htm.spec import parse

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "ct_constant_force.toml"
HTM = [sys.executable, "-c", "import sys; from htm.cli import main; sys.exit(main())"]
LIVE_CHILD = """
import sys, time
from htm.control import Session
from htm.control.session import specimen_of
from htm.devices.config import virtual_config
from htm.spec import load
spec = load(sys.argv[2])
s = Session().open(virtual_config("lockstep"), virtual=True, specimen=specimen_of(spec), paced=True)
s.start(spec, store=sys.argv[1], recording=False)
print("id", s.recorder.test_id, flush=True)
while True:  # the loop's period count (its clock), as often as a kill could come
    print("k", s.loop.k, flush=True)
    time.sleep(0.02)
"""


def short_spec(folder: Path, c_scale: float) -> Path:
    p = folder / "short.toml"
    p.write_text(EXAMPLE.read_text().replace("c = 1.1413e-29", f"c = {1.1413e-29 * c_scale:.6e}"))
    return p


def reference(spec_path: Path) -> tuple[dict, np.ndarray]:
    spec = parse(tomllib.loads(spec_path.read_text()), spec_path.stem)
    s = core.TestRun(spec.config, "full", core.RAW_POLICY)
    tables, raws = [], []
    while not s.finished:
        d = s.advance(max_seconds=60.0)
        tables.append(core.columns(d.table))
        raw = core.columns(d.raw)
        raws.append(np.column_stack([raw[k] for k in core.RAW_COLUMNS]))
    from htm.record.store import concat

    return concat(tables), np.concatenate(raws)


def simulated(folder: Path, kills: int, rng: random.Random) -> dict:
    spec = short_spec(folder, 1.5)  # ≈ 6·10⁴ cycles in full mode
    store = folder / "store"
    args = ["--store", str(store), "--quiet"]
    proc = subprocess.Popen(HTM + ["run", str(spec), "--mode", "full", "--out", str(folder / "o")] + args,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    tid = None
    while tid is None:
        time.sleep(0.05)
        if (store / "catalogue.sqlite").exists():
            with Store(store) as s:
                rows = s.list_tests()
            tid = rows[0]["id"] if rows else None
    tdir = store / "tests" / tid
    done, statuses = 0, []
    while done < kills:
        seg = tdir / f"journal-{max(len(journal.segments(tdir)) - 1, 0):03d}.htmj"
        t0 = time.monotonic()
        while proc.poll() is None and time.monotonic() - t0 < 60 and not (seg.exists() and seg.stat().st_size > 20_000):
            time.sleep(0.01)
        time.sleep(rng.uniform(0.0, 0.5))
        if proc.poll() is not None:
            break
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        done += 1
        with Store(store) as s:
            statuses.append(s.get(tid)["status"])
        proc = subprocess.Popen(HTM + ["resume", tid] + args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    proc.wait(600)
    with Store(store) as s:
        t = s.get(tid)
        table, raw = s.cycles(tid), s.raw(tid)
    ref, ref_raw = reference(spec)
    c, rc = table["cycle"], ref["cycle"]
    dt = 1.0 / 1000.0  # the example's control rate
    got_raw = np.column_stack([raw[k] for k in core.RAW_COLUMNS]) if raw else np.zeros((0, ref_raw.shape[1]))
    ref_rows = {tuple(r) for r in ref_raw.tolist()}
    same_raw = sum(tuple(r) in ref_rows for r in got_raw.tolist())
    identical = len(c) == len(rc) and all(np.array_equal(table[k], ref[k], equal_nan=True) for k in ref)
    return {"kills": done, "status": t["status"], "statuses_after_kill": sorted(set(statuses)),
            "cycles": int(len(c)), "cycles_reference": int(len(rc)),
            "cycles_lost": int(len(np.setdiff1d(rc, c))), "cycles_duplicated": int(len(c) - len(np.unique(c))),
            "table_identical": bool(identical), "raw_rows": int(len(got_raw)), "raw_rows_reference": int(len(ref_raw)),
            "raw_lost_s": (len(ref_raw) - same_raw) * dt}


def live(folder: Path, kills: int, rng: random.Random) -> dict:
    spec = EXAMPLE
    store = folder / "live-store"
    out = []
    for _ in range(kills):
        p = subprocess.Popen([sys.executable, "-c", LIVE_CHILD, str(store), str(spec)], stdout=subprocess.PIPE, text=True)
        tid = p.stdout.readline().split()[1]
        time.sleep(rng.uniform(2.0, 5.0))
        last_k = 0
        p.send_signal(signal.SIGKILL)
        for line in p.stdout.read().splitlines():  # everything the child said before it died
            if line.startswith("k "):
                last_k = int(line.split()[1])
        p.wait()
        # the next start: a store opened on the folder finds the dead writer
        with Store(store) as s:
            t = s.get(tid)
            c = s.cycles(tid).get("cycle", np.zeros(0))
            raw = s.raw(tid)
        t_loop = last_k / 500.0
        t_stored = float(raw["t_s"][-1]) if raw else 0.0
        out.append({"status": t["status"], "cycles": int(len(c)),
                    "contiguous": bool(np.array_equal(c, np.arange(1, len(c) + 1))),
                    "raw_lost_s": round(max(t_loop - t_stored, 0.0), 3)})
    return {"kills": len(out), "all_interrupted": all(o["status"] == "interrupted" for o in out),
            "all_contiguous": all(o["contiguous"] for o in out), "max_raw_lost_s": max(o["raw_lost_s"] for o in out),
            "runs": out}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--kills", type=int, default=20)
    ap.add_argument("--live-kills", type=int, default=5)
    ap.add_argument("--seed", type=int, default=7)
    a = ap.parse_args()
    rng = random.Random(a.seed)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        sim = simulated(Path(tmp), a.kills, rng)
        lv = live(Path(tmp), a.live_kills, rng)
    print(json.dumps({
        "kills": sim["kills"] + lv["kills"],
        "cycles_lost": sim["cycles_lost"],
        "cycles_duplicated": sim["cycles_duplicated"],
        "max_raw_lost_s": max(sim["raw_lost_s"], lv["max_raw_lost_s"]),
        "acceptance": {"cycles_lost": 0, "cycles_duplicated": 0, "max_raw_lost_s": 1.0},
        "simulated": sim, "live": lv, "wall_s": round(time.perf_counter() - t0, 1),
    }, indent=1))


if __name__ == "__main__":
    main()
