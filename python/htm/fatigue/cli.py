"""`htm e647` and `htm crack fit|predict`: E647 reduction, growth-law fitting and life prediction."""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from htm.errors import SpecError
from htm.fatigue.data import Setup, check_a_n, read_a_n
from htm.fatigue.e647 import reduce
from htm.fatigue.laws import Model, Points, fit_life, fit_rate, life_errors, load_model
from htm.fatigue.report import e647_report, plot_a_n, plot_dadn_dk, write_reduced_csv
from htm.report import md_table
from htm.terminal import add_json_flag, emit_json, grid, path, table


def _geometry_args(p: argparse.ArgumentParser, loads_required: bool = True) -> None:
    p.add_argument("--geometry", required=True, choices=["ct", "mt"], help="specimen: ct (a from load line) or mt (a = half crack length)")
    p.add_argument("--width-m", type=float, required=True, help="specimen width W [m]")
    p.add_argument("--thickness-m", type=float, required=True, help="specimen thickness B [m]")
    g = p.add_mutually_exclusive_group(required=loads_required)
    g.add_argument("--delta-p-n", type=float, help="force range ΔP [N] (E647: Pmax − Pmin for R ≥ 0)")
    g.add_argument("--pmax-n", type=float, help="maximum force Pmax [N]")
    p.add_argument("--r-ratio", type=float, required=loads_required, help="stress ratio R = Pmin/Pmax")
    p.add_argument("--yield-strength-pa", type=float, help="σ_ys [Pa]; enables the E647 size criterion")


def _setup(args: argparse.Namespace) -> Setup:
    for name in ("delta_p_n", "pmax_n"):
        v = getattr(args, name, None)
        if v is not None and v <= 0:
            raise SpecError(f"--{name.replace('_', '-')} = {v} N: loads must be positive (tension-positive force range or maximum)")
    if args.r_ratio is None:
        raise SpecError("--r-ratio is required with the loads")
    return Setup.from_loads(args.geometry, args.width_m, args.thickness_m, r_ratio=args.r_ratio,
                            delta_p_n=args.delta_p_n, pmax_n=args.pmax_n, yield_strength_pa=args.yield_strength_pa)


def _read(path: str, setup: Setup):
    datas = read_a_n(path)
    for d in datas:
        check_a_n(d, setup, source=str(path))
    return datas


def cmd_e647(args: argparse.Namespace) -> int:
    setup = _setup(args)
    datas = _read(args.input, setup)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    kw = {}
    if args.cycles_resolution is not None or args.a_resolution_m is not None:
        if args.cycles_resolution is None or args.a_resolution_m is None:
            raise SpecError("give both --cycles-resolution and --a-resolution-m (errors-in-variables fit) or neither")
        kw = {"cycles_resolution": args.cycles_resolution, "a_resolution_m": args.a_resolution_m}
    reds = [reduce(d, setup, method=args.method, n=args.n, **kw) for d in datas]
    multi = len(datas) > 1 or any(d.specimen != "1" for d in datas)
    write_reduced_csv(out / "reduced.csv", reds, multi)
    rep = e647_report(out, datas, setup, reds, args.n, source=args.input)
    nvalid = sum(int(r.valid.sum()) for r in reds)
    npts = sum(len(r) for r in reds)
    if args.json:
        emit_json({"points": npts, "valid_points": nvalid, "specimens": [d.specimen for d in datas],
                   "outputs": [str(out / "reduced.csv"), str(rep)]})
        return 0
    print(f"reduced {npts:,} points ({nvalid:,} valid) from {len(datas)} specimen(s)")
    print(f"wrote {path(out / 'reduced.csv')}, {path(rep)}")
    return 0


def _fit_one(law: str, pts: Points, datas, setup: Setup, w: int) -> tuple[Model, Model]:
    rate = fit_rate(law, pts, setup.r_ratio, window_points=w)
    life = fit_life(law, datas, setup, rate)
    return rate, life


