"""Steady piston velocity for each valve command of the thesis's Table 3.3 under the default
(thesis rig) parameters, side by side with the measured values.

Prints a JSON list of {"u_v": ..., "v_mm_s": ...} and then a table.
Run: .venv/bin/python examples/table_3_3.py
"""
import json

from htm import Params
from htm.simulate import steady_velocity

# (command [V], measured steady velocity [mm/s]) — Table 3.3 as corrected in NOTES.md item 7.
# Rows written "-0.115 +- a" are centred on the valve's hydraulic null.
TABLE_3_3 = [
    (0.389, -36.0), (-0.611, 35.0),
    (-0.115 + 0.2, -6.0), (-0.115 - 0.2, 6.0),
    (-0.115 + 0.5, -28.0), (-0.115 - 0.5, 28.0),
    (1.0, -66.0), (-1.0, 66.0),
    (2.0, -128.0), (-2.0, 128.0),
    (10.0, -600.0), (-10.0, 600.0),
    (1.5, -128.0),
    (5.0, -369.0), (-5.0, 369.0),
]


def rows(params: Params | None = None) -> list[dict]:
    p = params or Params()
    out = []
    for u, v_thesis in TABLE_3_3:
        v = steady_velocity(u, p) * 1e3
        out.append({"u_v": round(u, 3), "v_mm_s": round(v, 2), "thesis_v_mm_s": v_thesis})
    return out


def main() -> None:
    r = rows()
    print(json.dumps([{"u_v": x["u_v"], "v_mm_s": x["v_mm_s"]} for x in r]))
    print(f"\n{'u [V]':>8} {'model [mm/s]':>13} {'thesis [mm/s]':>14} {'deviation':>10}")
    for x in r:
        dev = (x["v_mm_s"] - x["thesis_v_mm_s"]) / abs(x["thesis_v_mm_s"]) * 100
        print(f"{x['u_v']:>8.3f} {x['v_mm_s']:>13.1f} {x['thesis_v_mm_s']:>14.0f} {dev:>9.1f}%")


if __name__ == "__main__":
    main()
