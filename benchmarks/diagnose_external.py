"""`htm diagnose` on the shared external benchmark's records (a rig simulator this project did not
write), regenerated with any seed shift, scored by its own scorer: prints one JSON line per case
and a JSON summary (STRICT and LENIENT passes, false claims, refusals, seconds).

    .venv/bin/python benchmarks/diagnose_external.py                 # the shipped seeds
    .venv/bin/python benchmarks/diagnose_external.py --shift 1000    # the same cases, other rigs and noise
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "external_rig"))

import cases as external  # noqa: E402
import score  # noqa: E402


def run(shift: int, names: list[str] | None, out: Path, htm: str, timeout: float) -> dict:
    data = out / f"shift{shift}"
    t0 = time.perf_counter()
    names = external.generate(str(data), shift, names)
    results = []
    for name in names:
        r = score.run_case(htm, name, str(data / "records"), str(data / "truth"), str(out / f"diag{shift}"), timeout=timeout)
        results.append(r)
        print(json.dumps(r), flush=True)
    n = len(results)
    summary = {
        "shift": shift,
        "cases": n,
        "strict": sum(bool(r.get("strict")) for r in results),
        "lenient": sum(bool(r.get("lenient")) for r in results),
        "false_claims": sum(bool(r.get("false_claim")) for r in results),
        "false_claims_on_clean": sum(bool(r.get("false_claim")) for r in results if r.get("class") == "clean"),
        "refused_or_failed": sum("why" in r for r in results),
        "strict_failures": [r["name"] for r in results if not r.get("strict")],
        "seconds": round(time.perf_counter() - t0, 1),
        "max_case_seconds": max((r.get("secs", 0.0) for r in results), default=0.0),
    }
    return summary


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shift", type=int, action="append", help="seed shift (repeatable; default 0, the shipped records)")
    ap.add_argument("--out", help="working folder (default: a temporary one)")
    ap.add_argument("--timeout", type=float, default=600.0, help="seconds per case")
    ap.add_argument("names", nargs="*", help="cases (default all thirteen)")
    a = ap.parse_args()
    htm = str(Path(sys.executable).with_name("htm"))
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(a.out) if a.out else Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        summaries = [run(s, a.names or None, out, htm, a.timeout) for s in (a.shift or [0])]
    print(json.dumps({"benchmark": "diagnose_external", "runs": summaries}))
    return 0


if __name__ == "__main__":
    # BLAS keeps its default threads, as under the shared scorer: the search's path (and on a
    # record near a decision, its result) depends on the last bits of its linear algebra.
    raise SystemExit(main())
