"""`htm diagnose` on specimen and load-train records (`displacement_input`): the specimen effect
matrix (`specimen_proving.SPECIMEN_MATRIX`) on seed sets A (built against), B and C (run once,
afterwards) and D (run once, last), and the same cases at 500 Hz and 2 kHz on other specimens
and histories, judged as the tests judge set A; `htm predict` of a second record of the same
specimen (RMS force error against the noise the force carries); and the real ARTS friction-damper
records (data/arts_friction_damper, CC BY-SA 4.0, or --arts DIR): what each diagnosis finds, the
force error before and after, and each model predicting the other two records. One JSON line per
item and a JSON summary.

    .venv/bin/python benchmarks/diagnose_specimen.py
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from htm.ident.diagnose import diagnose
from htm.ident.predict import predict, read_model
from htm.ident.records import read_record
from htm.ident.specimen_proving import NOISE_STD, QUANTUM, SPECIMEN_MATRIX, judge, make_specimen_record, specimen_matrix_record

ARTS = Path(__file__).resolve().parent.parent / "data" / "arts_friction_damper"
ARTS_RECORDS = ("arts_30lb_0p5hz_1in", "arts_30lb_1hz_0p5in", "arts_30lb_0p25hz_1p5in")
PREDICT_EFFECTS = {"specimen_friction": {}, "load_train_backlash": {}, "specimen_nonlinearity": {}}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed-sets", default="A,B,C")
    ap.add_argument("--arts", default=str(ARTS))
    a = ap.parse_args()
    t0 = time.perf_counter()
    tmp = Path(tempfile.mkdtemp(prefix="htm-specimen-bench-"))
    summary: dict = {"benchmark": "diagnose_specimen", "matrix": {}}
    for s in a.seed_sets.split(","):
        passed, failures = 0, []
        for case, _, _ in SPECIMEN_MATRIX:
            t1 = time.perf_counter()
            rec, truth = specimen_matrix_record(case, s)
            report = diagnose(rec)
            problems = judge(report, truth)
            passed += not problems
            if problems:
                failures.append(case)
            print(json.dumps({"case": case, "seed_set": s, "pass": not problems, "problems": problems,
                              "found": {f["effect"]: f["params"] for f in report["findings"]},
                              "truth": {e: t["params"] for e, t in truth["effects"].items()},
                              "final_params": report["final"]["params"], "rmse_f_n": report["final"]["rmse"]["f"],
                              "unexplained": report["unexplained"], "seconds": round(time.perf_counter() - t1, 2)}), flush=True)
        summary["matrix"][s] = {"cases": len(SPECIMEN_MATRIX), "passed": passed, "failures": failures}
    # the same cases at other sample rates, on other specimens and displacement histories
    for rate in (500, 2000):
        passed, failures = 0, []
        for j in range(5):
            for i, (case, effects, kw) in enumerate(SPECIMEN_MATRIX):
                rec, truth = make_specimen_record(effects, seed=30000 + 100 * j + i, rate_hz=rate, variant=j % 3, **kw)
                problems = judge(diagnose(rec), truth)
                passed += not problems
                if problems:
                    failures.append(f"{case} (seed {30000 + 100 * j + i})")
                    print(json.dumps({"case": case, "rate_hz": rate, "seed": 30000 + 100 * j + i, "problems": problems}), flush=True)
        summary[f"rate_{rate}_hz"] = {"cases": 5 * len(SPECIMEN_MATRIX), "passed": passed, "failures": failures}
    # a second record of the same specimen: another displacement history, other noise
    preds = []
    for seed in (77, 78, 79):
        rec0, truth = make_specimen_record(PREDICT_EFFECTS, seed=seed, variant=0)
        rec1, _ = make_specimen_record(PREDICT_EFFECTS, seed=seed, variant=1)
        report, model = _diagnosed(rec0, tmp / f"seed{seed}")
        out = predict(model, rec1)
        k = truth["params"]["specimen_stiffness_n_m"]
        noise = float(np.sqrt(NOISE_STD["f"] ** 2 + QUANTUM["f"] ** 2 / 12 + (k * NOISE_STD["y"]) ** 2))
        line = {"predict": f"seed {seed}: variant 0 -> variant 1", "findings": [f["effect"] for f in report["findings"]],
                "rmse_f_n": round(out["rmse"]["f"], 3), "noise_f_n": round(noise, 3),
                "ratio": round(out["rmse"]["f"] / noise, 3)}
        preds.append(line)
        print(json.dumps(line), flush=True)
    summary["predict_rmse_over_noise"] = [p["ratio"] for p in preds]
    arts = Path(a.arts)
    if arts.is_dir():
        models = {}
        summary["arts"] = {}
        for name in ARTS_RECORDS:
            t1 = time.perf_counter()
            rec = read_record(arts / f"{name}.csv.gz")
            report, model = _diagnosed(rec, tmp / name)
            models[name] = (model, rec)
            line = {"arts": name, "findings": {f["effect"]: f["params"] for f in report["findings"]},
                    "rmse_f_before_n": round(report["baseline"]["rmse"]["f"], 1),
                    "rmse_f_after_n": round(report["final"]["rmse"]["f"], 1),
                    "f_std_n": round(float(np.nanstd(rec.columns["f"])), 1),
                    "unexplained": report["unexplained"], "final_params": report["final"]["params"],
                    "seconds": round(time.perf_counter() - t1, 2)}
            summary["arts"][name] = {k: line[k] for k in ("findings", "rmse_f_before_n", "rmse_f_after_n", "unexplained")}
            print(json.dumps(line), flush=True)
        for name, (model, _) in models.items():
            for other, (_, rec) in models.items():
                if other != name:
                    print(json.dumps({"arts_predict": f"{name} -> {other}",
                                      "rmse_f_n": round(predict(model, rec)["rmse"]["f"], 1)}), flush=True)
    summary["seconds"] = round(time.perf_counter() - t0, 1)
    print(json.dumps(summary))
    return 0


def _diagnosed(rec, out: Path):
    """The diagnosis of `rec` written to `out`, and its model.json as `htm predict` reads it."""
    report = diagnose(rec, out_dir=out)
    return report, read_model(out / "model.json")


if __name__ == "__main__":
    raise SystemExit(main())
