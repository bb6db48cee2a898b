"""Million-cycle fatigue test benchmark: the engine at native speed.

Scenario: the C(T) of examples/ct_constant_force.toml (Table B.1: B = 6.35 mm, W = 50.8 mm,
ΔP = 4.45 kN, R = 0.1) on the thesis rig, demodulation control, sine 10 Hz with 1 kHz control,
a/W 0.30 → 0.60, Paris C divided by 10 so the test lasts ≈ 10⁶ cycles.
(i) full fidelity (every cycle through the plant) on one core, in a child process whose peak RSS is
measured; (ii) cycle-jump on the same spec: end crack length and cycles-to-end against (i), and
its wall time scaled to 10⁶ cycles; (iii) a batch of 16 tests (full fidelity, 3,000 cycles each,
Paris C varied) on 1 and on 2 worker threads.

Run: .venv/bin/python benchmarks/million_cycles.py   (prints one JSON object; ~2–3 minutes)
"""
from __future__ import annotations

import json
import resource
import subprocess
import sys
import time
import tomllib
from pathlib import Path

from htm import _core
from htm.spec import parse

ROOT = Path(__file__).resolve().parents[1]


def spec_doc() -> dict:
    d = tomllib.loads((ROOT / "examples" / "ct_constant_force.toml").read_text())
    d["law"]["c"] /= 10.0
    return d


def full_child(out: str) -> None:
    cfg = parse(spec_doc()).to_config()
    t0 = time.perf_counter()
    o = _core.run_test(cfg, "full")
    wall = time.perf_counter() - t0
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    Path(out).write_text(json.dumps({"cycles": o["cycles"], "a_end_m": o["a_end_m"], "wall_s": wall, "end_reason": o["end_reason"],
                                     "max_abs_df_err_pct": o["max_abs_df_err_pct"], "peak_rss_mb": rss,
                                     "rows": len(o["table"]["cycle"])}))


def main() -> None:
    tmp = ROOT / "out" / "bench_full.json"
    tmp.parent.mkdir(exist_ok=True)
    subprocess.run([sys.executable, __file__, "--full-child", str(tmp)], check=True)
    full = json.loads(tmp.read_text())

    cfg = parse(spec_doc()).to_config()
    walls = []
    for _ in range(3):
        t0 = time.perf_counter()
        jump = _core.run_test(cfg, "jump")
        walls.append(time.perf_counter() - t0)
    jump_wall = min(walls)

    batch = []
    for i in range(16):
        d = spec_doc()
        d["law"]["c"] *= 1.0 + 0.05 * i
        d["end"]["max_cycles"] = 3000
        batch.append(parse(d).to_config())
    t0 = time.perf_counter()
    one = _core.run_batch(batch, "full", 1)
    t1 = time.perf_counter() - t0
    t0 = time.perf_counter()
    two = _core.run_batch(batch, "full", 2)
    t2 = time.perf_counter() - t0
    assert [o["a_end_m"] for o in one] == [o["a_end_m"] for o in two]

    out = {
        "scenario": "C(T) W 50.8 mm B 6.35 mm, dP 4.45 kN R 0.1, thesis rig, demodulation control, sine 10 Hz, 1 kHz control, a/W 0.30->0.60",
        "full_cycles_per_s": round(full["cycles"] / full["wall_s"], 1),
        "full_cycles_to_end": full["cycles"],
        "full_a_end_m": full["a_end_m"],
        "full_end_reason": full["end_reason"],
        "full_wall_s": round(full["wall_s"], 2),
        "full_max_abs_df_err_pct": full["max_abs_df_err_pct"],
        "full_peak_rss_mb": round(full["peak_rss_mb"], 1),
        "jump_cycles_to_end": jump["cycles"],
        "jump_a_end_m": jump["a_end_m"],
        "jump_cycles_to_end_error_pct": round(100.0 * (jump["cycles"] / full["cycles"] - 1.0), 4),
        "jump_cycles_through_plant": jump["cycles_simulated"],
        "jump_wall_s": round(jump_wall, 4),
        "jump_seconds_per_1e6_cycles": round(jump_wall * 1e6 / jump["cycles"], 4),
        "batch_16_wall_1_core_s": round(t1, 2),
        "batch_16_wall_2_cores_s": round(t2, 2),
        "batch_speedup_2_cores": round(t1 / t2, 3),
        "targets": {"full_cycles_per_s": ">= 5000", "jump_cycles_to_end_error_pct": "|x| <= 0.5",
                    "jump_seconds_per_1e6_cycles": "<= 1", "batch_speedup_2_cores": ">= 1.7", "full_peak_rss_mb": "<= 300"},
    }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--full-child":
        full_child(sys.argv[2])
    else:
        main()
