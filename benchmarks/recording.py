"""Recording benchmark: what the store, the journal and the rerun recording cost a 10⁶-cycle test.

Scenario: the million-cycle spec of benchmarks/million_cycles.py (the C(T) of
examples/ct_constant_force.toml with Paris C / 10, a/W 0.30 → 0.60, ≈ 10⁶ cycles) in full
fidelity, every cycle through the plant, on one core:
(i)  the peer: `core.run_test` in one call, nothing recorded;
(ii) `htm run`'s recorded path: the chunked engine (0.25 s blocks, an engine snapshot per block),
     the journal (every row, flushed per block, fsync ≤ 1 s), the SQLite catalogue, Parquet tables
     (every cycle; raw windows: first 30 cycles, 2 per decade, 2 around each event) and the rerun
     recording (decimated after 10⁴ cycles; `htm.record.streams`).
Prints `recording_overhead_pct` = wall (ii)/(i) − 1 (also in CPU seconds of the process, all threads:
on a machine shared with other jobs the wall figure carries their noise) and `store_mb_per_1e6_cycles` = the test's folder
after close (Parquet + raw + .rrd) plus the catalogue, scaled to 10⁶ cycles.

Run: .venv/bin/python benchmarks/recording.py   (prints one JSON object; ≈ 2 × the full run, 4–8 min)
"""
from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

from htm import core
from htm.record.store import Store
from htm.run import run_recorded
from htm.spec import parse

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from million_cycles import spec_doc  # noqa: E402  (the same scenario)


def spec_text() -> str:
    """The example spec's text with Paris C / 10 (what spec_doc() parses to)."""
    text = (ROOT / "examples" / "ct_constant_force.toml").read_text()
    c = spec_doc()["law"]["c"]
    return text.replace("c = 1.1413e-29", f"c = {c!r}")


def main() -> None:
    text = spec_text()
    import tomllib

    spec = parse(tomllib.loads(text), "million")
    assert spec.law == parse(spec_doc(), "million").law
    cfg = spec.config

    t0, c0 = time.perf_counter(), time.process_time()
    plain = core.run_test(cfg, "full")
    t_plain, c_plain = time.perf_counter() - t0, time.process_time() - c0

    with tempfile.TemporaryDirectory(dir=ROOT / "out" if (ROOT / "out").exists() else None) as tmp:
        with Store(Path(tmp) / "store") as store:
            t0, c0 = time.perf_counter(), time.process_time()
            tid, rec, _ = run_recorded(spec, text, "full", store)
            t_rec, c_rec = time.perf_counter() - t0, time.process_time() - c0
            files = {p.name: p.stat().st_size for p in store.test_dir(tid).iterdir() if p.is_file()}
            catalogue = store.path.stat().st_size
            rows = len(rec["table"]["cycle"])
    same = bool((rec["table"]["a_m"] == plain.table["a_m"]).all()) and rows == len(plain.table["cycle"])
    total_mb = (sum(files.values()) + catalogue) / 1e6
    cycles = int(plain.cycles)
    out = {
        "scenario": "C(T) W 50.8 mm B 6.35 mm, dP 4.45 kN R 0.1, thesis rig, demodulation control, sine 10 Hz, "
                    "1 kHz control, a/W 0.30->0.60, Paris C/10, full fidelity",
        "cycles": cycles,
        "per_cycle_rows_stored": rows,
        "recorded_rows_equal_unrecorded": same,
        "plain_run_test_wall_s": round(t_plain, 2),
        "recorded_wall_s": round(t_rec, 2),
        "recording_overhead_pct": round(100.0 * (t_rec / t_plain - 1.0), 2),
        "plain_cpu_s": round(c_plain, 2),
        "recorded_cpu_s": round(c_rec, 2),
        "recording_overhead_cpu_pct": round(100.0 * (c_rec / c_plain - 1.0), 2),
        "recorded_engine_wall_s": round(rec["engine_wall_s"], 2),
        "recorded_close_wall_s": round(rec["close_wall_s"], 2),
        "store_files_mb": {k: round(v / 1e6, 3) for k, v in sorted(files.items())},
        "catalogue_mb": round(catalogue / 1e6, 3),
        "store_mb_per_1e6_cycles": round(total_mb * 1e6 / cycles, 2),
        "targets": {"recording_overhead_pct": "<= 20 (peer: the same test, run_test in one call, nothing recorded)",
                    "store_mb_per_1e6_cycles": "<= 200"},
    }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
