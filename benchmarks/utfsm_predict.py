"""A real machine's identified model, carried to another run: the UTFSM MTS chirps (data/utfsm).

`htm diagnose` on the 0 A chirp (the CLI, as a user runs it) writes model.json; `htm predict`
re-simulates the 1 A chirp with it, each sensor's zero tared on the first seconds at rest. Beside
it, from the same run, a second-order ARX model (y[k] = a1 y[k-1] + a2 y[k-2] + b1 r[k-d] +
b2 r[k-d-1] + c, least squares on the same 0 A chirp, delay d chosen by its own free-run error)
predicts the same 1 A chirp, free run from the command, tared the same way. Also the 1 A
prediction of the diagnosis' baseline model and of the final model with each finding switched
off again (the others kept), and the errors of each finding on the 0 A chirp (report.json).

Run: .venv/bin/python benchmarks/utfsm_predict.py [--out DIR]   (prints one JSON object)
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from htm.ident import loop
from htm.ident.predict import predict, read_model, rest_window
from htm.ident.records import read_record

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "data" / "utfsm"
FIT, OTHER = DATA / "utfsm_chirp_0A.csv.gz", DATA / "utfsm_chirp_1A.csv.gz"
TARE_S = 5.0
ARX_DELAYS = range(0, 41)


def arx_fit(r: np.ndarray, y: np.ndarray, d: int) -> np.ndarray:
    """Least-squares (equation error) coefficients [a1, a2, b1, b2, c] of the second-order ARX."""
    k = np.arange(d + 2, len(y))
    a = np.column_stack([y[k - 1], y[k - 2], r[k - d], r[k - d - 1], np.ones(len(k))])
    return np.linalg.lstsq(a, y[k], rcond=None)[0]


def arx_run(theta: np.ndarray, r: np.ndarray, y0: np.ndarray, d: int) -> np.ndarray:
    """Free run of the ARX model from the command, started on the first two measured samples."""
    from scipy.signal import lfilter

    a1, a2, b1, b2, c = theta
    u = np.zeros_like(r)
    u[d:] = r[: len(r) - d]
    u1 = np.r_[u[0], u[:-1]]
    drive = b1 * u + b2 * u1 + c
    zi = np.array([a1 * y0[1] + a2 * y0[0], a2 * y0[1]])  # state of y[k] - a1 y[k-1] - a2 y[k-2] = drive
    out = lfilter([1.0], [1.0, -a1, -a2], drive[2:], zi=zi)[0]
    return np.r_[y0[:2], out]


def tared_rmse(pred: np.ndarray, meas: np.ndarray, window: np.ndarray) -> float:
    """RMS of `pred` - `meas` with the prediction shifted to the measurement's level in `window`
    (inf for a run-away prediction: an unstable ARX candidate)."""
    with np.errstate(over="ignore", invalid="ignore"):
        p = pred + (np.mean(meas[window]) - np.mean(pred[window]))
        e = float(np.sqrt(np.mean((p - meas) ** 2)))
    return e if np.isfinite(e) else float("inf")


def arx_baseline(rec0, rec1) -> dict:
    """The second-order ARX fitted on `rec0` (delay by its own free-run error there) and its
    tared free-run position RMS on both records."""
    r0, y0 = rec0.columns["y_ref"], rec0.columns["y"]
    r1, y1 = rec1.columns["y_ref"], rec1.columns["y"]
    w0, w1 = rest_window(rec0, TARE_S), rest_window(rec1, TARE_S)
    best = min(ARX_DELAYS, key=lambda d: tared_rmse(arx_run(arx_fit(r0, y0, d), r0, y0, d), y0, w0))
    theta = arx_fit(r0, y0, best)
    return {"delay_samples": best, "coefficients": [float(x) for x in theta],
            "rmse_y_0A_m": tared_rmse(arx_run(theta, r0, y0, best), y0, w0),
            "rmse_y_1A_m": tared_rmse(arx_run(theta, r1, y1, best), y1, w1)}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", help="keep the diagnosis and prediction here (default: a temporary folder)")
    args = ap.parse_args(argv)
    tmp = tempfile.TemporaryDirectory()
    out = Path(args.out) if args.out else Path(tmp.name)
    diag, pred_dir = out / "diagnosis_0A", out / "predict_1A"
    t0 = time.perf_counter()
    cli = [sys.executable, "-m", "htm.cli"]
    done = subprocess.run(cli + ["diagnose", str(FIT), "--out", str(diag)], capture_output=True, text=True)
    t_diag = time.perf_counter() - t0
    if done.returncode:
        raise SystemExit(f"htm diagnose failed (exit {done.returncode}): {done.stderr.strip() or done.stdout.strip()}")
    done = subprocess.run(cli + ["predict", str(diag / "model.json"), str(OTHER), "--tare", str(TARE_S), "--out", str(pred_dir)],
                          capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(f"htm predict failed (exit {done.returncode}): {done.stderr.strip() or done.stdout.strip()}")
    report = json.loads((diag / "report.json").read_text())
    prediction = json.loads((pred_dir / "report.json").read_text())

    rec0, rec1 = read_record(FIT), read_record(OTHER)
    arx = arx_baseline(rec0, rec1)

    # the baseline (nominal loop of the 0 A record with the baseline's fitted parameters) and the
    # final model with each finding switched off again, on the 1 A chirp
    model = read_model(diag / "model.json")
    channels = model.channels
    family = loop.LoopFamily(rec0, channels)
    base = family.nominal.copy()
    for k, v in report["baseline"]["params"].items():
        base[k] = v
    variants = {"baseline": base}
    off = loop.LoopParams()
    for f in report["findings"]:
        p = model.params.copy()
        for key in loop.effect_fields(f["effect"]).values():
            if key in p:
                p[key] = off[key]
        variants[f"final without {f['effect']}" + (f" on {f['channel']}" if f["channel"] else "")] = p
    ablations = {}
    for name, p in variants.items():
        m = read_model(diag / "model.json")
        m.params = p
        ablations[name] = predict(m, rec1, tare_s=TARE_S)["rmse"]

    print(json.dumps({
        "benchmark": "UTFSM MTS chirps: model of the 0 A chirp (htm diagnose) predicting the 1 A chirp (htm predict --tare 5)",
        "diagnose_seconds": round(t_diag, 1),
        "findings_0A": [{"effect": f["effect"], "channel": f["channel"], "params": f["params"],
                         "rmse_before": f["rmse_before"], "rmse_after": f["rmse_after"]} for f in report["findings"]],
        "unexplained_0A": report["unexplained"],
        "rmse_0A": {"baseline": report["baseline"]["rmse"], "final": report["final"]["rmse"]},
        "predict_1A_rmse": prediction["rmse"],
        "predict_1A_other_models": ablations,
        "arx_2_2": arx,
        "position_rmse_1A_m": {"htm_model": prediction["rmse"]["y"], "arx_2_2": arx["rmse_y_1A_m"],
                               "arx_over_model": arx["rmse_y_1A_m"] / prediction["rmse"]["y"]},
    }, indent=2))


if __name__ == "__main__":
    main()
