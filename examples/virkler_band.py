"""Virkler's 40 specimens: life as a distribution, checked on specimens it did not see. Four folds,
each holding out every fourth specimen (1, 5, 9, ... then 2, 6, 10, ...): Paris fits of the other
30, a Monte Carlo campaign of `--samples` simulated tests over their (log10 C, m), the 5–95 % band's
coverage of the 10 held out, and each held-out specimen's prediction updated from its own points up
to a quarter of the median life. Prints JSON (the numbers of docs/validation.md).

    python examples/virkler_band.py [--samples 400] [--out out/virkler-band]
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from htm.campaign import engine
from htm.campaign.lifeband import build, evaluate, read_data
from htm.record.store import Store

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=400)
    ap.add_argument("--early-fraction", type=float, default=0.25)
    ap.add_argument("--out", default="out/virkler-band")
    args = ap.parse_args()
    t0 = time.perf_counter()
    data = ROOT / "data" / "virkler_2024t3" / "virkler_a_vs_n_specimens_1_40.csv"
    datas = read_data(data, "a_half_crack_mm")
    out = Path(args.out)
    folds, rows = [], []
    with Store(out / "store") as store:
        for k in range(4):
            hold = {d.specimen for i, d in enumerate(datas) if i % 4 == k}
            res = build(ROOT / "examples" / "virkler_mt.toml", datas, hold, args.samples, k + 1, store,
                        engine.local_runner(), out / f"fold{k}", progress=False)
            ev = evaluate(res, [d for d in datas if d.specimen in hold], args.early_fraction)
            lo, med, hi = res["band"]
            folds.append({"held_out": sorted(hold, key=int), "band": [lo, med, hi], "covered": sum(e["in_band"] for e in ev),
                          "corr_log10_c_m": res["joint"].corr, "tests_per_s": res["run"]["tests_per_s"]})
            rows += ev
    e0 = np.abs([e["err_no_update"] for e in rows])
    e1 = np.abs([e["err_update"] for e in rows])
    lives = np.array([e["life"] for e in rows])
    print(json.dumps({
        "specimens": len(rows), "samples_per_fold": args.samples,
        "coverage_5_95": float(np.mean([e["in_band"] for e in rows])),
        "measured_life_p5_p50_p95": [float(v) for v in np.percentile(lives, [5, 50, 95])],
        "median_error_no_update_mean_abs": float(e0.mean()), "median_error_no_update_max_abs": float(e0.max()),
        "median_error_updated_mean_abs": float(e1.mean()), "median_error_updated_max_abs": float(e1.max()),
        "updated_band_coverage": float(np.mean([e["in_updated_band"] for e in rows])),
        "band_width_rel_mean": float(np.mean([(f["band"][2] - f["band"][0]) / f["band"][1] for f in folds])),
        "updated_band_width_rel_mean": float(np.mean([(e["updated"][2] - e["updated"][0]) / e["life"] for e in rows])),
        "early_points_mean": float(np.mean([e["early_points"] for e in rows])),
        "early_a_mm_mean": float(np.mean([e["early_a_mm"] for e in rows])),
        "effective_draws_mean": float(np.mean([e["effective_draws"] for e in rows])),
        "folds": folds, "runtime_s": time.perf_counter() - t0,
    }, indent=2, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
