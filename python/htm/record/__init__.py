"""Recording: rerun streams and blueprints, the test store (SQLite catalogue + Parquet tables) and
the journal that lets a test resume after a crash.

For a live test (the device loop), the whole API is `Store` and `TestWriter`:

```python
from htm.record import Store, TestWriter

store = Store()                                   # --store / $HTM_STORE / ~/.local/share/htm/store
w = TestWriter.create(store, "ct-07", "device", "live", "toml", spec_text, frequency_hz=10.0,
                      recording=True, spawn=False, connect=None)   # rerun: file, + viewer if asked
w.event("mode_change", "force control on", cycle=0, time_s=0.0)   # fsync'd at once
w.signals({"t_s": t, "y_m": y, "f_n": f, "f_ref_n": r, "p_a_pa": pa, "p_b_pa": pb, "u_v": u})
w.cycles({"cycle": c, "fmax_n": fx, "fmin_n": fn, "a_m": a, ...}, snapshot=None)
w.close("finished", "target_crack_length", {"cycles": 123456})      # or w.interrupt("estop")
```

Every block goes to the journal first (`journal.py`: framed, checksummed, flushed at once, fsync'd
at events and at least once a second), then to the catalogue and the recording (`streams.py`).
`close` writes `cycles.parquet`, `raw.parquet` and `recording.rrd` and drops the journal; after a
crash `TestWriter.reopen(store, id)` returns the journal so far and a writer that continues it.
Signal names the recording lays out: `y_m`, `f_n`, `f_ref_n`, `p_a_pa`, `p_b_pa`, `u_v`, and a
rig's `v_m_s`, `p_s_pa` (others stay in the store's raw table only); per-cycle names are the
engine table's (`htm.core.run_test`). `htm run` and the console's live recorder both write this
one layout (`streams.py`).
"""
from htm.record.store import Store
from htm.record.writer import TestWriter

__all__ = ["Store", "TestWriter"]
