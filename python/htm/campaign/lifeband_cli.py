"""`htm life-band SPEC.toml --data A_N.csv`: life as a distribution from a specimen set's scatter,
by a Monte Carlo campaign; held-out specimens' coverage; a running specimen's early-data update."""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from htm.terminal import add_json_flag, emit_json, path


def cmd_life_band(args: argparse.Namespace) -> int:
    from htm.campaign import engine, lifeband
    from htm.record.store import Store

    datas = lifeband.read_data(args.data, args.a_mm_column)
    hold = {s.strip() for s in (args.hold_out or "").split(",") if s.strip()}
    out = Path(args.out)
    early = None
    if args.early:
        early = lifeband.read_data(args.early, args.a_mm_column)[0]
    with Store(args.store) as store:
        if args.cluster:
            from htm.campaign import cluster

            client = cluster.connect(args.cluster)
            runner = cluster.runner(client)
        else:
            client, runner = None, engine.local_runner()
        try:
            res = lifeband.build(Path(args.spec), datas, hold, args.samples, args.seed, store, runner, out, not args.quiet,
                                 band=args.band)
        finally:
            if client is not None:
                client.close()
    say = (lambda *a, **k: None) if args.json else print
    j = res["joint"]
    lo, med, hi = res["band"]
    summary: dict[str, Any] = {
        "specimens_fitted": j.n_specimens, "log10_c_si_mean": j.mean[0], "m_mean": j.mean[1],
        "log10_c_sd": float(np.sqrt(j.cov[0, 0])), "m_sd": float(np.sqrt(j.cov[1, 1])), "corr_log10_c_m": j.corr,
        "point_sigma_cycles": j.point_sigma_cycles, "draws": len(res["life"]),
        "draws_not_reaching_af": res["tests_not_reaching_af"],
        "life_median": med, "life_p5": lo, "life_p95": hi, "campaign": res["campaign"],
        "band": res["band_kind"], "rests_on_specimens": j.n_specimens, "effective_draws": res["effective_draws"],
        "band_note": (f"5-95 % prediction band for a new specimen (bivariate t, {j.dof} degrees of freedom: the "
                      f"fit's uncertainty across {j.n_specimens} specimens included)" if res["band_kind"] == "prediction"
                      else f"5-95 % of the {j.n_specimens} fitted specimens' normal taken as known (no fit uncertainty)"),
    }
    say(f"{j.n_specimens} specimens fitted (Paris by life): log10 C = {j.mean[0]:.3f} ± {np.sqrt(j.cov[0, 0]):.3f} (SI), "
          f"m = {j.mean[1]:.3f} ± {np.sqrt(j.cov[1, 1]):.3f}, correlation {j.corr:+.3f}")
    kind = (f"prediction band for a new specimen, resting on {j.n_specimens} specimens ({res['effective_draws']:.0f} "
            f"effective draws)" if res["band_kind"] == "prediction" else f"band of the {j.n_specimens} fitted specimens")
    say(f"life a0 {res['a0_m'] * 1e3:.2f} → {res['af_m'] * 1e3:.2f} mm over {len(res['life'])} simulated tests: "
        f"median {med:,.0f} cycles, 5–95 % {lo:,.0f} .. {hi:,.0f} ({kind})")
    held = [d for d in datas if d.specimen in hold]
    if held:
        ev = lifeband.evaluate(res, held, args.early_fraction)
        cov = float(np.mean([e["in_band"] for e in ev]))
        e0 = np.array([e["err_no_update"] for e in ev])
        e1 = np.array([e["err_update"] for e in ev])
        say(f"held-out specimens: {sum(e['in_band'] for e in ev)}/{len(ev)} inside the 5–95 % band ({100 * cov:.0f} %)")
        say(f"median life error, held-out: no update mean |e| {100 * np.mean(np.abs(e0)):.2f} % (max {100 * np.max(np.abs(e0)):.2f} %); "
              f"updated from points up to {100 * args.early_fraction:.0f} % of the median life: mean |e| "
              f"{100 * np.mean(np.abs(e1)):.2f} % (max {100 * np.max(np.abs(e1)):.2f} %), "
              f"{sum(e['in_updated_band'] for e in ev)}/{len(ev)} inside their updated band")
        summary.update({"held_out": len(ev), "coverage_5_95": cov, "mean_abs_err_no_update": float(np.mean(np.abs(e0))),
                        "mean_abs_err_update": float(np.mean(np.abs(e1))), "max_abs_err_no_update": float(np.max(np.abs(e0))),
                        "max_abs_err_update": float(np.max(np.abs(e1))),
                        "updated_band_coverage": float(np.mean([e["in_updated_band"] for e in ev])),
                        "mean_updated_band_width_rel": float(np.mean([(e["updated"][2] - e["updated"][0]) / e["life"] for e in ev])),
                        "band_width_rel": float((hi - lo) / med), "specimens": ev})
    if early is not None:
        u = lifeband.update(res, early)
        say(f"updated from {args.early}'s {u['points']} points (to a = {early.a_m[-1] * 1e3:.2f} mm at "
              f"{early.cycles[-1]:,.0f} cycles): median {u['median']:,.0f} cycles, 5–95 % {u['p5']:,.0f} .. {u['p95']:,.0f} "
              f"({u['effective_draws']:.0f} effective draws)")
        summary["early_update"] = {k: u[k] for k in ("median", "p5", "p95", "points")}
    (out / "life_band.json").write_text(json.dumps(summary, indent=2, default=float))
    if args.json:
        emit_json(dict(summary, outputs=[str(out / "life_band.json"), str(out / "campaign.toml")]))
        return 0
    say(f"outputs: {path(out / 'life_band.json')}, {path(out / 'campaign.toml')}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("life-band", help="crack-growth life as a distribution over a specimen set's scatter (Monte Carlo campaign)",
                       description="Fit a Paris law to every specimen of an a–N data set, take the joint normal of "
                                   "(log10 C, m), run the base spec's test as a Monte Carlo campaign over it on the "
                                   "simulated rig, and report the life's median and 5–95 % band; with --hold-out, how "
                                   "well the band covers specimens it did not see and how their own first points "
                                   "narrow their prediction; with --early, that update for a running test.")
    p.add_argument("spec", help="the test spec (TOML) of the set's test: specimen, material, constant-force loading, a0 and end")
    p.add_argument("--data", required=True, help="a–N CSV of the specimen set (cycles, a_m or a_mm, specimen)")
    p.add_argument("--a-mm-column", help="the column holding a in mm when not named a_mm (e.g. a_half_crack_mm)")
    p.add_argument("--hold-out", metavar="IDS", help="specimens left out of the fit and checked against the band (comma-separated)")
    p.add_argument("--early", metavar="CSV", help="a running test's a–N so far: its prediction updated from these points")
    p.add_argument("--early-fraction", type=float, default=0.25,
                   help="held-out specimens: their points up to this fraction of the median life drive the update (default 0.25)")
    p.add_argument("--samples", type=int, default=400, help="Monte Carlo draws (simulated tests; default 400)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--band", choices=["prediction", "specimens"], default="prediction",
                   help="prediction: for a new specimen, the fit's uncertainty included (default); specimens: the "
                        "fitted specimens' spread taken as known (narrower, the band before issue 33)")
    p.add_argument("--cluster", metavar="tcp://HOST:PORT", help="run the campaign on this Dask scheduler's workers")
    p.add_argument("--store", help="test store (folder or postgresql://...), as for `htm campaign`")
    p.add_argument("--out", default="out/life-band", help="folder for campaign.toml and life_band.json (default out/life-band)")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    add_json_flag(p)
    p.set_defaults(func=cmd_life_band)
