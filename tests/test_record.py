"""Recording (issue 7): the journal, the test store, rerun recordings read back, resume after SIGKILL,
corrupted files, a full disk."""
from __future__ import annotations

import errno
import random
import resource
import signal
import sqlite3
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

from htm import core
from htm.cli import main
from htm.errors import RecordError
from htm.record import Store, TestWriter, journal
from htm.record.store import MIGRATIONS, SCHEMA_VERSION
from htm.spec import parse

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "ct_constant_force.toml"
HTM = [sys.executable, "-c", "import sys; from htm.cli import main; sys.exit(main())"]


def short_spec(tmp_path: Path, c_scale: float = 15.0) -> Path:
    """The example C(T) with a faster Paris law: ≈ 6,000 cycles to a/W 0.6 in full mode."""
    text = EXAMPLE.read_text().replace("c = 1.1413e-29", f"c = {1.1413e-29 * c_scale:.6e}")
    p = tmp_path / "short.toml"
    p.write_text(text)
    return p


def reference(spec_path: Path) -> tuple[dict, dict]:
    """The uninterrupted run of the engine (per-cycle table, raw windows) for comparison."""
    spec = parse(tomllib.loads(spec_path.read_text()), spec_path.stem)
    table = core.columns(core.run_test(spec.config, "full").table)
    s = core.TestRun(spec.config, "full", core.RAW_POLICY)
    raws = []
    while not s.finished:
        raw = core.columns(s.advance(max_seconds=60.0).raw)
        raws.append(np.column_stack([raw[k] for k in core.RAW_COLUMNS]))
    return table, np.concatenate(raws)


# ---- journal -------------------------------------------------------------------------------------

def _journal(tmp_path: Path, n: int = 5) -> Path:
    w = journal.JournalWriter(tmp_path / "journal-000.htmj")
    for i in range(n):
        c = np.arange(10 * i + 1, 10 * i + 11)
        w.append(journal.CHUNK, {"i": i}, {"cycle": c, "a_m": c * 1e-6}, blob=bytes([i]) * 7)
    w.close()
    return tmp_path / "journal-000.htmj"


def test_journal_round_trip_and_torn_tail_dropped_at_every_cut(tmp_path):
    p = _journal(tmp_path)
    seg = journal.read_segment(p)
    assert [r.meta["i"] for r in seg.records] == [0, 1, 2, 3, 4] and seg.torn_bytes == 0
    assert np.array_equal(seg.records[3].arrays["cycle"], np.arange(31, 41)) and seg.records[3].blob == bytes([3]) * 7
    data = p.read_bytes()
    last = len(journal.encode(journal.CHUNK, {"i": 4}, {"cycle": np.arange(41, 51), "a_m": np.arange(41, 51) * 1e-6}, bytes([4]) * 7))
    cut_path = tmp_path / "cut.htmj"
    for cut in range(len(data) - last, len(data)):  # a kill at any byte of the last record
        cut_path.write_bytes(data[:cut])
        seg = journal.read_segment(cut_path)
        assert [r.meta["i"] for r in seg.records] == [0, 1, 2, 3] and seg.torn_bytes == cut - (len(data) - last)
    # a garbled last record (same length, bad checksum) is torn too
    cut_path.write_bytes(data[:-3] + b"\xff\xff\xff")
    assert len(journal.read_segment(cut_path).records) == 4


