"""`htm sn fit|staircase|damage` and `htm en fit`: S-N curves (E739, maximum likelihood with run-outs),
staircase fatigue strength (ISO 12107), Miner's damage of a measured history, strain-life (E606)."""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any


def _dump(path: Path, doc: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=2, default=float))


def sn_fit_files(data: str | Path, out: Path, method: str = "auto", runouts_as_failures: bool = False) -> tuple[dict[str, Any], Any, Path, Path]:
    """Fit the S-N CSV `data` and write `out`/fit.json with the report beside it (what `htm sn fit`
    writes; `htm campaign` writes the same for its S-N campaigns). Returns (fit.json, fit, md, html)."""
    from htm.fatigue import sn
    from htm.fatigue.sn_report import sn_report

    d = sn.read_sn(data)
    fit = sn.sn_fit(d, method, runouts_as_failures)
    doc = fit.to_json()
    doc["data"] = str(data)
    extra = {}
    if d.n_runouts and not runouts_as_failures:
        extra = {"e739 (run-outs left out)": sn.fit_e739(d), "e739 (run-outs as failures, biased)": sn.fit_e739(d, True)}
        if fit.method != "maximum_likelihood":
            extra["maximum likelihood (run-outs censored)"] = sn.fit_ml(d)
    _dump(out / "fit.json", doc)
    md, html = sn_report(out, d, fit, extra)
    return doc, fit, md, html


def cmd_sn_fit(args: argparse.Namespace) -> int:
    from htm.fatigue.sn_report import sn_summary_lines

    out = Path(args.out)
    doc, fit, md, html = sn_fit_files(args.data, out, args.method, args.runouts_as_failures)
    if args.json:
        print(json.dumps(doc, indent=2, default=float))
        return 0
    print("\n".join(sn_summary_lines(fit)))
    print(f"wrote {out / 'fit.json'}, {md}, {html}")
    return 0


def staircase_files(data: str | Path, out: Path, step_pa: float | None = None) -> tuple[dict[str, Any], Any, Path, Path]:
    """The staircase estimate of `data` written to `out`/fit.json with its report (`htm sn
    staircase`'s files; `htm campaign` writes the same for a staircase). Returns (fit.json, estimate, md, html)."""
    from htm.fatigue import staircase
    from htm.fatigue.sn_report import staircase_report

    s, ro = staircase.read_staircase(data)
    st = staircase.dixon_mood(s, ro, step_pa, str(data))
    doc = st.to_json() | {"data": str(data)}
    _dump(out / "fit.json", doc)
    md, html = staircase_report(out, str(data), s, ro, st)
    return doc, st, md, html


def cmd_sn_staircase(args: argparse.Namespace) -> int:
    from htm.fatigue.sn_report import staircase_lines

    out = Path(args.out)
    doc, st, md, html = staircase_files(args.data, out, args.step_pa)
    if args.json:
        print(json.dumps(doc, indent=2, default=float))
        return 0
    print("\n".join(staircase_lines(st)))
    print(f"wrote {out / 'fit.json'}, {md}, {html}")
    return 0


def cmd_sn_damage(args: argparse.Namespace) -> int:
    from htm.errors import RecordError
    from htm.fatigue import sn

    try:
        doc = json.loads(Path(args.fit).read_text())
    except FileNotFoundError:
        raise RecordError(f"{args.fit}: no such file") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise RecordError(f"{args.fit}: not a fit.json ({e})") from None
    fit = sn.SNFit.from_json(doc, str(args.fit))
    series = sn.read_columns(args.data, (args.column,))[args.column]
    res = sn.miner_damage(series * args.scale, fit)
    res["data"], res["fit"] = str(args.data), str(args.fit)
    if args.json:
        print(json.dumps(res, indent=2, default=float))
        return 0
    print(f"rainflow count (ASTM E1049, the core's): {res['cycles_counted']:,.1f} cycles in one pass of {args.data}")
    if res["cycles_counted"]:
        print(f"amplitudes {res['amplitude_min_pa'] / 1e6:.1f} .. {res['amplitude_max_pa'] / 1e6:.1f} MPa; "
              f"{res['cycles_outside_fitted_stresses']:,.1f} cycles outside the fitted {fit.stress_range_pa[0] / 1e6:.0f}–"
              f"{fit.stress_range_pa[1] / 1e6:.0f} MPa (curve extrapolated, no fatigue limit)")
        pm, pl = res["passes_to_failure_median"], res["passes_to_failure_lower_band"]
        print(f"Miner damage per pass: median curve {res['damage_median']:.4g} ({pm:,.4g} passes to D = 1); "
              f"lower 5 % of a new specimen {res['damage_lower_band']:.4g} ({pl:,.4g} passes); "
              f"curve from {fit.n_specimens} specimens")
    return 0


