"""The diagnosis files: report.json, predictions.csv, report.md and its plots (DATA_FORMAT.md)."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from htm.ident import features as ft
from htm.ident.records import Record
from htm.ident.search import Finding, Result
from htm.ident.trace import Trace
from htm.report import envelope, pyplot, save

# The plots' time axes are at most 9 in wide at 90 dpi: a line drawn from the envelope of this many
# columns looks the same as every sample drawn (and takes half the drawing of the default 1,500).
_COLUMNS = 9 * 90

# The plots' margins, fixed (a tenth of the 9-10 in width: room for a tick label of seven characters and the axis
# label beside it) rather than measured by tight_layout, which draws every axis once more (a
# third of a report's writing).
_MARGINS = {"left": 0.1, "right": 0.98}

# Engineering units for a person reading report.md: (scale from SI, unit).
_ENG = {"y": (1e3, "mm"), "v": (1e3, "mm/s"), "p_a": (1e-5, "bar"), "p_b": (1e-5, "bar"), "p_s": (1e-5, "bar"), "f": (1e-3, "kN")}


def write_diagnosis(out: Path, rec: Record, report: dict[str, Any], res: Result, info: dict[str, Any]) -> None:
    """Write DATA_FORMAT.md's diagnosis files into `out` (created if needed)."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    write_predictions(out / report["predictions"], rec, res.base_pred, res.pred)
    _write_markdown(out, rec, report, res.base_pred, res.pred, res.findings, info)
    from htm.ident.predict import write_model  # the identified model, for `htm predict` (both families)

    write_model(out / "model.json", rec, res, info["family"])
    if info["family"] == "machine_position":  # the loop's gain and phase vs frequency, measured and modelled
        from htm.ident.loop_report import append_loop_section

        append_loop_section(out, rec, report, res)


def write_predictions(path: Path, rec: Record, before: dict[str, np.ndarray], after: dict[str, np.ndarray]) -> None:
    """`t` plus `c_before`, `c_after` for each measured channel (sensor readings, SI)."""
    cols = ["t"]
    data = [np.asarray(rec.columns["t"], dtype=float)]
    for c in ft.measured_channels(rec.columns):
        cols += [f"{c}_before", f"{c}_after"]
        data += [np.asarray(before[c], dtype=float), np.asarray(after[c], dtype=float)]
    np.savetxt(path, np.column_stack(data), delimiter=",", header=",".join(cols), comments="", fmt="%.12g")


def read_predictions(path: str | Path) -> dict[str, np.ndarray]:
    """Columns of a predictions.csv by name."""
    with open(path) as fh:
        header = fh.readline().strip().split(",")
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return {h: data[:, i] for i, h in enumerate(header)}


def _fmt(c: str, x: float) -> str:
    k, unit = _ENG[c]
    return f"{x * k:.4g} {unit}"


def _write_markdown(out: Path, rec: Record, report: dict[str, Any], before: dict, after: dict,
                    findings: list[Finding], info: dict[str, Any]) -> None:
    channels = ft.measured_channels(rec.columns)
    sigma = info["noise_floor"]
    loop = "closed-loop free run from the reference" if rec.meta.get("controller") else \
        f"open loop on the recorded command, restarted from the measurement every {report.get('horizon_s')} s"
    lines = [f"# Diagnosis of `{rec.name}`", "",
             f"{len(rec.columns['t'])} samples at {rec.meta.get('sample_rate_hz')} Hz; predictions are {loop}. "
             f"{info['simulations']} simulations in {info['seconds']:.1f} s.", ""]
    if rec.meta.get("controller") and info.get("fitted_on") == "recorded command":
        lines += ["The model was fitted on the recorded command (open loop, restarted from the measurement every "
                  "horizon: well posed whatever the loop does with its sensor noise); the errors below are those of the "
                  "free-run closed loop.", ""]
    if report.get("warnings"):
        lines += ["**Warnings** (samples or a channel left out of the fit):", "", *[f"- {w}" for w in report["warnings"]], ""]
    lines += ["## Error per channel", "",
              "| channel | noise floor | baseline RMSE | final RMSE | final systematic / noise |", "|---|---|---|---|---|"]
    for c in channels:
        lines.append(f"| {c} | {_fmt(c, sigma[c])} | {_fmt(c, report['baseline']['rmse'][c])} | "
                     f"{_fmt(c, report['final']['rmse'][c])} | {info['systematic_ratio'][c]:.2f} |")
    lines += ["", "![residuals](residuals.png)", "", "## Baseline (EFFECTS.md base model, identified)", "",
              "| parameter | value |", "|---|---|"]
    lines += [f"| {k} | {v:.5g} |" for k, v in report["baseline"]["params"].items()]
    lines += ["", "## Findings", ""]
    if not findings:
        lines.append("None: no effect of EFFECTS.md pays off on the held-out segments.")
    for i, f in enumerate(findings, 1):
        ps = ", ".join(f"{k} = {v:.4g}" for k, v in f.params.items()) or "no parameters"
        lines += [f"### {i}. `{f.effect}`" + (f" on `{f.channel}`" if f.channel else "") + f" ({ps})", "",
                  f.evidence, "", "| channel | RMSE before | RMSE after |", "|---|---|---|"]
        lines += [f"| {c} | {_fmt(c, f.rmse_before[c])} | {_fmt(c, f.rmse_after[c])} |" for c in channels if c in f.rmse_before]
        png = f"finding_{i}_{f.effect}.png"
        _plot_finding(out / png, rec, f)
        lines += ["", f"![{f.effect}]({png})", ""]
    lines += ["", "## Unexplained", "",
              "Judged where the model was fitted, on held-out data: the residual's systematic part over the noise floor after "
              "what a linear map of the model's own signals reproduces (a form error of the model, not an effect it lacks), "
              "against the residual the model leaves on synthetic records of itself.", "",
              "| channel | beyond the model's form | the model's own floor |", "|---|---|---|"]
    lines += [f"| {c} | {info['form_ratio'][c]:.2f} | {info['own_floor'][c]:.2f} |" if c in info["form_ratio"]
              else f"| {c} | left out of the fit (see the warnings) | |" for c in channels]
    lines.append("")
    if report["unexplained"]:
        lines.append("**Yes**: structure remains on " + ", ".join(info["unexplained_channels"]) + " that neither the model's form "
                     "nor any finding accounts for. Do not read the findings above as the whole story.")
        outside = info.get("outside")
        if outside is not None:
            ps = ", ".join(f"{k} = {v:.4g}" for k, v in outside.params.items())
            lines += ["", f"It is reproduced by `{outside.effect}` ({ps}), which EFFECTS.md does not list: {outside.evidence}", "",
                      "![outside](outside.png)"]
            _plot_finding(out / "outside.png", rec, outside)
    else:
        lines.append("No: what remains is within the noise or within what the model leaves on records of itself.")
    lines += decision_lines(info.get("trace"))
    _plot_residuals(out / "residuals.png", rec, before, after, sigma)
    (out / "report.md").write_text("\n".join(lines) + "\n")


