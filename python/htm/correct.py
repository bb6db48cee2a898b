"""`htm db correct TEST --a0-visual MM --af-visual MM`: the measured crack sizes of a stored test
corrected to the visually measured initial and final crack fronts (ASTM E647), and the E647
reduction and report redone from the corrected sizes. Both the measured and the corrected sizes
are kept (the per-cycle table is not touched; the corrected a–N and both reductions are written
beside it and referenced from the catalogue).

The correction (E647: non-visual crack sizes are corrected to the post-test visual measurements,
the difference distributed over the test) is linear in the measured crack extension: the offset
between visual and measured size at the first and the last point, interpolated in between by the
measured size (the core's `correct_to_visual`).

This module sits above `htm.record` and `htm.fatigue` (it needs both) and adds its action to the
`htm db` group.
"""
from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path
from typing import Any

import numpy as np

from htm import core
from htm.errors import InputError, RecordError, SpecError
from htm.fatigue.data import CrackData, Setup
from htm.fatigue.e647 import reduce
from htm.fatigue.report import e647_report, write_reduced_csv
from htm.record.store import Store
from htm.terminal import add_json_flag, emit_json

METHOD = "linear in the measured crack extension between the visual initial and final crack sizes (E647)"


def _spec_geometry(spec_text: str) -> tuple[str, float, float]:
    import tomllib

    try:
        doc: dict[str, Any] = tomllib.loads(spec_text)
        sp = doc["specimen"]
        return str(sp["geometry"]), float(sp["width_m"]), float(sp["thickness_m"])
    except (tomllib.TOMLDecodeError, KeyError, TypeError, ValueError) as e:
        raise RecordError(f"the stored spec does not give the specimen (geometry, width_m, thickness_m): {e}") from None


def correct_test(store: Store, test_id: str, a0_visual_m: float, af_visual_m: float, n: int = 3) -> dict[str, Any]:
    """Correct test `test_id`'s crack sizes to the visual ones, redo E647 on both; returns what was written."""
    t = store.get(test_id)
    table = store.cycles(test_id)
    col = "a_measured_m" if "a_measured_m" in table else "a_m"
    if col not in table or "cycle" not in table or len(table["cycle"]) < 2:
        raise RecordError(f"test {test_id} has no crack sizes in its per-cycle table")
    cycles = np.asarray(table["cycle"], float)
    a = np.asarray(table[col], float)
    ok = np.isfinite(a) & np.isfinite(cycles)
    cycles, a = cycles[ok], a[ok]
    geometry, w, b = _spec_geometry(t["spec"])
    if not (0 < a0_visual_m < af_visual_m < (w if geometry == "ct" else w / 2)):
        raise SpecError(f"visual crack sizes a0 = {a0_visual_m * 1e3:g} mm, af = {af_visual_m * 1e3:g} mm: need "
                        f"0 < a0 < af < {(w if geometry == 'ct' else w / 2) * 1e3:g} mm for this {geometry.upper()}")
    try:
        corrected = core.correct_to_visual(np.ascontiguousarray(a), a0_visual_m, af_visual_m)
    except InputError as e:
        raise RecordError(f"test {test_id}: {e}") from None
    fmax = np.asarray(table.get("fmax_n", []), float)
    fmin = np.asarray(table.get("fmin_n", []), float)
    if fmax.size and np.isfinite(fmax).any():
        pmax = float(np.nanmedian(fmax[ok]))
        r = float(np.nanmedian(fmin[ok] / fmax[ok]))
    else:
        raise RecordError(f"test {test_id}: the per-cycle table has no forces (fmax_n, fmin_n) for the E647 reduction")
    setup = Setup.from_loads(geometry, w, b, r_ratio=r, pmax_n=pmax)
    out = store.test_dir(test_id) / "corrected"
    out.mkdir(parents=True, exist_ok=True)
    a_n = out / "a_n_corrected.csv"
    with open(a_n, "w", newline="") as fh:
        wr = csv.writer(fh, lineterminator="\n")
        wr.writerow(["cycles", "a_m", "a_measured_m"])
        for c, ac, am in zip(cycles, corrected, a):
            wr.writerow([str(int(c)), repr(float(ac)), repr(float(am))])
    written: dict[str, Any] = {"a_n": a_n}
    for name, sizes in (("measured", a), ("corrected", corrected)):
        d = out / f"e647_{name}"
        d.mkdir(exist_ok=True)
        data = CrackData("1", cycles, np.asarray(sizes, float))
        red = reduce(data, setup, n=n)
        write_reduced_csv(d / "reduced.csv", [red], False)
        written[name] = e647_report(d, [data], setup, [red], n)
    store.add_file(test_id, "a_n_corrected", a_n)
    store.add_file(test_id, "e647_measured", Path(written["measured"]))
    store.add_file(test_id, "e647_corrected", Path(written["corrected"]))
    results = {"a0_visual_m": a0_visual_m, "af_visual_m": af_visual_m, "a0_measured_m": float(a[0]), "af_measured_m": float(a[-1]),
               "visual_correction": {"column": col, "method": METHOD, "points": int(a.size),
                                     "offset_a0_m": float(a0_visual_m - a[0]), "offset_af_m": float(af_visual_m - a[-1]),
                                     "pmax_n": pmax, "r_ratio": r}}
    store.set_results(test_id, results)
    (out / "correction.json").write_text(json.dumps(results, indent=1) + "\n")
    return {**written, **results}


def cmd_correct(args: argparse.Namespace) -> int:
    for name in ("a0_visual", "af_visual"):
        v = getattr(args, name)
        if not (np.isfinite(v) and v > 0):
            raise SpecError(f"--{name.replace('_', '-')} = {v} mm must be a positive crack size in millimetres")
    with Store(args.store) as store:
        r = correct_test(store, args.id, args.a0_visual * 1e-3, args.af_visual * 1e-3, n=args.n)
    vc = r["visual_correction"]
    if args.json:
        emit_json(r)
        return 0
    print(f"test {args.id}: crack sizes corrected {METHOD}")
    print(f"  a0: measured {r['a0_measured_m'] * 1e3:8.3f} mm, visual {r['a0_visual_m'] * 1e3:8.3f} mm ({vc['offset_a0_m'] * 1e3:+.3f} mm)")
    print(f"  af: measured {r['af_measured_m'] * 1e3:8.3f} mm, visual {r['af_visual_m'] * 1e3:8.3f} mm ({vc['offset_af_m'] * 1e3:+.3f} mm)")
    print(f"wrote {r['a_n']}, {r['corrected']} (corrected) and {r['measured']} (measured); both kept")
    return 0


def add_db_action(dsub: argparse._SubParsersAction) -> None:
    """`htm db correct`: handed to `htm.record.cli.register` by the command line (this module sits
    above the store's own commands)."""
    p = dsub.add_parser("correct", help="correct a test's crack sizes to the visual initial and final cracks; redo E647",
                        description=f"Correct the measured crack sizes of TEST {METHOD}, redo the E647 reduction and "
                                    "report from the corrected sizes, and keep both (files in the test's folder, "
                                    "results in the catalogue).")
    p.add_argument("id", metavar="TEST")
    p.add_argument("--a0-visual", type=float, required=True, metavar="MM", help="visual initial crack size [mm]")
    p.add_argument("--af-visual", type=float, required=True, metavar="MM", help="visual final crack size [mm]")
    p.add_argument("--n", type=int, default=3, help="E647 incremental polynomial half-width (default 3)")
    p.add_argument("--store", help="test store folder (default $HTM_STORE or ~/.local/share/htm/store)")
    add_json_flag(p)
    p.set_defaults(func=cmd_correct)
