"""The machine's displacement loop in a diagnosis report: its gain and phase against frequency,
measured from the record (position over command) beside the identified model's, and the
identified loop's parameters in the words of docs/effects.md."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from htm.ident.loop import filled
from htm.ident.records import Record
from htm.ident.search import Result
from htm.report import pyplot, save

# Frequency-response estimates: segment length [s] (resolution 1/SEGMENT_S), the share of the
# command's peak spectral density below which a frequency is not excited enough to show, and the
# coherence of command and measured position it must have there.
SEGMENT_S = 4.0
EXCITED = 1e-3
COHERENT = 0.9
# The loop's base parameters as a person reads them: key -> (label, scale from SI, unit).
SHOWN = {"gain": ("command-to-position gain", 1.0, ""), "offset_m": ("offset", 1e3, "mm"),
         "bandwidth_hz": ("loop bandwidth", 1.0, "Hz"), "delay_s": ("command delay", 1e3, "ms"),
         "feedforward": ("velocity feed-forward", 1.0, ""), "compliance_m_per_n": ("static compliance under load", 1e9, "µm/kN"),
         "specimen_stiffness_n_m": ("specimen stiffness", 1e-3, "kN/m"), "specimen_damping_n_s_m": ("specimen damping", 1e-3, "kN·s/m")}


def frequency_response(rec: Record, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(frequencies [Hz], complex y/y_ref) where the command excites the record and the measured
    position follows it coherently: averaged cross-spectra over Hann-windowed `SEGMENT_S`
    segments overlapping by half (Welch)."""
    t = np.asarray(rec.columns["t"], dtype=float)
    fs = 1.0 / float(np.median(np.diff(t)))
    r = filled(rec.columns["y_ref"])
    nper = int(min(len(r), max(64, SEGMENT_S * fs)))
    f, (rr, ry, yy, rm, mm) = _spectra(nper, fs, r, filled(y), filled(rec.columns["y"]))
    coh = np.abs(rm) ** 2 / np.maximum(rr * mm, 1e-300)
    keep = (f > 0) & (rr > EXCITED * rr.max()) & (coh >= COHERENT)
    return f[keep], ry[keep] / rr[keep]


def _spectra(nper: int, fs: float, r: np.ndarray, y: np.ndarray, m: np.ndarray) -> tuple[np.ndarray, tuple]:
    """Averaged auto- and cross-spectra (r·r, r·y, y·y, r·m, m·m), each segment's mean removed."""
    step = max(1, nper // 2)
    starts = range(0, len(r) - nper + 1, step)
    win = 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(nper) / nper)  # periodic Hann

    def seg(x: np.ndarray) -> np.ndarray:
        segs = np.stack([x[i:i + nper] for i in starts])
        return np.fft.rfft((segs - segs.mean(axis=1, keepdims=True)) * win, axis=1)

    fr, fy, fm = seg(r), seg(y), seg(m)
    mean = lambda a, b: np.mean(np.conj(a) * b, axis=0)  # noqa: E731
    return np.fft.rfftfreq(nper, 1.0 / fs), (mean(fr, fr).real, mean(fr, fy), mean(fy, fy).real, mean(fr, fm), mean(fm, fm).real)


def linear_loop(p: Any, f: np.ndarray) -> np.ndarray:
    """The identified loop's linear part y/y_ref at frequencies `f` [Hz] (no load, effects that
    are not linear left out): k·(1 + β·s/ω)·e^(−sτ)·ω / (s·(1 + τ_v·s) + ω)."""
    s = 2j * np.pi * f
    w = 2 * np.pi * p["bandwidth_hz"]
    return p["gain"] * (1 + p["feedforward"] * s / w) * np.exp(-s * p["delay_s"]) * w / (s * (1 + p["valve_tau_s"] * s) + w)


def append_loop_section(out: Path, rec: Record, report: dict[str, Any], res: Result) -> None:
    """Add the loop's characteristic (loop_response.png) and parameters to DIR/report.md."""
    p = res.model.params()
    lines = ["", "## The machine's displacement loop", "",
             "The base model here is the machine's closed displacement loop (docs/effects.md), driven by the recorded "
             "command `y_ref`" + (" with the specimen's force predicted from the modelled motion" if "f" in res.pred else "")
             + "; the findings are that loop's own effects.", "", "| parameter | baseline | final |", "|---|---|---|"]
    base = res.base.params()
    for key, (label, k, unit) in SHOWN.items():
        if key in report["final"]["params"]:
            lines.append(f"| {label} | {base[key] * k:.4g} {unit} | {p[key] * k:.4g} {unit} |")
    f, h_meas = frequency_response(rec, np.asarray(rec.columns["y"], dtype=float))
    if len(f) >= 3:
        _, h_final = frequency_response(rec, res.pred["y"])
        _, h_base = frequency_response(rec, res.base_pred["y"])
        _plot(out / "loop_response.png", f, {"measured": h_meas, "baseline": h_base, "final model": h_final},
              linear_loop(p, f))
        lines += ["", "Gain and phase of position over command against frequency: estimated from the record (measured) and "
                      "from the models' predictions of the same record; the dashed line is the final model's linear part.", "",
                  "| frequency | measured gain | model gain | measured phase | model phase |", "|---|---|---|---|---|"]
        for fi in np.unique(np.geomspace(f[0], f[-1], 6).round(2)):
            i = int(np.argmin(np.abs(f - fi)))
            lines.append(f"| {f[i]:.2f} Hz | {abs(h_meas[i]):.3f} | {abs(h_final[i]):.3f} | "
                         f"{np.degrees(np.angle(h_meas[i])):.1f}° | {np.degrees(np.angle(h_final[i])):.1f}° |")
        lines += ["", "![loop response](loop_response.png)", ""]
    with open(out / "report.md", "a") as fh:
        fh.write("\n".join(lines) + "\n")


def _plot(path: Path, f: np.ndarray, curves: dict[str, np.ndarray], linear: np.ndarray) -> None:
    fig, (a1, a2) = pyplot().subplots(2, 1, figsize=(8, 6), sharex=True)
    for (name, h), style in zip(curves.items(), ("k.", "-", "-")):
        a1.plot(f, np.abs(h), style, ms=3, lw=1, label=name)
        a2.plot(f, np.degrees(np.unwrap(np.angle(h))), style, ms=3, lw=1)
    a1.plot(f, np.abs(linear), "--", lw=1, label="final model, linear part")
    a2.plot(f, np.degrees(np.unwrap(np.angle(linear))), "--", lw=1)
    a1.set_ylabel("gain |y / y_ref|")
    a2.set_ylabel("phase [deg]")
    a2.set_xlabel("frequency [Hz]")
    a1.set_xscale("log")
    a1.legend(fontsize=8)
    a1.grid(True, which="both", lw=0.3)
    a2.grid(True, which="both", lw=0.3)
    fig.suptitle("the machine's displacement loop: position over command")
    fig.tight_layout()
    save(fig, path, dpi=90)
