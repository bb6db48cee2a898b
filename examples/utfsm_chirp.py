"""A real machine that closes its own loop: the UTFSM MTS chirps (data/utfsm), through the CLI.

An MTS servo-hydraulic press in displacement control drives a magnetorheological damper with a
0.8 → 20 Hz chirp, once with the damper's coil at 0 A and once at 1 A. Only the command, the
LVDT and the load cell were recorded (`machine_position` records). This example runs what a
user would:

    htm diagnose data/utfsm/utfsm_chirp_0A.csv.gz --out OUT/diagnosis_0A
    htm predict OUT/diagnosis_0A/model.json data/utfsm/utfsm_chirp_1A.csv.gz --tare 5 --out OUT/predict_1A

and prints the findings and the errors. OUT/diagnosis_0A/report.md shows the residuals before
and after, the evidence for each finding and the loop's gain and phase against frequency.

    .venv/bin/python examples/utfsm_chirp.py --out out/utfsm
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from htm.cli import main as htm

DATA = Path(__file__).resolve().parents[1] / "data" / "utfsm"
TARE_S = 5.0  # both chirps rest for more than 5 s before they start


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="out/utfsm", help="output folder (diagnosis_0A/, predict_1A/)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    diag, pred = out / "diagnosis_0A", out / "predict_1A"
    code = htm(["diagnose", str(DATA / "utfsm_chirp_0A.csv.gz"), "--out", str(diag)])
    if code:
        return code
    code = htm(["predict", str(diag / "model.json"), str(DATA / "utfsm_chirp_1A.csv.gz"), "--tare", str(TARE_S), "--out", str(pred)])
    if code:
        return code
    report = json.loads((diag / "report.json").read_text())
    prediction = json.loads((pred / "report.json").read_text())
    mm = lambda x: f"{x * 1e3:.4f} mm"  # noqa: E731
    print(f"0 A chirp: position RMS {mm(report['baseline']['rmse']['y'])} (baseline) -> {mm(report['final']['rmse']['y'])} (final)")
    for f in report["findings"]:
        ps = ", ".join(f"{k} = {v:.4g}" for k, v in f["params"].items())
        print(f"  {f['effect']}{' on ' + f['channel'] if f['channel'] else ''} ({ps}): "
              f"y {mm(f['rmse_before']['y'])} -> {mm(f['rmse_after']['y'])}")
    print(f"unexplained structure left: {str(report['unexplained']).lower()}")
    print(f"1 A chirp predicted by the 0 A model (tared on its first {TARE_S:g} s): position RMS {mm(prediction['rmse']['y'])}, "
          f"force RMS {prediction['rmse']['f']:.0f} N")
    print(f"report: {diag / 'report.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