def test_corrupted_journal_is_a_clear_error_and_nothing_is_touched(tmp_path, capsys):
    spec = short_spec(tmp_path, 60.0)
    store = tmp_path / "store"
    # a simulated test stopped after three blocks, so its journal stays
    with Store(store) as s:
        w = TestWriter.create(s, "short", "simulated", "full", "toml", spec.read_text(), 10.0, recording=False)
        sess = core.TestRun(parse(tomllib.loads(spec.read_text())).config, "full", core.RAW_POLICY)
        for _ in range(3):
            w.cycles(core.columns(sess.advance(max_cycles=200).table), None, bytes(sess.snapshot()))
        w.interrupt("interrupted")
        tid = w.id
        assert s.get(tid)["status"] == "stopped"
    seg = journal.segments(store / "tests" / tid)[0]
    data = bytearray(seg.read_bytes())
    data[len(journal.MAGIC) + 200] ^= 0xFF  # a flipped byte inside the first record
    seg.write_bytes(bytes(data))
    before = {f.name: f.read_bytes() for f in (store / "tests" / tid).iterdir()}
    cat = (store / "catalogue.sqlite").read_bytes()
    assert main(["resume", tid, "--store", str(store), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "corrupted at byte" in err and seg.name in err and "nothing was changed" in err and "Traceback" not in err
    assert {f.name: f.read_bytes() for f in (store / "tests" / tid).iterdir()} == before
    assert (store / "catalogue.sqlite").read_bytes() == cat


def test_full_disk_injected_enospc_keeps_what_was_written(tmp_path):
    class Full:
        """A file that takes `room` bytes, then fails like a full disk (part of the write lands)."""

        def __init__(self, path, room):
            self.f, self.room = open(path, "xb"), room

        def write(self, b):
            if len(b) > self.room:
                self.f.write(b[: self.room])
                self.room = 0
                raise OSError(errno.ENOSPC, "No space left on device")
            self.room -= len(b)
            return self.f.write(b)

        def flush(self):
            self.f.flush()

        def fileno(self):
            return self.f.fileno()

        def close(self):
            self.f.close()

    w = journal.JournalWriter(tmp_path / "journal-000.htmj", opener=lambda p: Full(p, 2000))
    rows = 0
    with pytest.raises(RecordError, match="No space left"):
        for i in range(100):
            w.append(journal.CHUNK, {}, {"cycle": np.arange(i * 20 + 1, i * 20 + 21)})
            rows += 20
    assert w.closed
    seg = journal.read_segment(tmp_path / "journal-000.htmj")
    got = np.concatenate([r.arrays["cycle"] for r in seg.records])
    assert np.array_equal(got, np.arange(1, rows + 1)) and seg.torn_bytes > 0


# ---- store -----------------------------------------------------------------------------------------

def test_store_round_trip_events_results_files_and_delete(tmp_path):
    with Store(tmp_path / "s") as s:
        w = TestWriter.create(s, "live-1", "device", "live", "toml", "[x]\ny = 1\n", 5.0, recording=False)
        w.event("mode_change", "force control on", cycle=0, time_s=0.0)
        w.signals({"t_s": np.linspace(0, 1, 11), "f_n": np.arange(11.0)})
        ev = np.array([0, 0, core.EVENTS["stiffness_step"], 0, core.EVENTS["end"]], np.uint32)
        w.cycles({"cycle": np.arange(1, 6), "fmax_n": np.full(5, 4.9e3), "events": ev,
                  "a_m": np.linspace(0.015, 0.016, 5)})
        assert s.get(w.id)["status"] == "running" and len(s.cycles(w.id)["cycle"]) == 5  # from the journal while open
        with pytest.raises(RecordError, match="ascend"):
            w.cycles({"cycle": np.array([5, 6])})
        files = w.close("finished", "target_crack_length", {"cycles": 5, "final_a_m": 0.016, "note": {"k": 1}})
        t = s.get(w.id)
        assert t["status"] == "finished" and t["cycles"] == 5 and t["a_end_m"] == 0.016 and t["spec"] == "[x]\ny = 1\n"
        assert t["results"]["note"] == {"k": 1} and t["results"]["cycles"] == 5
        kinds = [e["kind"] for e in t["events"]]
        assert {"test_started", "mode_change", "stiffness_step", "end"} <= set(kinds)
        assert set(files) == {"cycles", "raw"} and not journal.segments(s.test_dir(w.id))
        assert np.array_equal(s.cycles(w.id)["fmax_n"], np.full(5, 4.9e3)) and np.array_equal(s.raw(w.id)["f_n"], np.arange(11.0))
        s.delete(w.id)
        assert s.list_tests() == [] and not s.test_dir(w.id).exists()
        with pytest.raises(RecordError, match="no test"):
            s.get(w.id)


def test_catalogue_migrates_from_version_1_and_refuses_newer_or_garbage(tmp_path):
    root = tmp_path / "s"
    (root / "tests").mkdir(parents=True)
    db = sqlite3.connect(root / "catalogue.sqlite")
    db.executescript(MIGRATIONS[0] + "PRAGMA user_version = 1;")
    db.execute("INSERT INTO tests(id, name, kind, status, created_utc, updated_utc) VALUES ('old', 'x', 'simulated', 'finished', 't', 't')")
    db.execute("INSERT INTO specs VALUES ('old', 'toml', '')")
    db.commit()
    db.close()
    with Store(root) as s:
        assert s.db.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION == 6
        assert s.get("old")["host"] is None and [t["id"] for t in s.list_tests()] == ["old"]
    db = sqlite3.connect(root / "catalogue.sqlite")
    db.execute("PRAGMA user_version = 99")
    db.commit()
    db.close()
    with pytest.raises(RecordError, match="newer than this htm"):
        Store(root)
    garbage = b"this is not a database" * 300
    (root / "catalogue.sqlite").write_bytes(garbage)
    with pytest.raises(RecordError, match="not readable.*nothing was changed"):
        Store(root)
    assert (root / "catalogue.sqlite").read_bytes() == garbage
    assert main(["db", "list", "--store", str(root)]) == 2


def test_two_processes_opening_a_new_store_at_once_both_open_it(tmp_path, monkeypatch):
    # the first to take the write lock migrates; the other, which read the old version before,
    # finds the new one under the lock and leaves it (it used to re-apply the migration and fail)
    with Store(tmp_path / "s") as first:
        db = first.db
        current = db.version
        assert current() == SCHEMA_VERSION
        stale = [0]  # a late second opener read version 0 before the first one migrated
        monkeypatch.setattr(db, "version", lambda: stale.pop() if stale else current())
        db.migrate(MIGRATIONS)
        assert current() == SCHEMA_VERSION
        codes = [subprocess.Popen([sys.executable, "-c", "import sys; from htm.cli import main; "
                                   f"sys.exit(main(['db', 'list', '--store', {str(tmp_path / 'new')!r}]))"])
                 for _ in range(4)]
        assert [p.wait(60) for p in codes] == [0, 0, 0, 0]


# ---- a recorded run, read back -------------------------------------------------------------------

def _rrd(path: Path) -> dict[str, dict[str, np.ndarray]]:
    """entity -> {column: values} of a recording, via rerun.chunk.RrdReader."""
    from rerun.chunk import RrdReader

    out: dict[str, list] = {}
    for ch in RrdReader(path).stream():
        if ch.is_static:
            continue
        b = ch.to_record_batch()
        out.setdefault(ch.entity_path, []).append(b)
    import pyarrow as pa

    res = {}
    for e, bs in out.items():
        cols: dict[str, list] = {}
        names = dict.fromkeys(n for b in bs for n in b.schema.names if not n.startswith("rerun."))
        for name in names:
            vals: list = []
            for b in bs:
                if name not in b.schema.names:
                    vals += [None] * b.num_rows  # e.g. an event logged before any cycle
                    continue
                col = b.column(name)
                vals += (col.cast(pa.int64()) if pa.types.is_temporal(col.type) else col).to_pylist()  # durations as ns
            cols[name] = vals
        res[e] = cols
    return res


def test_htm_run_records_store_and_rrd_that_read_back(tmp_path, capsys):
    spec = short_spec(tmp_path, 60.0)
    store = tmp_path / "store"
    assert main(["run", str(spec), "--mode", "full", "--out", str(tmp_path / "o"), "--quiet", "--store", str(store)]) == 0
    with Store(store) as s:
        (t,) = s.list_tests()
        tid = t["id"]
        table = s.cycles(tid)
        raw = s.raw(tid)
        row = s.get(tid)
    ref, ref_raw = reference(spec)
    for k in ("cycle", "fmax_n", "a_m", "ctrl_u1_v", "events"):
        assert np.array_equal(table[k], ref[k]), k
    assert np.array_equal(np.column_stack([raw[k] for k in core.RAW_COLUMNS]), ref_raw)
    # raw windows: the first 30 cycles whole, then a couple per decade and around events
    kept = np.unique(raw["cycle"]).astype(int)
    assert set(range(1, 31)) <= set(kept) and {100, 101, 1000, 1001} <= set(kept) and len(kept) < 0.1 * len(table["cycle"])
    assert row["status"] == "finished" and row["end_reason"] == "target_crack_length"
    # the same per-cycle table as before beside the run's outputs
    import pyarrow.parquet as pq
    assert np.array_equal(pq.read_table(tmp_path / "o" / "cycles.parquet").column("a_m").to_numpy(), table["a_m"])

    rrd = Path(row["files"]["recording"]["path"])
    from rerun.chunk import RrdReader
    r = RrdReader(rrd)
    assert r.recordings()[0].application_id == "htm" and r.blueprints(), "the blueprint is saved with the recording"
    ents = _rrd(rrd)
    expected = {"/cycle/force_n", "/cycle/force_error_pct", "/cycle/crack_length_m", "/cycle/stress_intensity_pa_sqrt_m",
                "/cycle/dadn_m_per_cycle", "/cycle/specimen_stiffness_n_m", "/cycle/controller_v", "/signals/force_n",
                "/signals/position_m", "/signals/pressure_pa", "/signals/valve_v", "/events", "/crack/dadn_vs_delta_k"}
    assert expected <= set(ents), set(ents)
    f = ents["/cycle/force_n"]
    assert f["cycle"] == list(table["cycle"]), "every cycle once (short test: no decimation)"
    assert np.allclose(np.array(f["time"]) / 1e9, table["cycle"] / 10.0, atol=1e-8), "time = cycle / f"
    assert np.array_equal(np.array(f["Scalars:scalars"])[:, 0], table["fmax_n"])
    a = ents["/cycle/crack_length_m"]
    assert np.array_equal(np.array(a["Scalars:scalars"])[:, 0], table["a_m"])
    sig = ents["/signals/force_n"]
    assert np.array_equal(np.array(sig["Scalars:scalars"])[:, 0], raw["f_n"]) and "time" in sig and "cycle" in sig
    texts = [str(x) for x in ents["/events"]["TextLog:text"]]
    assert any("end" in x for x in texts) and any("test_started" in x for x in texts)
    assert any("convergence" in x and "start (cycle" in x for x in texts), "the start's convergence is in the recording"
    assert row["results"]["cycles_to_2pct"] is not None and row["results"]["convergence"][0]["cause"] == "start"
    capsys.readouterr()
    assert main(["db", "show", tid, "--store", str(store)]) == 0
    shown = capsys.readouterr().out
    assert "finished" in shown and "cycles.parquet" in shown and "recording.rrd" in shown
    assert main(["db", "export", tid, "--out", str(tmp_path / "ex"), "--format", "csv", "--store", str(store)]) == 0
    assert (tmp_path / "ex" / "cycles.csv").read_text().count("\n") == len(table["cycle"]) + 1
    assert main(["db", "export", tid, "--out", str(tmp_path / "ex"), "--store", str(store)]) == 2  # never overwrites
    assert main(["db", "delete", tid, "--store", str(store)]) == 2  # needs --yes
    assert main(["db", "delete", tid, "--yes", "--store", str(store)]) == 0 and not rrd.exists()


# ---- crash and resume ------------------------------------------------------------------------------

def _test_id(store: Path, deadline: float) -> str | None:
    while time.monotonic() < deadline:
        db = store / "catalogue.sqlite"
        if db.exists():
            try:
                with Store(store) as s:
                    rows = s.list_tests()
                if rows:
                    return rows[0]["id"]
            except RecordError:
                pass
        time.sleep(0.05)
    return None


def _kill_at_random_moment(proc: subprocess.Popen, seg: Path, rng: random.Random, during_startup: bool) -> bool:
    """SIGKILL `proc` at a random moment: during its start-up, or once it writes blocks of rows to
    its journal segment `seg`, 0–0.5 s later (so mid-run, mid-write included). False if it ended first."""
    deadline = time.monotonic() + 120
    if during_startup:
        time.sleep(rng.uniform(0.0, 1.0))
    else:
        while proc.poll() is None and time.monotonic() < deadline and not (seg.exists() and seg.stat().st_size > 20_000):
            time.sleep(0.01)
        time.sleep(rng.uniform(0.0, 0.5))
    if proc.poll() is not None:
        return False
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    return True


def test_sigkill_at_20_random_moments_then_resume_loses_and_doubles_nothing(tmp_path):
    spec = short_spec(tmp_path, 0.5)  # ≈ 1.8·10⁵ cycles, full mode: 20 kills take ≈ 7·10⁴ on a quiet 2-core machine
    store = tmp_path / "store"
    rng = random.Random(7)
    args = ["--store", str(store), "--quiet"]
    proc = subprocess.Popen(HTM + ["run", str(spec), "--mode", "full", "--out", str(tmp_path / "o")] + args,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    tid = _test_id(store, time.monotonic() + 60)
    assert tid is not None
    tdir = store / "tests" / tid
    kills, progress = 0, []
    seg = tdir / "journal-000.htmj"
    while kills < 20:
        if not _kill_at_random_moment(proc, seg, rng, during_startup=kills % 5 == 4):
            break
        kills += 1
        with Store(store) as s:
            # a killed writer's test is marked interrupted by the next store opened on the root
            assert s.get(tid)["status"] in ("interrupted", "finished")
            c = s.cycles(tid).get("cycle", np.zeros(0))  # from the journal (a torn tail dropped)
        assert np.array_equal(c, np.arange(1, len(c) + 1)), "the journal after a kill: no gap, no duplicate"
        progress.append(len(c))
        seg = tdir / f"journal-{len(journal.segments(tdir)):03d}.htmj"  # the one the resumed run will write
        proc = subprocess.Popen(HTM + ["resume", tid] + args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err.decode()
    print("cycles in the journal after each kill:", progress)
    assert kills == 20, f"the test ended after {kills} kills; make it longer"
    assert len(set(progress)) >= 12 and progress == sorted(progress), f"kills mid-run, progress kept: {progress}"
    with Store(store) as s:
        t = s.get(tid)
        table, raw = s.cycles(tid), s.raw(tid)
    assert t["status"] == "finished" and t["end_reason"] == "target_crack_length"
    assert sum(e["kind"] == "resumed" for e in t["events"]) >= 16  # kills in start-up may precede it
    c = table["cycle"]
    assert np.array_equal(c, np.arange(1, len(c) + 1)), "no gap, no duplicate"
    ref, ref_raw = reference(spec)
    for k in ref:
        assert np.array_equal(table[k], ref[k], equal_nan=True), k  # bit for bit as if never killed
    assert np.array_equal(np.column_stack([raw[k] for k in core.RAW_COLUMNS]), ref_raw)
    ents = _rrd(Path(t["files"]["recording"]["path"]))
    f = np.array(ents["/cycle/force_n"]["cycle"])
    assert np.array_equal(f, c[(c <= 10_000) | (c % 10 == 0) | (table["events"] & ~np.uint32(core.EVENTS["start"]) != 0)]), \
        "the recording: each cycle it shows, once"


def test_full_disk_in_a_child_stops_safely_then_resumes(tmp_path):
    """RLIMIT_FSIZE makes every file past 1.5 MB fail to grow (EFBIG), as a full disk would."""
    spec = short_spec(tmp_path, 5.0)  # ≈ 2·10⁴ cycles: the limit is met mid-run
    store = tmp_path / "store"
    Store(store).close()  # the catalogue exists before the limit
    limit = 1_500_000

    def cap():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    p = subprocess.run(HTM + ["run", str(spec), "--mode", "full", "--out", str(tmp_path / "o"), "--quiet", "--store", str(store)],
                       preexec_fn=cap, capture_output=True, text=True, timeout=300)
    assert p.returncode == 2, p.stderr
    err = [ln for ln in p.stderr.splitlines() if ln.startswith("htm run: error")]
    assert len(err) == 1 and "stopped safely" in err[0] and "Traceback" not in p.stderr, p.stderr
    with Store(store) as s:
        (t,) = s.list_tests()
        assert t["status"] == "stopped" and t["end_reason"] == "recording_failed"
        kept = s.cycles(t["id"])
    assert len(kept["cycle"]) > 100 and np.array_equal(kept["cycle"], np.arange(1, len(kept["cycle"]) + 1))
    ref, _ = reference(spec)
    n = len(kept["cycle"])
    assert np.array_equal(kept["a_m"], ref["a_m"][:n]), "what was recorded is intact"
    assert main(["resume", t["id"], "--store", str(store), "--quiet"]) == 0  # space again: it continues
    with Store(store) as s:
        assert np.array_equal(s.cycles(t["id"])["a_m"], ref["a_m"]) and s.get(t["id"])["status"] == "finished"


# ---- issue 17: interrupted tests, export, events ----------------------------------------------------

WRITER_CHILD = """
import sys, time, numpy as np
from htm.record import Store, TestWriter
w = TestWriter.create(Store(sys.argv[1]), "live", sys.argv[2], "lockstep", "json", "{}", 10.0, recording=False)
print(w.id, flush=True)
for i in range(1, 1000):
    w.cycles({"cycle": np.array([i]), "a_m": np.array([0.015 + i * 1e-9]), "events": np.zeros(1, np.uint32)})
    if i == 40:
        print("40", flush=True)
    time.sleep(0.01)
"""


@pytest.mark.parametrize("kind", ["device", "simulated"])
def test_a_killed_writers_test_is_marked_interrupted_and_keeps_its_rows(tmp_path, kind, capsys):
    store = tmp_path / "store"
    p = subprocess.Popen([sys.executable, "-c", WRITER_CHILD, str(store), kind], stdout=subprocess.PIPE, text=True)
    tid = p.stdout.readline().strip()
    assert p.stdout.readline().strip() == "40"
    with Store(store) as s:
        assert s.get(tid)["status"] == "running", "a live writer's test is left alone"
    p.send_signal(signal.SIGKILL)
    p.wait()
    with Store(store) as s:  # the next store opened on the root (e.g. the next test's start)
        t = s.get(tid)
        c = s.cycles(tid)["cycle"]
    assert t["status"] == "interrupted" and t["cycles"] == len(c) >= 40
    assert np.array_equal(c, np.arange(1, len(c) + 1)), "every row written before the kill is kept"
    assert any(e["kind"] == "interrupted" for e in t["events"])
    assert main(["db", "show", tid, "--store", str(store)]) == 0
    out = capsys.readouterr().out
    if kind == "device":
        assert "does not resume" in out and "htm resume" not in out
        assert main(["resume", tid, "--store", str(store)]) == 2  # a clear refusal, not a traceback
    else:
        assert f"htm resume {tid}" in out


def test_export_carries_the_recording_and_the_report(tmp_path):
    store = tmp_path / "store"
    assert main(["run", str(EXAMPLE), "--out", str(tmp_path / "o"), "--quiet", "--store", str(store)]) == 0
    with Store(store) as s:
        (t,) = s.list_tests()
    assert main(["db", "export", t["id"], "--out", str(tmp_path / "x"), "--store", str(store)]) == 0
    names = {p.name for p in (tmp_path / "x").iterdir()}
    assert {"cycles.parquet", "recording.rrd", "report.md", "test.json"} <= names
    assert {p.name for p in (tmp_path / "o").glob("*.png")} <= names, "the report's plots go with it"
    assert _rrd(tmp_path / "x" / "recording.rrd"), "the exported recording reads back"


def test_summary_and_store_name_the_same_size_criterion_cycle_in_jump_mode(tmp_path):
    import json

    store = tmp_path / "store"
    assert main(["run", str(EXAMPLE), "--out", str(tmp_path / "o"), "--quiet", "--store", str(store), "--no-recording"]) == 0
    first = json.loads((tmp_path / "o" / "summary.json").read_text())["size_criterion_cycle"]
    with Store(store) as s:
        (t,) = s.list_tests()
        ev = [e["cycle"] for e in s.get(t["id"])["events"] if e["kind"] == "size_criterion"]
        table = s.cycles(t["id"])
    assert first is not None and ev == [first]
    # jump mode: one row per cycle run through the plant and one per jump (the README says so)
    c, jump = table["cycle"], (table["events"] & core.EVENTS["jump"]) != 0
    gaps = np.flatnonzero(np.diff(c) > 1) + 1
    assert len(gaps) > 10 and jump[gaps].all(), "every gap in the cycle column closes on a jump row"