# Stages of the trace shown in report.md (report.json's `trace` holds every decision).
_MD_STAGES = ("finding", "break ties", "own form", "backward check", "stop", "verdict")


def decision_lines(trace: Trace | None) -> list[str]:
    """report.md's brief account of the search: the decisions that added, named, dropped or
    stopped (report.json's `trace` has every one, with all its numbers), close ones marked."""
    if trace is None:
        return []
    shown = [d for d in trace.decisions if d.stage in _MD_STAGES or d.close]
    if not shown:
        return []
    return ["", "## Decisions", "",
            "Why each effect was kept or dropped (the rule and the numbers it compared; the settings and every "
            "decision are in report.json, `settings` and `trace`). A decision marked CLOSE lay within "
            "close_margin of its threshold or between two candidates the record barely tells apart.", "",
            *[f"- {d.text()}" for d in shown]]


def _plot_residuals(path: Path, rec: Record, before: dict, after: dict, sigma: dict) -> None:
    plt = pyplot()
    channels = ft.measured_channels(rec.columns)
    t = np.asarray(rec.columns["t"], dtype=float)
    fig, axes = plt.subplots(len(channels), 1, figsize=(9, 1.8 * len(channels)), sharex=True, squeeze=False)
    for ax, c in zip(axes[:, 0], channels):
        k, unit = _ENG[c]
        meas = np.asarray(rec.columns[c], dtype=float)
        ax.plot(*envelope(t, (before[c] - meas) * k, _COLUMNS), lw=0.6, label="baseline")
        ax.plot(*envelope(t, (after[c] - meas) * k, _COLUMNS), lw=0.6, label="final")
        ax.axhspan(-2 * sigma[c] * k, 2 * sigma[c] * k, color="0.85", label="±2σ noise")
        ax.set_ylabel(f"{c} [{unit}]")
    axes[0, 0].legend(loc="upper right", fontsize=7, ncol=3)
    axes[-1, 0].set_xlabel("t [s]")
    fig.suptitle("residual = prediction − measurement")
    fig.subplots_adjust(**_MARGINS, top=1.0 - 0.45 / fig.get_figheight(), bottom=0.5 / fig.get_figheight(), hspace=0.15)
    save(fig, path, dpi=90)


def _plot_finding(path: Path, rec: Record, f: Finding) -> None:
    plt = pyplot()
    c = f.focus
    k, unit = _ENG[c]
    t = np.asarray(rec.columns["t"], dtype=float)
    meas = np.asarray(rec.columns[c], dtype=float)
    rb, ra = (f.pred_before[c] - meas) * k, (f.pred_after[c] - meas) * k
    name, x = f.feature
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.4), gridspec_kw={"width_ratios": [2, 1]})
    a1.plot(*envelope(t, rb, _COLUMNS), lw=0.6, label="before")
    a1.plot(*envelope(t, ra, _COLUMNS), lw=0.6, label="after")
    a1.set_xlabel("t [s]")
    a1.set_ylabel(f"{c} residual [{unit}]")
    a1.legend(fontsize=7)
    step = max(1, len(t) // 3000)
    a2.plot(np.asarray(x)[::step], rb[::step], ".", ms=2, label="before")
    a2.plot(np.asarray(x)[::step], ra[::step], ".", ms=2, label="after")
    a2.set_xlabel(name)
    a2.set_ylabel(f"{c} residual [{unit}]")
    fig.suptitle(f"{f.cand.label}: residual before/after and its signature")
    fig.subplots_adjust(**_MARGINS, top=0.88, bottom=0.16, wspace=0.3)
    save(fig, path, dpi=90)
