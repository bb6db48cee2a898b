"""Are two runs' per-cycle tables identical? Compares DIR_A/NAME/cycles.parquet with
DIR_B/NAME/cycles.parquet for every NAME present in DIR_A: the same column names, types and
values bit for bit (NaN equal to NaN). Prints one line per table and exits 1 on any difference.

Capture both with the same command, e.g. every example spec `htm run` accepts:
    for f in examples/*.toml; do htm run $f --out DIR/$(basename $f .toml) --quiet --store DIR/s --no-recording; done
Run: .venv/bin/python tools/compare_tables.py /tmp/typed_before /tmp/typed_after
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq


def same(a: Path, b: Path) -> str | None:
    ta, tb = pq.read_table(a), pq.read_table(b)
    if ta.schema.names != tb.schema.names:
        return f"columns differ: {ta.schema.names} vs {tb.schema.names}"
    for name in ta.schema.names:
        if ta.schema.field(name).type != tb.schema.field(name).type:
            return f"{name}: type {ta.schema.field(name).type} vs {tb.schema.field(name).type}"
        x, y = ta[name].to_numpy(), tb[name].to_numpy()
        if x.shape != y.shape:
            return f"{name}: {len(x)} vs {len(y)} rows"
        if x.tobytes() != y.tobytes():  # bit for bit (the same NaN bits included)
            eq = (x == y) | (np.isnan(x) & np.isnan(y)) if x.dtype.kind == "f" else x == y
            bad = np.flatnonzero(~eq)
            return f"{name}: values differ (first rows {bad[:5].tolist()})"
    return None


def main(argv: list[str]) -> int:
    a, b = (Path(x) for x in argv[1:3])
    names = sorted(p.parent.name for p in a.glob("*/cycles.parquet"))
    if not names:
        print(f"no */cycles.parquet under {a}")
        return 1
    bad = 0
    for n in names:
        pb = b / n / "cycles.parquet"
        if not pb.exists():
            print(f"{n}: missing in {b}")
            bad += 1
            continue
        diff = same(a / n / "cycles.parquet", pb)
        rows = pq.read_metadata(pb).num_rows
        print(f"{n}: {'identical' if diff is None else 'DIFFERENT: ' + diff} ({rows} rows)")
        bad += diff is not None
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
