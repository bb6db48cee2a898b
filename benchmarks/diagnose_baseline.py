"""Behaviour baseline of `htm.ident.diagnose`: diagnose a fixed set of records (the effect matrix's
seed set A and a few shared external records) and save each report's findings, parameters,
`unexplained` flag and final errors; `--compare` checks two such files against each other.

A refactor of the search that claims to preserve behaviour runs this before (with the old build)
and after (with the new one) and compares:

    /work/main/.venv/bin/python benchmarks/diagnose_baseline.py --out before.json
    .venv/bin/python benchmarks/diagnose_baseline.py --out after.json
    .venv/bin/python benchmarks/diagnose_baseline.py --compare before.json after.json

Parameters compare at a relative tolerance (`--rtol`, default 2e-3: the fit's own tolerance is far
looser than a refactor's changes of summation order); findings, channels and `unexplained` must be
identical.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

# The shared external set beside the repository (../shared of the main checkout, /work/shared).
EXTERNAL = next((p for p in (Path(__file__).resolve().parents[1].parent / "shared", Path("/work/shared"))
                 if (p / "benchmarks" / "diagnose_external" / "records").is_dir()),
                Path("/work/shared")) / "benchmarks" / "diagnose_external" / "records"
EXTERNAL_CASES = ("rec_a1", "rec_c3", "rec_e2", "rec_k2")


def summary(report: dict, seconds: float) -> dict:
    return {"findings": [{"effect": f["effect"], "channel": f["channel"], "params": f["params"]} for f in report["findings"]],
            "unexplained": report["unexplained"], "final_rmse": report["final"]["rmse"],
            "final_params": report["final"]["params"], "seconds": round(seconds, 1)}


def run(args: argparse.Namespace) -> int:
    from htm.ident import proving
    from htm.ident.diagnose import diagnose
    from htm.ident.records import read_record

    out: dict = {}
    path = Path(args.out)
    if path.exists():
        out = json.loads(path.read_text())
    todo = []
    if not args.no_matrix:
        todo += [(f"A:{case}", case) for case, _, _ in proving.MATRIX]
    external = Path(args.external)
    todo += [(f"ext:{name}", name) for name in args.external_cases]
    for key, name in todo:
        if args.only and not any(o in key for o in args.only):
            continue
        if key in out:
            continue
        t0 = time.perf_counter()
        truth = None
        if key.startswith("A:"):
            rec, truth = proving.matrix_record(name, "A")
        else:
            rec = read_record(external / f"{name}.csv.gz", external / f"{name}.json")
        report = diagnose(rec)
        out[key] = summary(report, time.perf_counter() - t0)
        if truth is not None:  # the matrix test's own judge (tests/test_diagnose_effects.py)
            out[key]["judge_problems"] = proving.judge(report, truth)
        print(key, json.dumps(out[key]["findings"]), out[key]["unexplained"], out[key]["seconds"], flush=True)
        path.write_text(json.dumps(out, indent=1) + "\n")
    return 0


def close(a, b, rtol: float) -> bool:
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(close(a[k], b[k], rtol) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(close(x, y, rtol) for x, y in zip(a, b))
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return math.isclose(a, b, rel_tol=rtol, abs_tol=1e-12)
    return a == b


def compare(before: Path, after: Path, rtol: float) -> int:
    b, a = json.loads(before.read_text()), json.loads(after.read_text())
    bad = 0
    for key in b:
        if key not in a:
            print(f"{key}: missing after")
            bad += 1
            continue
        x, y = b[key], a[key]
        same_ids = [(f["effect"], f["channel"]) for f in x["findings"]] == [(f["effect"], f["channel"]) for f in y["findings"]]
        ok = same_ids and x["unexplained"] == y["unexplained"] and close([f["params"] for f in x["findings"]],
                                                                          [f["params"] for f in y["findings"]], rtol)
        ok_rmse = close(x["final_rmse"], y["final_rmse"], rtol * 10)
        if not (ok and ok_rmse):
            bad += 1
        print(f"{'same' if ok and ok_rmse else 'DIFFERENT'}  {key}: {[(f['effect'], f['channel']) for f in x['findings']]} "
              f"unexplained={x['unexplained']}  ->  {[(f['effect'], f['channel']) for f in y['findings']]} unexplained={y['unexplained']}"
              f"{'' if ok_rmse else '  (final errors differ)'}  {x['seconds']} s -> {y['seconds']} s")
    judged = [k for k in a if "judge_problems" in a[k]]
    print(json.dumps({"cases": len(b), "different": bad, "rtol": rtol, "matrix_judged": len(judged),
                      "matrix_passed": sum(not a[k]["judge_problems"] for k in judged)}))
    return 1 if bad else 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", help="results JSON (resumed if it exists)")
    ap.add_argument("--compare", nargs=2, metavar=("BEFORE", "AFTER"))
    ap.add_argument("--rtol", type=float, default=2e-3)
    ap.add_argument("--external", default=str(EXTERNAL))
    ap.add_argument("--external-cases", nargs="*", default=list(EXTERNAL_CASES))
    ap.add_argument("--no-matrix", action="store_true")
    ap.add_argument("--only", nargs="*", help="keys containing any of these")
    a = ap.parse_args()
    if a.compare:
        return compare(Path(a.compare[0]), Path(a.compare[1]), a.rtol)
    if not a.out:
        ap.error("--out or --compare")
    return run(a)


if __name__ == "__main__":
    sys.exit(main())
