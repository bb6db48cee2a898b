"""Typed boundary benchmark: `htm run examples/ct_constant_force.toml --mode full`, cycles/s of this
tree's build against a peer build (default: the main tree's untouched build, /work/main/.venv), in
the same run, alternating the two so both see the same machine load.

Two paths of `htm run`, each `repeats` times per build:
- "store": the default (journal, catalogue, rerun recording; the engine in 0.25 s chunks whose
  per-cycle rows and raw samples leave the core as Arrow record batches);
- "no_store": `--no-store` (one engine call; its table written to Parquet from the record batch).
cycles/s = summary.json's cycles / wall_time_s (the run itself); `process_s` the whole command;
cycles per CPU second = cycles / the command's CPU time (user + system, all threads): on a machine
shared with other jobs the wall figures carry their noise, the CPU figure much less.
Prints one JSON object: the median of each, the ratio this/peer (≥ 1 = not slower).

Run: .venv/bin/python benchmarks/typed_boundary.py [--peer /work/main/.venv/bin/htm] [--repeats 3]
"""
from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SPEC = ROOT / "examples" / "ct_constant_force.toml"


def one(htm: str, path: str, tmp: Path, k: int) -> dict[str, float]:
    out = tmp / f"{Path(htm).parts[-4] if len(Path(htm).parts) > 4 else 'x'}-{path}-{k}"
    args = [htm, "run", str(SPEC), "--mode", "full", "--out", str(out), "--quiet"]
    args += ["--no-store"] if path == "no_store" else ["--store", str(tmp / f"store-{out.name}")]
    t0, ru0 = time.perf_counter(), resource.getrusage(resource.RUSAGE_CHILDREN)
    r = subprocess.run(args, capture_output=True, text=True, timeout=900)
    process_s = time.perf_counter() - t0
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu_s = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    if r.returncode != 0:
        sys.exit(f"{' '.join(args)} failed: {r.stderr.strip()}")
    s = json.loads((out / "summary.json").read_text())
    return {"cycles": s["cycles"], "cycles_per_s": s["cycles"] / s["wall_time_s"], "process_s": process_s,
            "cycles_per_cpu_s": s["cycles"] / cpu_s}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--peer", default="/work/main/.venv/bin/htm", help="the build compared against (before)")
    ap.add_argument("--this", default=str(ROOT / ".venv" / "bin" / "htm"), help="this tree's build (after)")
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    res: dict[str, dict[str, list[dict[str, float]]]] = {p: {"this": [], "peer": []} for p in ("store", "no_store")}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for k in range(a.repeats):
            for path in ("store", "no_store"):
                for who, htm in (("peer", a.peer), ("this", a.this)) if k % 2 == 0 else (("this", a.this), ("peer", a.peer)):
                    res[path][who].append(one(htm, path, tmp, k))
    out: dict[str, object] = {"spec": "examples/ct_constant_force.toml", "mode": "full", "repeats": a.repeats,
                              "this": a.this, "peer": a.peer}
    for path, r in res.items():
        med = {who: {key: statistics.median(x[key] for x in runs) for key in ("cycles_per_s", "process_s", "cycles_per_cpu_s")} for who, runs in r.items()}
        assert {x["cycles"] for x in r["this"]} == {x["cycles"] for x in r["peer"]}, "both builds run the same test"
        out[path] = {"cycles": r["this"][0]["cycles"],
                     "this_cycles_per_s": round(med["this"]["cycles_per_s"]), "peer_cycles_per_s": round(med["peer"]["cycles_per_s"]),
                     "ratio_this_over_peer": round(med["this"]["cycles_per_s"] / med["peer"]["cycles_per_s"], 3),
                     "this_process_s": round(med["this"]["process_s"], 2), "peer_process_s": round(med["peer"]["process_s"], 2),
                     "this_cycles_per_cpu_s": round(med["this"]["cycles_per_cpu_s"]), "peer_cycles_per_cpu_s": round(med["peer"]["cycles_per_cpu_s"]),
                     "cpu_ratio_this_over_peer": round(med["this"]["cycles_per_cpu_s"] / med["peer"]["cycles_per_cpu_s"], 3),
                     "all_this_cycles_per_s": [round(x["cycles_per_s"]) for x in r["this"]],
                     "all_peer_cycles_per_s": [round(x["cycles_per_s"]) for x in r["peer"]]}
    out["target"] = "ratio_this_over_peer >= 1 within the spread of the repeats (not lower than before)"
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
