"""The effect matrix (`htm.ident.proving.MATRIX`) on a seed set, judged as the test suite judges
set A (`proving.judge`): prints one JSON line per case and a JSON summary (passed, failures,
seconds). Seed sets B, C and D are the same cases on rigs and noise that no constant was adjusted
against (D drawn last and run once; see `proving.MATRIX_SEED`).

    .venv/bin/python benchmarks/diagnose_matrix.py --seed-set B
"""
from __future__ import annotations

import argparse
import json
import time

from htm.ident import proving
from htm.ident.diagnose import diagnose


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed-set", default="B", choices=sorted(proving.MATRIX_SEED))
    ap.add_argument("cases", nargs="*", help="matrix cases (default all)")
    a = ap.parse_args()
    t0 = time.perf_counter()
    results = []
    for case, _, _ in proving.MATRIX:
        if a.cases and case not in a.cases:
            continue
        t1 = time.perf_counter()
        rec, truth = proving.matrix_record(case, a.seed_set)
        try:
            report = diagnose(rec)
            problems = proving.judge(report, truth)
            found = [f"{f['effect']}/{f['channel']}" for f in report["findings"]]
            unexplained = report["unexplained"]
        except Exception as e:  # noqa: BLE001 - a crash is a failed case, reported
            problems, found, unexplained = [f"{type(e).__name__}: {e}"], [], None
        r = {"case": case, "pass": not problems, "problems": problems, "found": found, "unexplained": unexplained,
             "seconds": round(time.perf_counter() - t1, 1)}
        results.append(r)
        print(json.dumps(r), flush=True)
    print(json.dumps({"benchmark": "diagnose_matrix", "seed_set": a.seed_set, "cases": len(results),
                      "passed": sum(r["pass"] for r in results), "failures": [r["case"] for r in results if not r["pass"]],
                      "seconds": round(time.perf_counter() - t0, 1)}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