def cmd_crack_fit(args: argparse.Namespace) -> int:
    setup = _setup(args)
    datas = _read(args.input, setup)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    reds = [reduce(d, setup, n=args.n) for d in datas]
    pts = Points.from_reduced(reds)
    w = 2 * args.n + 1
    diagnosis = None
    if args.law == "auto":
        from htm.fatigue.loop import candidates_for, diagnose

        paris = fit_rate("paris", pts, setup.r_ratio, window_points=w)
        diagnosis = diagnose(paris, pts, setup, w)
        best = paris
        for _, free, fixed in candidates_for(diagnosis["missing_terms"]):
            m = fit_rate("nasgro", pts, setup.r_ratio, free=free, fixed=fixed, window_points=w)
            if m.fit["bic"] < best.fit["bic"] - 10:
                best = m
        rate = best
        life = fit_life(rate.law, datas, setup, rate)
    else:
        rate, life = _fit_one(args.law, pts, datas, setup, w)
    chosen = life if args.fit_by == "life" else rate
    other = rate if args.fit_by == "life" else life
    errs = [life_errors(chosen, d, setup) for d in datas]
    from htm.fatigue.laws import rms_log_rate

    model = chosen.to_dict()
    model["fit"] = {
        "method": args.fit_by, "specimens": [d.specimen for d in datas], "rate_points": len(pts),
        "rms_log10_rate": rms_log_rate(chosen, pts, setup.r_ratio),
        "life_rms_rel": float(np.sqrt(np.mean([e["rms_rel"] ** 2 for e in errs]))),
        "life_final_rel": [e["final_rel"] for e in errs],
        "other_method": {"method": "rate" if args.fit_by == "life" else "life", "parameters": other.to_dict()["parameters"],
                         "rms_log10_rate": rms_log_rate(other, pts, setup.r_ratio)},
    }
    if diagnosis is not None:
        model["fit"]["auto"] = {"missing_terms": diagnosis["missing_terms"],
                                "f_statistic": diagnosis["delta_k"]["f_statistic"]}
    model["setup"] = setup.to_dict()
    (out / "model.json").write_text(json.dumps(model, indent=2, default=float))
    a_n = plot_a_n(out / "a_n.png", datas, model=chosen, setup=setup)
    dadn = plot_dadn_dk(out / "dadn_dk.png", reds, {f"{chosen.law} ({args.fit_by} fit)": chosen}, setup.r_ratio)
    prow = [[k, f"{v['value']:.6g}", "" if v["stderr"] is None else f"{v['stderr']:.3g}", v["unit"], "yes" if v["fitted"] else "fixed"]
            for k, v in model["parameters"].items()]
    lines = [f"# Crack-growth fit: {chosen.law}", "", f"Input `{args.input}`, {len(datas)} specimen(s), "
             f"{len(pts)} da/dN points (incremental polynomial n = {args.n}); parameters fitted by {args.fit_by}.", "",
             md_table(["parameter", "value", "std. error", "unit", "status"], prow), "",
             f"RMS log10 da/dN error: {model['fit']['rms_log10_rate']:.4f}; RMS life error (relative to each span, "
             f"integrated from the first point): {100 * model['fit']['life_rms_rel']:.3f} %.", "",
             f"![a-N]({a_n.name})", "", f"![da/dN-dK]({dadn.name})", ""]
    (out / "report.md").write_text("\n".join(lines))
    if args.json:
        emit_json(dict(model, outputs=[str(out / "model.json"), str(out / "report.md")]))
        return 0
    print(f"{chosen.law} law fitted by {args.fit_by} to {len(datas)} specimen(s), {len(pts):,} da/dN points:")
    print(grid(["parameter", "value", "± std. error", "unit", ""],
               [[k, f"{v['value']:.5g}", "" if v["stderr"] is None else f"± {v['stderr']:.2g}", v["unit"],
                 "" if v["fitted"] else "(fixed)"] for k, v in model["parameters"].items()],
               right=[False, True, True, False, False], indent="  "))
    print(table([("RMS log10 da/dN error", f"{model['fit']['rms_log10_rate']:.4f}"),
                 ("RMS life error", f"{100 * model['fit']['life_rms_rel']:.3f} % (of each specimen's span)")]))
    print(f"wrote {path(out / 'model.json')}, {path(out / 'report.md')}")
    return 0


