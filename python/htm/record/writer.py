"""An open test in the store: journal first, then catalogue and rerun recording; closed into
Parquet tables. The one writer for simulated tests (`htm run`) and live ones (the device loop).

Order of writes: a block of rows goes to the journal (framed, flushed) before anything else sees
it, so after a crash the journal holds everything any other file holds. The recording is written
to `recording.rrd.partial` and becomes `recording.rrd` at close; a resumed test rebuilds it from
the journal (a killed writer leaves an unreadable tail), under the same recording id.
"""
from __future__ import annotations

import fcntl
import json
import os
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from htm import core
from htm.errors import RecordError
from htm.record import journal
from htm.record.store import Store, concat

# event bits of the engine's per-cycle table, as the core names them
EVENT_NAMES = {bit: name for name, bit in core.EVENTS.items()}
# bits worth an entry in the catalogue's event list when they appear (start, jump and stop are states)
CATALOGUED = sum(core.EVENTS[n] for n in ("out_of_tolerance", "tolerance_exceeded", "size_criterion", "stiffness_step",
                                           "phase_change", "end"))
JUMP = core.EVENTS["jump"]
# seconds between two checks that the recording's file writer is alive
FLUSH_EVERY_S = 0.5


def engine_events(table: dict[str, np.ndarray], frequency_hz: float, prev_cycle: int = 0) -> list[tuple[int, float, str, str]]:
    """(cycle, time [s], kind, detail) for every notable event bit that appears in `table`
    (`prev_cycle`: the cycle of the row before the table's first). A bit on a jump row happened
    somewhere inside the jump: it is dated at the jump's first cycle, as the engine dates it
    (`size_criterion_cycle`), so the summary and the store name the same cycle."""
    if not table or len(table.get("cycle", [])) == 0:
        return []
    ev = np.asarray(table["events"], dtype=np.uint32)
    cyc = np.asarray(table["cycle"])
    prev = np.concatenate([[np.uint32(0)], ev[:-1]])
    out = []
    for bit, name in EVENT_NAMES.items():
        if not bit & CATALOGUED:
            continue
        for i in np.flatnonzero((ev & bit) & ~(prev & bit)):
            c = int(cyc[i])
            if ev[i] & JUMP:
                c = (int(cyc[i - 1]) if i > 0 else prev_cycle) + 1
            out.append((c, c / frequency_hz, name, f"a = {float(table['a_m'][i]) * 1e3:.3f} mm" if "a_m" in table else ""))
    return sorted(out)


