"""Convert the UTFSM MTS chirp CSVs (and any CSV of that layout: `t_s, x_cmd_mm, x_meas_mm,
F_N`, the authors' scaled channels) into DATA_FORMAT.md `machine_position` records: SI columns
`t, y_ref, y, f`, metadata declaring a machine that closes its own loop, with the source's
attribution.

    .venv/bin/python tools/utfsm_record.py SOURCE/chirp_MRcurrent_0A.csv \\
        --current-a 0 --out data/utfsm/utfsm_chirp_0A

writes `data/utfsm/utfsm_chirp_0A.csv.gz` and `.json` (refuses to overwrite).
"""
from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

from htm.errors import HtmError, RecordError
from htm.ident.records import FORMAT, MACHINE_POSITION, Record, validate_record, write_record

# column -> (DATA_FORMAT column, scale to SI, decimals of the source in its own unit)
COLUMNS = {"t_s": ("t", 1.0, 3), "x_cmd_mm": ("y_ref", 1e-3, 3), "x_meas_mm": ("y", 1e-3, 3), "F_N": ("f", 1.0, 2)}
SOURCE = ("UTFSM (Chile) MSc thesis data, 2022, recorded by M. Quiroz; repository DanielMaurelE/vRTHS_AMBC_MRdamper "
          "(MIT licence). An MTS uniaxial servo-hydraulic press in displacement control driving a magnetorheological "
          "damper with a ~0.8-20 Hz chirp. Scaling by the authors: x_meas_mm = 10*ch0 (LVDT), F_N = 9806.65*ch1 (load cell), "
          "x_cmd_mm = 10*ch2 (command). Converted to SI by tools/utfsm_record.py.")


def _si(text: str, scale: float, decimals: int) -> float:
    """The source's decimal reading in SI, as the double nearest to the exact decimal value."""
    v = float(text)
    return float(f"{v:.{decimals}f}e{int(round(np.log10(scale)))}") if scale != 1.0 else round(v, decimals)


def convert(path: Path, *, current_a: float | None, name: str) -> Record:
    """One CSV of the UTFSM layout as a `machine_position` record (SI)."""
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    if len(rows) < 3:
        raise RecordError(f"{path}: no data rows")
    header = [h.strip() for h in rows[0]]
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise RecordError(f"{path}: column(s) {', '.join(missing)} missing; this converter reads {', '.join(COLUMNS)}")
    idx = {c: header.index(c) for c in COLUMNS}
    cols: dict[str, list[float]] = {new: [] for new, _, _ in COLUMNS.values()}
    for k, row in enumerate(rows[1:], start=2):
        if not row:
            continue
        try:
            for c, (new, scale, dec) in COLUMNS.items():
                cols[new].append(_si(row[idx[c]], scale, dec))
        except (ValueError, IndexError) as e:
            raise RecordError(f"{path}: row {k}: {e}") from None
    columns = {k: np.asarray(v, dtype=float) for k, v in cols.items()}
    columns["t"] = columns["t"] - columns["t"][0]
    rate = 1.0 / float(np.median(np.diff(columns["t"])))
    specimen = {"stiffness_n_m": 0.0, "description": "magnetorheological damper (a friction-like load, no spring)"}
    if current_a is not None:
        specimen["coil_current_a"] = current_a
    meta = {"format": FORMAT, "sample_rate_hz": round(rate, 6),
            "rig": {"description": "MTS uniaxial servo-hydraulic press, displacement control (vendor controller)"},
            "specimen": specimen,
            "controller": {"type": MACHINE_POSITION},
            "sensors": {"y": {"resolution_m": 1e-6}, "y_ref": {"resolution_m": 1e-6}, "f": {"resolution_n": 0.01}},
            "source": SOURCE, "source_file": path.name}
    rec = Record(columns, meta, name)
    validate_record(rec)
    return rec


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("csv", type=Path, help="a CSV of the UTFSM layout (t_s, x_cmd_mm, x_meas_mm, F_N)")
    ap.add_argument("--out", type=Path, required=True, help="record base path (writes OUT.csv.gz and OUT.json)")
    ap.add_argument("--current-a", type=float, help="the damper's coil current [A] (metadata)")
    args = ap.parse_args(argv)
    try:
        rec = convert(args.csv, current_a=args.current_a, name=args.out.name)
        table, meta = write_record(rec, args.out, compress=True)
    except (HtmError, OSError) as e:
        print(f"utfsm_record: {e}", file=sys.stderr)
        return 2
    print(f"wrote {table} and {meta}: {len(rec.columns['t'])} samples at {rec.meta['sample_rate_hz']:g} Hz")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
