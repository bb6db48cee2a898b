"""A life test (force_life, strain_life) recorded like a crack-growth test: a test in the store
(catalogue row, spec, results, ``cycles.parquet``, ``loops.parquet`` with every sample of the
hysteresis loops kept at logarithmic intervals) and a rerun recording (``recording.rrd``: the
per-cycle peaks, moduli and stabilised level on the cycle timeline, each kept loop as a
stress–strain line strip at its cycle)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from htm.fatigue import lifetest

APP_ID = "htm"
SERIES = {
    "life/stress_pa": ("stress_max_pa", "stress_min_pa"),
    "life/strain": ("strain_max", "strain_min"),
    "life/plastic_strain_range": ("plastic_strain_range",),
    "life/modulus_pa": ("modulus_t_pa", "modulus_c_pa"),
    "life/tensile_peak_n": ("fmax_n", "trend"),
}


def record(store: Any, spec_path: str | Path, spec: lifetest.LifeSpec, out: dict[str, Any], wall: float,
           recording: bool = True) -> str:
    """Put a finished life test into `store` (an open `htm.record.store.Store`); returns its id."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    text = Path(spec_path).read_text(encoding="utf-8")
    tid = store.create_test(spec.name, spec.mode, "jump" if spec.config.get("jump", True) else "full", "toml", text,
                            spec.config.get("frequency_hz"))
    d = store.test_dir(tid)
    pq.write_table(pa.table(out["table"]), d / "cycles.parquet", compression="zstd")
    pq.write_table(pa.table(out["loops"]), d / "loops.parquet", compression="zstd")
    store.add_file(tid, "loops", d / "loops.parquet")
    s = lifetest.summary(spec, out, wall)
    store.set_results(tid, {"failed": int(s["failed"]), "life_cycles": s["cycles"], "n_drop10": s["n_drop10"],
                            "n_drop50": s["n_drop50"], "wall_time_s": wall, "stabilised": s["stabilised"]})
    if recording:
        rrd = d / "recording.rrd"
        write_recording(rrd, tid, spec, out)
        store.add_file(tid, "recording", rrd)
    store.set_status(tid, "finished", out["end_reason"], int(out["cycles"]))
    return tid


def write_recording(path: Path, recording_id: str, spec: lifetest.LifeSpec, out: dict[str, Any]) -> None:
    import rerun as rr

    rec = rr.RecordingStream(APP_ID, recording_id=recording_id)
    rec.save(str(path))
    rec.send_recording_name(spec.name)
    t = out["table"]
    c = np.asarray(t["cycle"]).astype(np.int64)
    for ent, cols in SERIES.items():
        rec.log(ent, rr.SeriesLines(names=list(cols)), static=True)
        v = np.column_stack([np.asarray(t[k], np.float64) for k in cols])
        rec.send_columns(ent, indexes=[rr.TimeColumn("cycle", sequence=c)], columns=rr.Scalars.columns(scalars=v))
    lp = out["loops"]
    lc = np.asarray(lp["cycle"]).astype(np.int64)
    for cyc in np.unique(lc):
        at = lc == cyc
        rec.set_time("cycle", sequence=int(cyc))
        rec.log("life/loop", rr.LineStrips2D([np.column_stack([lp["strain"][at], np.asarray(lp["stress_pa"][at]) / 1e6])]))
    rec.flush()
    rec.disconnect()
