"""What each internal-leak verdict took of the held-out error where the actuator stands still
(`SearchSettings.still_share`), read from the decision traces of `htm diagnose` reports, beside the
record's truth: the measurement behind the standstill rule (docs/validation.md, "What still goes
wrong").

Diagnose a set of records with a scorer that keeps the reports, e.g.

    SCORE_OUT=OUT/q4 .venv/bin/python benchmarks/external_rig/score.py .venv/bin/htm \
        --data DIR/records --truth DIR/truth

then, for each kept set, its report folder and the truth folder beside its records:

    .venv/bin/python benchmarks/leak_standstill.py OUT/q4=DIR/truth [OUT/l1=DIR1/truth ...]

Prints one JSON line per leak verdict that reached the standstill test (set, record, round,
stage, outcome, share taken at rest, samples, whether the truth holds a leak), then a summary:
the range of the share taken by verdicts that paid off, for records with and without a true leak.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path


def truth_effects(truth_dir: Path, name: str) -> list[str]:
    """The truth's effect ids of record `name` (the scorer's truth layout: `effect` or `effects`)."""
    path = truth_dir / f"{name}.json"
    if not path.is_file():
        return []
    t = json.loads(path.read_text())
    effects = t.get("effects") or [t.get("effect")]
    return [e if isinstance(e, str) else (e or {}).get("effect", "") for e in effects if e]


def verdicts(out_dir: Path, truth_dir: Path) -> list[dict]:
    rows = []
    for report in sorted(out_dir.glob("*/report.json")):
        r = json.loads(report.read_text())
        name = report.parent.name
        leak = any("internal_leakage" in e for e in truth_effects(truth_dir, name))
        for e in r.get("trace", []):
            at = (e.get("numbers") or {}).get("at_standstill") if isinstance(e.get("numbers"), dict) else None
            if e.get("candidate") != "internal_leakage" or not at or "taken" not in at:
                continue
            rows.append({"set": out_dir.name, "record": name, "round": e.get("round"), "stage": e.get("stage"),
                         "pays_off": (e.get("rule") or "").startswith("pays off"),
                         "fails_only_standstill": e.get("rule") == "fails: takes the error at standstill",
                         "taken": round(float(at["taken"]), 3), "samples": at["samples"], "true_leak": leak})
    return rows


def main(argv: list[str]) -> int:
    if not argv or any("=" not in a for a in argv):
        print("usage: leak_standstill.py REPORTS_DIR=TRUTH_DIR ...", file=sys.stderr)
        return 2
    rows = []
    for arg in argv:
        out, truth = (Path(p) for p in arg.split("=", 1))
        if not out.is_dir() or not truth.is_dir():
            print(f"leak_standstill: not a folder: {out if not out.is_dir() else truth}", file=sys.stderr)
            return 2
        rows += verdicts(out, truth)
    for row in rows:
        print(json.dumps(row))
    summary: dict[str, object] = {"benchmark": "leak_standstill", "verdicts": len(rows)}
    for leak, key in ((True, "true_leak"), (False, "no_leak")):
        # a verdict that would pay off but for this rule counts with those that paid off
        taken = [r["taken"] for r in rows if r["true_leak"] is leak and (r["pays_off"] or r["fails_only_standstill"])]
        summary[f"{key}_taken_when_otherwise_paying"] = [min(taken), max(taken)] if taken else None
        summary[f"{key}_count"] = len(taken)
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