def en_fit_files(data: str | Path, out: Path, modulus_pa: float | None = None) -> tuple[dict[str, Any], Any, Path, Path]:
    """Fit the strain-life CSV `data` and write `out`/fit.json with its report (`htm en fit`'s
    files; `htm campaign` writes the same for its strain_life campaigns). Returns (fit.json, fit, md, html)."""
    from htm.fatigue import strainlife
    from htm.fatigue.sn_report import en_report

    d = strainlife.read_en(data, modulus_pa)
    fit = strainlife.en_fit(d)
    doc = fit.to_json() | {"data": str(data)}
    _dump(out / "fit.json", doc)
    md, html = en_report(out, d, fit)
    return doc, fit, md, html


def cmd_en_fit(args: argparse.Namespace) -> int:
    from htm.fatigue.sn_report import en_lines

    out = Path(args.out)
    doc, fit, md, html = en_fit_files(args.data, out, args.modulus_pa)
    if args.json:
        print(json.dumps(doc, indent=2, default=float))
        return 0
    print("\n".join(en_lines(fit)))
    print(f"wrote {out / 'fit.json'}, {md}, {html}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sn", help="S-N curves: E739 and maximum-likelihood fits with run-outs, staircase, Miner damage",
                       description="Stress-life analysis of a lab's or a campaign's results (SI inside, MPa on screen).")
    ss = p.add_subparsers(dest="sn_command", required=True)
    f = ss.add_parser("fit", help="fit log10 N = a + b·log10 S with 90 %% intervals and bands",
                      description="Fit the S-N curve of DATA.csv (columns stress_amplitude_pa, cycles, runout 0/1) and "
                                  "write DIR/fit.json, report.md/.html and sn_curve.png. auto: maximum likelihood with "
                                  "run-outs as censored lives when there are run-outs, else E739 (they agree then).")
    f.add_argument("data", help="CSV: stress_amplitude_pa [Pa], cycles, runout (0 failure / 1 run-out)")
    f.add_argument("--out", required=True, help="output folder")
    f.add_argument("--method", choices=["auto", "e739", "ml"], default="auto")
    f.add_argument("--runouts-as-failures", action="store_true", help="count run-outs as failures (biased; for comparison)")
    f.add_argument("--json", action="store_true", help="print fit.json instead of the summary")
    f.set_defaults(func=cmd_sn_fit)
    s = ss.add_parser("staircase", help="fatigue strength and its scatter from a staircase (ISO 12107, Dixon–Mood)",
                      description="DATA.csv in test order: stress_amplitude_pa [Pa], runout (0/1).")
    s.add_argument("data")
    s.add_argument("--out", required=True)
    s.add_argument("--step-pa", type=float, help="the step [Pa] (default: the smallest spacing of the levels)")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_sn_staircase)
    m = ss.add_parser("damage", help="Miner's damage of a measured stress history against a fitted curve (rainflow count)",
                      description="Rainflow-count a stress history (the core's ASTM E1049 count) and sum n/N over the "
                                  "fitted curve's median and the lower end of its prediction band.")
    m.add_argument("data", help="CSV with the stress history in column --column")
    m.add_argument("--fit", required=True, help="fit.json written by `htm sn fit`")
    m.add_argument("--column", default="stress_pa", help="column of the history (default stress_pa, in Pa)")
    m.add_argument("--scale", type=float, default=1.0, help="multiply the history by this to get Pa (e.g. 1e6 for MPa)")
    m.add_argument("--json", action="store_true")
    m.set_defaults(func=cmd_sn_damage)
    e = sub.add_parser("en", help="strain-life (ε-N) and cyclic stress–strain curves from strain-controlled tests",
                       description="Strain-life analysis (ASTM E606 / ISO 12106).")
    es = e.add_subparsers(dest="en_command", required=True)
    ef = es.add_parser("fit", help="fit Basquin + Coffin–Manson and K', n' with 90 %% intervals",
                       description="DATA.csv: strain_amplitude (m/m), cycles (to failure), stress_amplitude_pa (stabilised) "
                                   "and either plastic_strain_amplitude or --modulus-pa; runout (0/1) optional.")
    ef.add_argument("data")
    ef.add_argument("--out", required=True)
    ef.add_argument("--modulus-pa", type=float, help="Young's modulus E [Pa] for the elastic/plastic split")
    ef.add_argument("--json", action="store_true")
    ef.set_defaults(func=cmd_en_fit)

