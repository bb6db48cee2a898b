"""The identification commands: `htm identify` (the thesis's chapter-3 identification),
`htm diagnose` (the model fit and effect search) and `htm predict` (an identified model on
another record of the same rig)."""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any, Callable

import numpy as np

from htm.ident.classic import identify, stribeck_basis, SMOOTHING_M_S
from htm.ident.records import read_record


def cmd_identify(args: argparse.Namespace) -> int:
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
    print(f"identified {rec.name}: {result['segments']} segments; wrote {out / 'identification.json'}, {out / 'report.md'}")
    return 0


def _plot(result: dict, path: Path) -> None:
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
    p.set_defaults(func=cmd_identify)
    _register_diagnose(sub)
    _register_predict(sub)


def cmd_diagnose(args: argparse.Namespace) -> int:
    import sys

    from htm.ident.diagnose import diagnose

    rec = read_record(args.record, args.meta)
    run: dict[str, Any] = {}
    report = diagnose(rec, out_dir=args.out, verbose=args.verbose, stats=run, progress=None if args.quiet else stage_line())
    found = ", ".join(f["effect"] + (f"({f['channel']})" if f["channel"] else "") for f in report["findings"]) or "none"
    if sys.stderr.isatty() and not args.quiet:
        sys.stderr.write("\n")
    print(f"diagnosed {rec.name}: findings: {found}; unexplained: {str(report['unexplained']).lower()}; "
          f"{run['simulations']} simulations in {run['seconds']:.1f} s; wrote {Path(args.out) / 'report.json'}")
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
    errs = ", ".join(f"{c} {v:.4g}" for c, v in report["rmse"].items())
    print(f"predicted {rec.name} with the {model.family} model of `{model.meta.get('record')}`: RMS error {errs} (SI); "
          f"wrote {Path(args.out) / 'report.json'}")
    return 0


def _register_predict(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("predict", help="re-simulate a record with a model identified by `htm diagnose`",
                       description="Re-simulate another DATA_FORMAT.md record of the same rig with the model.json that "
                                   "`htm diagnose` wrote (valve-level or machine_position); write predictions.csv "
                                   "(c_pred per measured channel) and report.json (RMS error per channel).")
    p.add_argument("model", help="model.json written by htm diagnose")
    p.add_argument("record", help="record table (NAME.csv, NAME.csv.gz or NAME.parquet)")
    p.add_argument("--meta", help="metadata JSON (default: NAME.json beside the table)")
    p.add_argument("--tare", type=float, metavar="S",
                   help="take each sensor's zero from the record's first S seconds, which must be at rest")
    p.add_argument("--out", required=True, help="output directory")
    p.set_defaults(func=cmd_predict)
