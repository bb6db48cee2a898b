"""In the band from the first cycle, off the million-cycle table: the worst |ΔF error| of the first
20 full-amplitude cycles over sine/triangle/trapezoid × 25–50 Hz × ΔF 3, 4.45, 6 kN × two C(T)
sizes (examples/ct_constant_force.toml and one twice its size), with the default amplitude
ramp-in (20 cycles or 1 s, whichever is longer) and, as the peer, a fixed 20-cycle ramp-in.
Cases `htm run --check` refuses are counted as refused, not run.

Run: .venv/bin/python benchmarks/ramp_grid.py   (one JSON object; a few seconds)
"""
from __future__ import annotations

import json
import tomllib

from million_cycles import ROOT, WAVES  # the table's waveforms, off its frequencies

from htm import core
from htm.errors import InfeasibleTest
from htm.spec import parse

SIZES = {"W50.8": (0.0508, 0.00635, 0.0152), "W101.6": (0.1016, 0.0127, 0.0304)}
FREQS = (25.0, 30.0, 35.0, 40.0, 45.0, 50.0)
FORCES = (3000.0, 4450.0, 6000.0)


def case(wave: str, f: float, df: float, size: str, ramp_cycles: float | None) -> float | None:
    """Worst |ΔF error| [%] of the first 20 full-amplitude cycles; None if the check refuses."""
    d = tomllib.loads((ROOT / "examples" / "ct_constant_force.toml").read_text())
    w, b, a0 = SIZES[size]
    d["specimen"].update(width_m=w, thickness_m=b, a0_m=a0)
    d["loading"].update(waveform=wave, frequency_hz=f, delta_f_n=df, **WAVES[wave])
    if ramp_cycles is not None:
        d["start"]["amplitude_cycles"] = ramp_cycles
    ramp = core.start_amplitude_cycles(f) if ramp_cycles is None else ramp_cycles
    d["end"]["max_cycles"] = int(d["start"]["mean_cycles"] + ramp) + 25
    try:
        spec = parse(d)
    except InfeasibleTest:
        return None
    return core.run_test(spec.config, "full").convergence[0]["worst_first_df_pct"]


def grid(ramp_cycles: float | None) -> dict:
    cases = [(wave, f, df, size) for size in SIZES for df in FORCES for wave in WAVES for f in FREQS]
    got = {c: case(*c, ramp_cycles) for c in cases}
    ran = {c: v for c, v in got.items() if v is not None}
    worst = max(ran, key=lambda c: ran[c])
    return {"cases": len(cases), "refused": len(cases) - len(ran), "worst_df_pct": round(ran[worst], 3),
            "worst_case": dict(zip(("waveform", "frequency_hz", "delta_f_n", "specimen"), worst)),
            "outside_2pct": sum(v >= 2.0 for v in ran.values())}


def main() -> None:
    print(json.dumps({"benchmark": "ramp_grid", "default_ramp_in": grid(None), "peer_20_cycle_ramp_in": grid(20.0),
                      "target": "worst_df_pct < 2 wherever the check lets the test run"}, indent=2))


if __name__ == "__main__":
    main()