def cmd_crack_predict(args: argparse.Namespace) -> int:
    model = load_model(args.model)
    setup = _setup(args)
    amax = setup.a_geometry_max_m
    where = "W" if setup.geometry == "ct" else "W/2"
    for name, v in (("--a0-m", args.a0_m), ("--af-m", args.af_m)):
        if not (math.isfinite(v) and v > 0):
            raise SpecError(f"{name} = {v}: a crack size must be a positive number of metres")
        if v >= amax:
            hint = f"; if you meant {v:g} mm, give {v * 1e-3:g}" if v > 2.0 and v * 1e-3 < amax else ""
            raise SpecError(f"{name} = {v:g} m ({v * 1e3:g} mm) is not inside the {setup.geometry.upper()} specimen: "
                            f"a crack must be shorter than {where} = {amax * 1e3:g} mm{hint}")
    if args.af_m <= args.a0_m:
        raise SpecError(f"--af-m = {args.af_m:g} m must exceed --a0-m = {args.a0_m:g} m (the crack grows from a0 to af)")
    life = model.life(setup, args.a0_m, args.af_m)
    res = {"law": model.law, "cycles": life["cycles"], "a0_m": args.a0_m, "af_m": args.af_m,
           "a_end_m": life["a_end_m"], "fractured": life["fractured"]}
    if not math.isfinite(res["cycles"]):
        raise SpecError("the predicted life is not finite")
    if args.json:
        emit_json(res)
        return 0
    print(f"{model.law} law of {path(args.model)}, {setup.geometry.upper()} W = {setup.width_m * 1e3:g} mm, "
          f"B = {setup.thickness_m * 1e3:g} mm, ΔP = {setup.delta_p_n / 1e3:.4g} kN, R = {setup.r_ratio:g}:")
    print(table([("life", f"{res['cycles']:,.0f} cycles"),
                 ("crack", f"{args.a0_m * 1e3:.3f} → {res['a_end_m'] * 1e3:.3f} mm"
                           + (" (fractured before af)" if res["fractured"] else ""))], indent="  "))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    e = sub.add_parser("e647", help="ASTM E647 reduction of a–N data: da/dN, ΔK, Kmax, validity",
                       description="Reduce a–N data per ASTM E647 (incremental polynomial or secant) and write "
                                   "DIR/reduced.csv, DIR/report.md and plots. INPUT.csv has columns `cycles` and `a_m` "
                                   "(or `a_mm`, millimetres), optionally `specimen`.")
    e.add_argument("input", metavar="INPUT.csv")
    _geometry_args(e)
    e.add_argument("--n", type=int, default=3, help="incremental polynomial half-width: 2n+1 points (default 3)")
    e.add_argument("--method", choices=["polynomial", "secant"], default="polynomial", help="da/dN method (default polynomial)")
    e.add_argument("--cycles-resolution", type=float, help="quantisation step of recorded N (enables the errors-in-variables fit)")
    e.add_argument("--a-resolution-m", type=float, help="quantisation step of recorded a [m]")
    e.add_argument("--out", required=True, help="output directory")
    add_json_flag(e)
    e.set_defaults(func=cmd_e647)

    c = sub.add_parser("crack", help="fit crack-growth laws to a–N data; predict life",
                       description="Crack-growth laws (Paris, Forman, NASGRO) fitted to measured a–N data, and life prediction.")
    csub = c.add_subparsers(dest="crack_command", required=True, metavar="ACTION")
    f = csub.add_parser("fit", help="fit a growth law to a–N data and write DIR/model.json and a report",
                        description="Fit a growth law in log-rate space and by life; write DIR/model.json (law, "
                                    "parameters with uncertainty, fit errors) and DIR/report.md. INPUT.csv: `cycles`, "
                                    "`a_m` (or `a_mm`), optional `specimen` (pooled fit over specimens).")
    f.add_argument("input", metavar="INPUT.csv")
    _geometry_args(f)
    f.add_argument("--law", choices=["paris", "forman", "nasgro", "auto"], default="paris",
                   help="law; auto = Paris, then add the terms its residual shows missing (default paris)")
    f.add_argument("--fit-by", choices=["rate", "life"], default="rate", help="parameters in model.json from the log-rate or the life fit (default rate)")
    f.add_argument("--n", type=int, default=3, help="incremental polynomial half-width (default 3)")
    f.add_argument("--out", required=True, help="output directory")
    add_json_flag(f)
    f.set_defaults(func=cmd_crack_fit)

    p = csub.add_parser("predict", help="cycles to grow a crack from a0 to af with a fitted model",
                        description="Integrate MODEL.json's law from a0 to af under constant amplitude; print the life "
                                    "(with --json: JSON with `cycles`, SI).")
    p.add_argument("model", metavar="MODEL.json")
    _geometry_args(p)
    p.add_argument("--a0-m", type=float, required=True, help="initial crack size [m]")
    p.add_argument("--af-m", type=float, required=True, help="final crack size [m]")
    add_json_flag(p)
    p.set_defaults(func=cmd_crack_predict)
    register_measure(csub)