class TestWriter:
    """Write one test. Use `TestWriter.create` for a new test, `TestWriter.reopen` to resume one.

    * `event(kind, detail, cycle=None, time_s=None)`: an event (journal fsync'd at once)
    * `cycles(table, raw=None, snapshot=None)`: a block of per-cycle rows (dict of equal-length
      arrays, `cycle` ascending), optional raw samples (dict of columns with `t_s`) and an engine
      snapshot (bytes) taken after the block's last cycle
    * `signals(columns)`: a decimated window of live signals (dict with `t_s` [s])
    * `close(status, end_reason, results)`: Parquet tables, catalogue, recording; journal removed
    * `interrupt(reason)`: a safe stop that keeps the journal so the test can resume
    """

    __test__ = False  # not a pytest class

    def __init__(self, store: Store, test_id: str, *, recording: bool = True, spawn: bool = False,
                 connect: str | None = None, opener: Callable[[Path], BinaryIO] | None = None, replay: bool = False):
        self.store, self.id = store, test_id
        row = store.get(test_id)
        self.dir = store.test_dir(test_id)
        self.frequency_hz = float(row["frequency_hz"] or 1.0)
        self._lock = open(self.dir / "lock", "a+")
        try:
            fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self._lock.close()
            raise RecordError(f"test {test_id} is open in another process; nothing was changed") from None
        self._lock.seek(0)
        self._lock.truncate()
        self._lock.write(str(os.getpid()))
        self._lock.flush()
        old = journal.read_journal(self.dir) if replay else []
        n = len(journal.segments(self.dir))
        self.journal = journal.JournalWriter(self.dir / f"journal-{n:03d}.htmj", opener=opener)
        self.journal.append(journal.HEADER, {"format": "htm-journal/1", "test": test_id, "segment": n, "pid": os.getpid()}, sync=True)
        self.last_cycle = max((int(r.arrays["cycle"][-1]) for s in old for r in s.records
                               if r.kind == journal.CHUNK and len(r.arrays.get("cycle", []))), default=0)
        self.rec = None
        self._rec_cycle = 0  # the last cycle sent to the recording
        self._flushed = time.monotonic()
        if recording:
            from htm.record.streams import Recording

            rid = str(uuid.uuid5(uuid.NAMESPACE_URL, f"htm-test:{test_id}"))
            self.rec = Recording(self.dir / "recording.rrd.partial", rid, f"{row['name']} ({test_id})", self.frequency_hz,
                                 spawn=spawn, connect=connect)
            for s in old:
                for r in s.records:
                    self._to_recording(r)

    @classmethod
    def create(cls, store: Store, name: str, kind: str, mode: str | None, spec_format: str, spec_body: str,
               frequency_hz: float, **kw: Any) -> TestWriter:
        """A new test in `store` (status running), ready for rows."""
        test_id = store.create_test(name, kind, mode, spec_format, spec_body, frequency_hz)
        w = cls(store, test_id, **kw)
        w.event("test_started", f"{kind} test {name}, mode {mode}")
        return w

    @classmethod
    def reopen(cls, store: Store, test_id: str, **kw: Any) -> tuple[TestWriter, list[journal.Segment]]:
        """Resume writing a test: its journal so far (validated) and a writer on a new segment."""
        row = store.get(test_id)
        if row["status"] == "finished":
            raise RecordError(f"test {test_id} is finished; nothing to resume")
        segs = journal.read_journal(store.test_dir(test_id))  # raises on corruption, before any write
        w = cls(store, test_id, replay=True, **kw)
        store.set_status(test_id, "running")  # held by this writer again (it was stopped or interrupted)
        return w, segs

    def _to_recording(self, r: journal.Record) -> None:
        if self.rec is None:
            return
        if r.kind == journal.CHUNK:
            self.rec.cycles(r.arrays)
            for c, t, k, d in engine_events(r.arrays, self.frequency_hz, self._rec_cycle):
                self.rec.event(k, d, c, t, "WARN" if k in ("tolerance_exceeded", "size_criterion") else "INFO")
            if len(r.arrays.get("cycle", [])):
                self._rec_cycle = int(r.arrays["cycle"][-1])
        elif r.kind == journal.SIGNALS:
            self.rec.signals(r.arrays)
        elif r.kind == journal.EVENT:
            m = r.meta
            self.rec.event(m["kind"], m.get("detail", ""), m.get("cycle"), m.get("time_s"), m.get("level", "INFO"))

    # ---- the device loop's API ---------------------------------------------------------------
    def event(self, kind: str, detail: str = "", cycle: int | None = None, time_s: float | None = None, level: str = "INFO") -> None:
        """An event; in the journal (fsync'd) before it reaches the catalogue and the recording."""
        meta = {"kind": kind, "detail": detail, "cycle": cycle, "time_s": time_s, "level": level}
        self.journal.append(journal.EVENT, meta, sync=True)
        self.store.add_event(self.id, kind, detail, cycle, time_s, source="journal")
        self._to_recording(journal.Record(journal.EVENT, meta))

    def cycles(self, table: dict[str, np.ndarray], raw: dict[str, np.ndarray] | None = None, snapshot: bytes | None = None) -> None:
        """A block of per-cycle rows (+ raw samples, + engine snapshot) as one journal record."""
        c = np.asarray(table.get("cycle", []))
        if len(c) and (c[0] <= self.last_cycle or np.any(np.diff(c) <= 0)):
            raise RecordError(f"cycle rows must ascend past {self.last_cycle}: got {int(c[0])}..{int(c[-1])}")
        arrays = {k: np.asarray(v) for k, v in table.items()}
        meta: dict[str, Any] = {"rows": int(len(c))}
        self.journal.append(journal.CHUNK, meta, arrays, blob=snapshot or b"")
        if len(c):
            self.last_cycle = int(c[-1])
        if raw is not None and len(raw.get("t_s", [])):
            self.signals(raw)
        self._to_recording(journal.Record(journal.CHUNK, meta, arrays))
        if self.rec is not None and time.monotonic() - self._flushed >= FLUSH_EVERY_S:
            self.rec.flush()  # a recording that cannot be written stops the test like the journal would
            self._flushed = time.monotonic()

    def signals(self, columns: dict[str, np.ndarray]) -> None:
        """A window of samples (dict of equal-length arrays with `t_s` [s])."""
        if "t_s" not in columns:
            raise RecordError("a signal window needs a `t_s` column (test time, s)")
        arrays = {k: np.asarray(v) for k, v in columns.items()}
        self.journal.append(journal.SIGNALS, {"rows": int(len(arrays["t_s"]))}, arrays)
        self._to_recording(journal.Record(journal.SIGNALS, {}, arrays))

    # ---- the end ------------------------------------------------------------------------------
    def interrupt(self, reason: str, detail: str = "") -> None:
        """Stop safely and keep the journal (resumable with `htm resume`). Works on a full disk:
        only the catalogue's small status row is written."""
        try:
            if not self.journal.closed:
                self.journal.append(journal.EVENT, {"kind": "stopped", "detail": f"{reason} {detail}".strip()}, sync=True)
        except RecordError:
            pass
        self.journal.close()
        if self.rec is not None:
            try:
                self.rec.close()
            except Exception:  # the recording is rebuilt from the journal on resume
                pass
        try:
            self.store.set_status(self.id, "stopped", end_reason=reason, cycles=self.last_cycle)
            self.store.add_event(self.id, "stopped", f"{reason} {detail}".strip(), self.last_cycle, self.last_cycle / self.frequency_hz)
        finally:
            self._unlock()

    def close(self, status: str = "finished", end_reason: str | None = None, results: dict[str, Any] | None = None) -> dict[str, Path]:
        """Write `cycles.parquet`, `raw.parquet` and `recording.rrd`, fill the catalogue, then
        drop the journal (its content now lives in those files). Returns the files."""
        results = dict(results or {})
        self.journal.append(journal.CLOSE, {"status": status, "end_reason": end_reason, "results": results}, sync=True)
        self.journal.close()
        try:
            return self._finalize(status, end_reason, results)
        except (OSError, RuntimeError, RecordError) as e:
            try:
                self.store.set_status(self.id, "stopped", end_reason="recording_failed", cycles=self.last_cycle)
            except RecordError:
                pass
            self._unlock()
            raise RecordError(f"closing test {self.id} failed ({e}) — test stopped safely at cycle {self.last_cycle:,}; "
                              f"what was recorded is kept in its journal (`htm resume {self.id}` finishes it once the cause "
                              "is fixed)") from None

    def _finalize(self, status: str, end_reason: str | None, results: dict[str, Any]) -> dict[str, Path]:
        import pyarrow as pa
        import pyarrow.parquet as pq

        segs = journal.read_journal(self.dir)
        table = concat([r.arrays for s in segs for r in s.records if r.kind == journal.CHUNK])
        raw = concat([r.arrays for s in segs for r in s.records if r.kind == journal.SIGNALS])
        if len(table.get("cycle", [])) and np.any(np.diff(table["cycle"]) <= 0):
            raise RecordError(f"test {self.id}: the journal's cycles do not ascend; the journal is kept for inspection")
        files = {}
        for name, t in (("cycles", table), ("raw", raw)):
            if t:
                path = self.dir / f"{name}.parquet"
                tmp = path.with_suffix(".parquet.tmp")
                pq.write_table(pa.table(t), tmp, compression="zstd")
                with open(tmp, "rb") as f:
                    os.fsync(f.fileno())
                os.replace(tmp, path)
                files[name] = path
        if self.rec is not None:
            self.rec.close()
            rrd = self.dir / "recording.rrd"
            os.replace(self.dir / "recording.rrd.partial", rrd)
            files["recording"] = rrd
        _fsync_dir(self.dir)
        ev = engine_events(table, self.frequency_hz)
        self.store.replace_events(self.id, "engine", [(c, t, k, d) for c, t, k, d in ev])
        self.store.replace_events(self.id, "journal", [(r.meta.get("cycle"), r.meta.get("time_s"), r.meta["kind"], r.meta.get("detail", ""))
                                                      for s in segs for r in s.records if r.kind == journal.EVENT])
        for role, p in files.items():
            self.store.add_file(self.id, role, p)
        self.store.set_results(self.id, results)
        cyc = results.get("cycles", int(table["cycle"][-1]) if table else 0)
        self.store.set_status(self.id, status, end_reason=end_reason, cycles=int(cyc),
                              a_end_m=results.get("final_a_m"))
        for p in journal.segments(self.dir):
            p.unlink()
        self._unlock()
        return files

    def _unlock(self) -> None:
        if not self._lock.closed:
            fcntl.flock(self._lock, fcntl.LOCK_UN)
            self._lock.close()


def _fsync_dir(d: Path) -> None:
    fd = os.open(d, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def spec_json(obj: Any) -> str:
    return json.dumps(obj, indent=1, default=float)
