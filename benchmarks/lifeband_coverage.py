"""`htm life-band`'s 5–95 % band on Virkler specimens it was not built on: the README's four folds
(every fourth specimen held out) and two contiguous splits (1–20 fit / 21–40 held out and the
reverse). Prints JSON: per split the band, the specimens it rests on, and how many held-out lives
fall inside (nominal 90 %).

    python benchmarks/lifeband_coverage.py [--samples 400] [--band prediction|specimens] [--out DIR]
"""
from __future__ import annotations

import argparse
import inspect
import json
import time
from pathlib import Path

from htm.campaign import engine
from htm.campaign.lifeband import build, evaluate, read_data
from htm.record.store import Store

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=400)
    ap.add_argument("--band", default="prediction", help="prediction (default) or specimens (the band before issue 33)")
    ap.add_argument("--out", default="out/lifeband-coverage")
    args = ap.parse_args()
    t0 = time.perf_counter()
    datas = read_data(ROOT / "data" / "virkler_2024t3" / "virkler_a_vs_n_specimens_1_40.csv", "a_half_crack_mm")
    ids = [d.specimen for d in datas]
    splits = {f"fold{k}": {s for i, s in enumerate(ids) if i % 4 == k} for k in range(4)}
    splits["fit_1-20_hold_21-40"] = set(ids[20:])
    splits["fit_21-40_hold_1-20"] = set(ids[:20])
    kw = {"band": args.band} if "band" in inspect.signature(build).parameters else {}
    out, res_all = Path(args.out) / args.band, {}
    with Store(out / "store") as store:
        for k, (name, hold) in enumerate(splits.items()):
            res = build(ROOT / "examples" / "virkler_mt.toml", datas, hold, args.samples, k + 1, store,
                        engine.local_runner(), out / name, progress=False, **kw)
            ev = evaluate(res, [d for d in datas if d.specimen in hold], 0.25)
            lo, med, hi = res["band"]
            res_all[name] = {"rests_on_specimens": res["joint"].n_specimens, "held_out": len(ev),
                             "covered": int(sum(e["in_band"] for e in ev)), "band_p5_p50_p95": [lo, med, hi],
                             "width_rel": (hi - lo) / med}
    folds = [v for k, v in res_all.items() if k.startswith("fold")]
    print(json.dumps({
        "band": args.band if kw else "specimens (code before issue 33)", "samples_per_split": args.samples,
        "four_folds_covered": sum(f["covered"] for f in folds), "four_folds_held_out": sum(f["held_out"] for f in folds),
        "splits": res_all, "runtime_s": time.perf_counter() - t0,
    }, indent=2, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