# ---- `htm crack measure`: crack size and closure from a raw record (htm.fatigue.measure) -------
def cmd_crack_measure(args: argparse.Namespace) -> int:
    from htm.fatigue.measure import measure, read_table, write_a_n

    if args.cycles_per_interval is not None and args.cycles_per_interval < 1:
        raise SpecError(f"--cycles-per-interval = {args.cycles_per_interval}: give at least 1 cycle")
    columns, meta = read_table(args.record, args.meta)
    m = measure(columns, meta, method=args.method, cycles_per_interval=args.cycles_per_interval, name=Path(args.record).name)
    path = write_a_n(m, Path(args.out))
    c = m.columns
    a = c["a_m"]
    un = m.opening_not_resolved()
    if args.json:
        op = c["opening_force_n"]
        emit_json({"method": m.method, "expression": m.expression, "rows": len(m), "resolution_m": m.resolution_m,
                   "cycles": [int(c["cycles"][0]), int(c["cycles"][-1])], "a_m": [float(a[0]), float(a[-1])],
                   "opening_force_n": [float(np.nanmin(op)), float(np.nanmax(op))] if np.isfinite(op).any() else None,
                   "opening_force_not_resolved_rows": None if un is None else int(un.sum()),
                   "outputs": [str(path), str(path.parent / "measure.json")]})
        return 0
    print(f"crack size from {m.method.replace('_', ' ')}: {m.expression}")
    print(f"{len(m)} rows, cycles {int(c['cycles'][0]):,}..{int(c['cycles'][-1]):,}, a {a[0] * 1e3:.3f} → {a[-1] * 1e3:.3f} mm "
          f"(resolution {m.resolution_m * 1e3:.3f} mm)")
    op = c["opening_force_n"]
    if np.isfinite(op).any():
        print(f"opening force (2 % compliance offset, E647 X2): {np.nanmin(op):.0f}..{np.nanmax(op):.0f} N "
              f"= {100 * np.nanmin(op / c['fmax_n']):.1f}..{100 * np.nanmax(op / c['fmax_n']):.1f} % of Fmax")
    if un is not None and un.any():
        print(f"opening force not resolved on {int(un.sum())} of {len(m)} rows: the gauge's noise hides the closure "
              f"(offset noise {np.nanmin(c['offset_noise'][un]):.3f}..{np.nanmax(c['offset_noise'][un]):.3f}); "
              "left empty, ΔK_eff not claimed")
    print(f"wrote {path}, {path.parent / 'measure.json'}")
    return 0


def register_measure(csub: argparse._SubParsersAction) -> None:
    m = csub.add_parser("measure", help="crack size and opening force from a load–opening or potential-drop record",
                        description="Reduce a raw record (DATA_FORMAT.md: `cycle` with `cod` + `f` from a clip gauge, or "
                                    "`dcpd_v`) to DIR/a_n.csv (`cycles`, `a_m`, `opening_force_n`, one row per burst or "
                                    "interval) and DIR/measure.json naming the expression used. The specimen entry of the "
                                    "metadata gives the constants (geometry, width_m, thickness_m; youngs_modulus_pa and "
                                    "cod_at / cod_y_m for compliance; dcpd_probe_y_m, dcpd_a_ref_m, dcpd_v_ref or "
                                    "dcpd_calibration for potential drop). `htm e647 DIR/a_n.csv` reduces the result.")
    m.add_argument("record", metavar="RECORD")
    m.add_argument("--meta", help="metadata JSON (default RECORD's .json beside it)")
    m.add_argument("--method", choices=["auto", "compliance", "potential_drop"], default="auto",
                   help="auto: compliance when the record has `cod`, else potential drop")
    m.add_argument("--cycles-per-interval", type=int,
                   help="cycles pooled per row (default: one row per burst; 10 for a continuous record)")
    m.add_argument("--out", required=True, help="output directory")
    add_json_flag(m)
    m.set_defaults(func=cmd_crack_measure)
