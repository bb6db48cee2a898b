"""Entrained air is seen only where the chambers run at low pressure: the base model's stiffening
of the oil with pressure (`bulk_modulus_slope`, a nuisance every real rig needs) and free air
differ only in curvature over the pressures a record visits. This diagnoses the effect matrix's
`entrained_air` record of each seed set at the thesis rig's supply (190 bar: chambers at 55-100
bar) and at the 70 bar the matrix case runs (chambers at 12-65 bar), as shipped and, at 190 bar,
with the slope pinned at the truth's own 0 (an oracle: no real rig's oil is that stiff-free).
Per run: the air found, the velocity channel's error before and after, and what the matrix's
judge says (it asks some channel's error above its sensor noise to halve).

Run: .venv/bin/python benchmarks/air_identifiability.py   (one JSON line per run)
"""
from __future__ import annotations

import dataclasses
import json
import time

from htm.ident import proving, valve
from htm.ident.diagnose import diagnose

CASE = "entrained_air"


def main() -> int:
    shipped = list(valve.OTHER_FREES)
    pinned = [dataclasses.replace(f, hi=1e-3) if f.key == "bulk_modulus_slope" else f for f in shipped]
    low = next(kw for case, _, kw in proving.MATRIX if case == CASE)["supply_pa"]  # the case's own supply
    for seed_set in sorted(proving.MATRIX_SEED):
        for supply_pa, frees in ((None, shipped), (None, pinned), (low, shipped)):
            valve.OTHER_FREES[:] = frees
            rec, truth = proving.matrix_record(CASE, seed_set, supply_pa=supply_pa)  # None: the thesis rig's
            t0 = time.perf_counter()
            report = diagnose(rec)
            air = [f["params"]["air_fraction"] for f in report["findings"] if f["effect"] == CASE]
            print(json.dumps({
                "seed_set": seed_set, "supply_bar": round(truth["params"]["supply_pressure_pa"] / 1e5),
                "slope": "pinned at 0" if frees is pinned else "free (0-20)",
                "air_true": truth["effects"][CASE]["params"]["air_fraction"], "air_found": air[0] if air else None,
                "other_findings": [f["effect"] for f in report["findings"] if f["effect"] != CASE],
                "v_rmse_before": report["baseline"]["rmse"]["v"], "v_rmse_after": report["final"]["rmse"]["v"],
                "judge": proving.judge(report, truth), "seconds": round(time.perf_counter() - t0, 1)}), flush=True)
    valve.OTHER_FREES[:] = shipped
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
