"""The identification commands: `htm identify` (the thesis's chapter-3 identification),
`htm diagnose` (the model fit and effect search) and `htm predict` (an identified model on
another record of the same rig)."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Callable

import numpy as np

from htm.ident.records import read_record
from htm.terminal import add_json_flag, emit_json, label, path, si, table


def cmd_identify(args: argparse.Namespace) -> int:
    # the classic identification (scipy.optimize, scipy.ndimage) is imported by its own command only
    from htm.ident.classic import identify

    rec = read_record(args.record, args.meta)
    result = identify(rec)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "identification.json").write_text(json.dumps(result, indent=2) + "\n")
    lines = [f"# Identification of `{rec.name}`", "", f"{result['segments']} constant-velocity segments.", ""]
    vg = result["velocity_gain"]
    lines += [f"Velocity gain {vg['gain_m_s_per_v'] * 1e3:.2f} mm/s per V, hydraulic null at {vg['null_command_v']:+.3f} V (R² {vg['r2']:.4f}).", ""]
    if "friction" in result:
        lines += ["| model | method | parameters | R² |", "|---|---|---|---|"]
        for name, fit in result["friction"].items():
            ps = ", ".join(f"{k} = {v:.4g}" for k, v in fit["params"].items())
            lines.append(f"| {name} | {fit['method']} | {ps} | {fit['r2']:.6f} |")
        off = result["offset"]
        lines += ["", f"Offset term (eq. 3.16): {off['offset_n']:.1f} N = {off['as_chamber_a_pressure_pa'] / 1e5:.2f} bar on chamber A; "
                      f"R² {off['r2_without']:.4f} without it, {off['r2_with']:.6f} with it. A large offset that the fit needs "
                      "points to a pressure-transducer offset or a wrong nominal mass (the thesis found 4 bar on p_a).",
                  "", f"Moving mass from acceleration: {result['mass']['moving_mass_kg']:.2f} kg (R² {result['mass']['r2']:.3f}, "
                      f"{result['mass']['samples']} samples).", "", "![friction](friction.png)"]
        _plot(result, out / "friction.png")
    (out / "report.md").write_text("\n".join(lines) + "\n")
    notes = list(result["warnings"])
    if "friction" not in result:
        have = [c for c in ("p_a", "p_b") if c in rec.columns]
        notes.append("friction, offset and moving mass not identified: " +
                     (f"the record has no pressure column ({', '.join(c for c in ('p_a', 'p_b') if c not in have)} missing)"
                      if len(have) < 2 else "no constant-velocity segment with finite pressures"))
    warn("identify", notes)
    if args.json:
        emit_json({k: v for k, v in result.items() if k != "points"} | {"outputs": [str(out / "identification.json"), str(out / "report.md")]})
        return 0
    print(f"identified {rec.name}: {result['segments']} constant-velocity segments")
    rows = [("velocity gain", f"{vg['gain_m_s_per_v'] * 1e3:.2f} mm/s per V, null at {vg['null_command_v']:+.3f} V (R² {vg['r2']:.4f})")]
    if "friction" in result:
        fit = result["friction"]["stribeck_sig"]
        rows += [("friction (Stribeck)", ", ".join(f"{label(k)} {si(k, v)}" for k, v in fit["params"].items()) + f" (R² {fit['r2']:.4f})"),
                 ("offset", f"{result['offset']['offset_n'] / 1e3:.3f} kN = {result['offset']['as_chamber_a_pressure_pa'] / 1e5:.2f} bar on chamber A"),
                 ("moving mass", f"{result['mass']['moving_mass_kg']:.2f} kg (R² {result['mass']['r2']:.3f})")]
    print(table(rows, indent="  "))
    print(f"wrote {path(out / 'identification.json')}, {path(out / 'report.md')}")
    return 0


def warn(command: str, notes: list[str]) -> None:
    """What a record made htm drop or leave out, on stderr (not only in the report)."""
    for n in notes:
        print(f"htm {command}: warning: {n}", file=sys.stderr)


def _plot(result: dict, path: Path) -> None:
    from htm.ident.classic import SMOOTHING_M_S, stribeck_basis
    from htm.report import pyplot, save

    v = np.array(result["points"]["v_m_s"])
    f = np.array(result["points"]["f_n"])
    fit = result["friction"]["stribeck_sig"]["params"]
    vv = np.linspace(v.min(), v.max(), 400)
    model = stribeck_basis(vv, fit["stribeck_m_s"], SMOOTHING_M_S) @ [fit["viscous_n_s_m"], fit["coulomb_n"], fit["static_n"]]
    fig, ax = pyplot().subplots(figsize=(6, 4))
    ax.plot(v * 1e3, f, "o", label="F_h - F_g at constant velocity")
    ax.plot(vv * 1e3, model + fit["offset_n"], "-", label="Stribeck (sig) + offset")
    ax.plot(vv * 1e3, model, "--", label="Stribeck (sig), offset removed")
    ax.set_xlabel("velocity [mm/s]")
    ax.set_ylabel("force [N]")
    ax.legend()
    fig.tight_layout()
    save(fig, path, dpi=100)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("identify", help="classic identification (friction, offsets, velocity gain, mass) from a record",
                       description="Thesis chapter-3 identification of a DATA_FORMAT.md record: constant-velocity "
                                   "segments, friction fits with an offset term, velocity gain, moving mass.")
    p.add_argument("record", help="record table (NAME.csv, NAME.csv.gz or NAME.parquet)")
    p.add_argument("--meta", help="metadata JSON (default: NAME.json beside the table)")
    p.add_argument("--out", required=True, help="output directory")
    add_json_flag(p)
    p.set_defaults(func=cmd_identify)
    _register_diagnose(sub)
    _register_predict(sub)


def cmd_diagnose(args: argparse.Namespace) -> int:
    import sys

    from htm.ident.diagnose import diagnose

    rec = read_record(args.record, args.meta)
    # (diagnose() loads the plotting library report.md needs on a thread while the fit runs:
    # htm.report.preload; the diagnosis itself needs no scipy: htm.ident.dsp.)
    run: dict[str, Any] = {}
    report = diagnose(rec, out_dir=args.out, verbose=args.verbose, stats=run, progress=None if args.quiet else stage_line())
    if sys.stderr.isatty() and not args.quiet:
        sys.stderr.write("\n")
    notes = list(report.get("warnings", []))
    absent = [c for c in ("p_a", "p_b") if c not in rec.columns]
    if absent:
        notes.append(f"no pressure column {', '.join(absent)}: the model is fitted to {', '.join(c for c in ('y', 'v', 'p_a', 'p_b', 'f') if c in rec.columns)} only")
    warn("diagnose", notes)
    if args.json:
        emit_json({"record": rec.name, "findings": report["findings"], "unexplained": report["unexplained"],
                   "warnings": notes, "simulations": run["simulations"], "seconds": run["seconds"],
                   "outputs": [str(Path(args.out) / "report.json")]})
        return 0
    found = ", ".join(f["effect"] + (f" ({f['channel']})" if f["channel"] else "") for f in report["findings"]) or "none"
    print(f"diagnosed {rec.name}")
    print(table([("findings", found), ("unexplained", "yes" if report["unexplained"] else "no"),
                 ("search", f"{run['simulations']:,} simulations in {run['seconds']:.1f} s")], indent="  "))
    print(f"wrote {path(Path(args.out) / 'report.json')}")
    return 0


def _register_diagnose(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("diagnose", help="fit the model to a record and find the effects it lacks",
                       description="Fit the EFFECTS.md base model to a DATA_FORMAT.md record by simulation error, trace "
                                   "the residual to effects (kept only if they pay off on held-out segments) and write "
                                   "report.json, predictions.csv and report.md with plots.")
    p.add_argument("record", help="record table (NAME.csv, NAME.csv.gz or NAME.parquet)")
    p.add_argument("--meta", help="metadata JSON (default: NAME.json beside the table)")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--verbose", action="store_true", help="print the search as it goes")
    add_json_flag(p)
    p.add_argument("--quiet", action="store_true", help="no progress line per stage on stderr")
    p.set_defaults(func=cmd_diagnose)


def stage_line(stream: Any = None) -> Callable[[str], None]:
    """A progress callback for `diagnose`: one line per stage on stderr — plain lines when stderr
    is not a terminal (a log, a pipe), one line rewritten in place when it is."""
    import sys

    out = stream if stream is not None else sys.stderr
    tty = bool(getattr(out, "isatty", lambda: False)())

    def show(line: str) -> None:
        if tty:
            out.write("\r\033[K" + line[: 200])
        else:
            out.write(line + "\n")
        out.flush()

    return show


def cmd_predict(args: argparse.Namespace) -> int:
    from htm.ident.predict import predict, read_model, write_prediction

    model = read_model(args.model)
    rec = read_record(args.record, args.meta)
    result = predict(model, rec, tare_s=args.tare)  # refused records raise before anything is written
    report = write_prediction(Path(args.out), model, result, args.tare)
    warn("predict", list(result["warnings"]))
    if args.json:
        emit_json({"record": rec.name, "model": str(args.model), "family": model.family, "rmse": report["rmse"],
                   "outputs": [str(Path(args.out) / "report.json")]})
        return 0
    print(f"predicted {rec.name} with the {model.family} model of `{model.meta.get('record')}`; RMS error per channel:")
    print(table([(c, RMSE_UNITS.get(c, lambda v: f"{v:.4g}")(v)) for c, v in report["rmse"].items()], indent="  "))
    print(f"wrote {path(Path(args.out) / 'report.json')}")
    return 0


# a channel's RMS error (SI) in the unit a person reads
RMSE_UNITS = {"y": lambda v: f"{v * 1e3:.4g} mm", "v": lambda v: f"{v * 1e3:.4g} mm/s", "p_a": lambda v: f"{v / 1e5:.4g} bar",
              "p_b": lambda v: f"{v / 1e5:.4g} bar", "p_s": lambda v: f"{v / 1e5:.4g} bar", "f": lambda v: f"{v / 1e3:.4g} kN"}


def _register_predict(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("predict", help="re-simulate a record with a model identified by `htm diagnose`",
                       description="Re-simulate another DATA_FORMAT.md record of the same rig with the model.json that "
                                   "`htm diagnose` wrote (valve-level, machine_position or displacement_input); write predictions.csv "
                                   "(c_pred per measured channel) and report.json (RMS error per channel).")
    p.add_argument("model", help="model.json written by htm diagnose")
    p.add_argument("record", help="record table (NAME.csv, NAME.csv.gz or NAME.parquet)")
    p.add_argument("--meta", help="metadata JSON (default: NAME.json beside the table)")
    p.add_argument("--tare", type=float, metavar="S",
                   help="take each sensor's zero from the record's first S seconds, which must be at rest")
    p.add_argument("--out", required=True, help="output directory")
    add_json_flag(p)
    p.set_defaults(func=cmd_predict)
