"""The test store: a SQLite catalogue (tests, specs, status, events, results, file references) and
one folder per test holding its journal, Parquet tables and rerun recording.

Layout: `ROOT/catalogue.sqlite`, `ROOT/tests/ID/` with `journal-NNN.htmj` (while the test is open),
`cycles.parquet` (one row per cycle run through the plant, and one per cycle jump), `raw.parquet`
(raw high-rate windows: the first cycles, a few cycles per decade, around events), `recording.rrd`;
`ROOT/fleet/MACHINE/DATE/NAME.parquet` with `NAME.json` (measurement records put in for fleet
diagnosis, `htm fleet add`; catalogue table `fleet_records`). The root is `--store`, else
`$HTM_STORE`, else `~/.local/share/htm/store`. With `--store postgresql://USER@HOST/DB` (or such an
`$HTM_STORE`) the catalogue is that PostgreSQL database and the test folders are under the shared path
`$HTM_STORE_FILES` (default as above): same schema, same migrations (`backend.py` translates).
The schema version is SQLite's `user_version` (a table on PostgreSQL);
`MIGRATIONS[i]` takes a catalogue from version i to i + 1 inside one transaction.
A catalogue that does not read as one raises `RecordError` and is left untouched.
A test whose writer died (SIGKILL, power loss) is still `running` in the catalogue; the next
`Store` opened on the root finds it (its folder's lock is free) and marks it `interrupted`, keeping
every row its journal holds.
"""
from __future__ import annotations

import calendar
import fcntl
import json
import os
import secrets
import shutil
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from htm.errors import RecordError
from htm.record import backend, journal

MIGRATIONS = [
    # 0 -> 1
    """
    CREATE TABLE tests(
        id TEXT PRIMARY KEY, name TEXT NOT NULL, kind TEXT NOT NULL, mode TEXT, status TEXT NOT NULL,
        created_utc TEXT NOT NULL, updated_utc TEXT NOT NULL, end_reason TEXT, cycles INTEGER,
        a_end_m REAL, frequency_hz REAL);
    CREATE TABLE specs(test_id TEXT PRIMARY KEY REFERENCES tests(id) ON DELETE CASCADE,
        format TEXT NOT NULL, body TEXT NOT NULL);
    CREATE TABLE events(test_id TEXT NOT NULL REFERENCES tests(id) ON DELETE CASCADE,
        cycle INTEGER, time_s REAL, kind TEXT NOT NULL, detail TEXT, source TEXT NOT NULL);
    CREATE TABLE results(test_id TEXT NOT NULL REFERENCES tests(id) ON DELETE CASCADE,
        key TEXT NOT NULL, value REAL, text TEXT, PRIMARY KEY(test_id, key));
    CREATE TABLE files(test_id TEXT NOT NULL REFERENCES tests(id) ON DELETE CASCADE,
        role TEXT NOT NULL, path TEXT NOT NULL, PRIMARY KEY(test_id, role));
    """,
    # 1 -> 2: file sizes, event lookups by test, the machine that ran the test
    """
    ALTER TABLE files ADD COLUMN bytes INTEGER;
    ALTER TABLE tests ADD COLUMN host TEXT;
    CREATE INDEX events_by_test ON events(test_id, cycle);
    """,
    # 2 -> 3: virtual test campaigns (htm.campaign): one row per planned test, keyed by its index
    # in the campaign's plan, so a re-started or retried chunk never adds a row twice
    """
    CREATE TABLE campaigns(id TEXT PRIMARY KEY, name TEXT NOT NULL, created_utc TEXT NOT NULL,
        mode TEXT NOT NULL, n_tests INTEGER NOT NULL, swept TEXT NOT NULL, body TEXT NOT NULL,
        base_spec TEXT NOT NULL);
    CREATE TABLE campaign_tests(campaign_id TEXT NOT NULL REFERENCES campaigns(id) ON DELETE CASCADE,
        idx INTEGER NOT NULL, inputs_hash TEXT NOT NULL, inputs TEXT NOT NULL, life_cycles INTEGER,
        end_reason TEXT, a_end_m REAL, max_abs_df_err_pct REAL, max_abs_peak_err_pct REAL,
        size_criterion_cycle INTEGER, valid INTEGER NOT NULL, error TEXT, wall_s REAL, worker TEXT,
        written_utc TEXT NOT NULL, PRIMARY KEY(campaign_id, idx));
    """,
    # 3 -> 4: fleet diagnosis (htm.fleet): the parameters `htm diagnose` identified, per machine and date
    """
    CREATE TABLE fleet_params(machine TEXT NOT NULL, date TEXT NOT NULL, record TEXT NOT NULL, param TEXT NOT NULL,
        value REAL NOT NULL, findings TEXT NOT NULL, unexplained INTEGER NOT NULL, diagnosed_utc TEXT NOT NULL,
        PRIMARY KEY(machine, date, record, param));
    """,
    # 4 -> 5: measurement records kept in the store for fleet diagnosis (htm.fleet): the table as
    # Parquet with its metadata JSON beside it under ROOT/fleet/MACHINE/DATE/, `path` relative to ROOT
    """
    CREATE TABLE fleet_records(machine TEXT NOT NULL, date TEXT NOT NULL, record TEXT NOT NULL, path TEXT NOT NULL,
        columns TEXT NOT NULL, samples INTEGER NOT NULL, bytes INTEGER NOT NULL, added_utc TEXT NOT NULL,
        PRIMARY KEY(machine, date, record));
    """,
    # 5 -> 6: life-test campaigns (htm.campaign.life): a test's own results beyond the crack-growth
    # columns (run-out, the 10 % / 50 % drop cycles, the stabilised loop) as JSON
    """
    ALTER TABLE campaign_tests ADD COLUMN results TEXT;
    """,
]
SCHEMA_VERSION = len(MIGRATIONS)
STATUSES = ("running", "finished", "stopped", "failed", "interrupted")
# a `running` test without a writer's lock file this young may be starting right now
STARTING_S = 60.0


def default_root(allow_url: bool = True) -> Path:
    env = os.environ.get("HTM_STORE")
    if env and (allow_url or not backend.is_postgres(env)):
        return Path(env)
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "htm" / "store"


def _now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


class Store:
    """The test store: a SQLite catalogue of tests with their per-cycle tables (Parquet), events,
    specs and files.

    Parameters
    ----------
    root : str or Path, optional
        The store's folder, created when missing (default ``$HTM_STORE``, else
        ``~/.local/share/htm/store``).

    Notes
    -----
    Tables hold SI columns (``a_m`` [m], ``delta_k_pa_sqrt_m`` [Pa·√m], forces [N], times [s]).
    ``list()`` gives every test, ``get(id)`` one test's catalogue row, ``cycles(id)`` its
    per-cycle table as numpy arrays. Use it as a context manager to close the catalogue.
    Catalogue errors raise RecordError.
    """

    def __init__(self, root: Path | str | None = None):
        # `root` a folder (catalogue.sqlite inside), or a PostgreSQL URL for the catalogue with the
        # test folders on the shared path $HTM_STORE_FILES (backend.py)
        if backend.is_postgres(root) or (root is None and backend.is_postgres(os.environ.get("HTM_STORE"))):
            url = str(root or os.environ["HTM_STORE"])
            files = os.environ.get("HTM_STORE_FILES")
            self.root = Path(files) if files else default_root(allow_url=False)
            self.path: Path | str = backend.check_url(url)
        else:
            self.root = Path(root) if root is not None else default_root()
            self.path = self.root / "catalogue.sqlite"
        if isinstance(self.path, str) or not self.path.exists():
            (self.root / "tests").mkdir(parents=True, exist_ok=True)
        self.db = backend.open_catalogue(self.path)
        version = self.db.version()
        if version > SCHEMA_VERSION:
            self.db.close()
            raise RecordError(f"catalogue {self.path} has schema version {version}, newer than this htm "
                              f"({SCHEMA_VERSION}); upgrade htm. Nothing was changed")
        self.db.migrate(MIGRATIONS)
        self.mark_interrupted()

    def mark_interrupted(self) -> list[str]:
        """Mark `interrupted` every `running` test whose writer is gone (its lock is free): the
        process was killed or the machine lost power. Its rows stay in its journal (`cycles()`
        reads them); a simulated one continues with `htm resume`. Returns the ids marked."""
        marked = []
        for test_id, created in self.db.execute("SELECT id, created_utc FROM tests WHERE status = 'running'").fetchall():
            if not self._writer_gone(test_id, created):
                continue
            try:
                segs = journal.read_journal(self.test_dir(test_id))
                last = max((int(r.arrays["cycle"][-1]) for s in segs for r in s.records
                            if r.kind == journal.CHUNK and len(r.arrays.get("cycle", []))), default=0)
                note = f"its writer stopped without closing it (killed or power lost); {last:,} cycles kept in its journal"
            except RecordError as e:
                last, note = None, f"its writer stopped without closing it; the journal does not read: {e}"
            with self._tx():
                self.db.execute("UPDATE tests SET status = 'interrupted', end_reason = 'interrupted', "
                                "cycles = COALESCE(?, cycles), updated_utc = ? WHERE id = ? AND status = 'running'",
                                (last, _now(), test_id))
                self.db.execute("INSERT INTO events VALUES (?, ?, ?, 'interrupted', ?, 'store')",
                                (test_id, last, None, note))
            marked.append(test_id)
        return marked

    def _writer_gone(self, test_id: str, created_utc: str) -> bool:
        lock = self.test_dir(test_id) / "lock"
        if not lock.exists():
            t = calendar.timegm(time.strptime(created_utc, "%Y-%m-%dT%H:%M:%SZ"))
            return time.time() - t > STARTING_S or not self.test_dir(test_id).exists()
        try:
            with open(lock, "a+") as fh:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)  # taken: a live writer holds it
                fcntl.flock(fh, fcntl.LOCK_UN)
        except OSError:
            return False
        return True

    def close(self) -> None:
        self.db.close()

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- writing ---------------------------------------------------------------------------
    def create_test(self, name: str, kind: str, mode: str | None, spec_format: str, spec_body: str,
                    frequency_hz: float | None = None) -> str:
        """A new test (status running) and its folder; returns its id (`YYYYMMDD-HHMMSS-xxxx`)."""
        test_id = time.strftime("%Y%m%d-%H%M%S", time.gmtime()) + "-" + secrets.token_hex(2)
        self.test_dir(test_id).mkdir(parents=True)
        now = _now()
        with self._tx():
            self.db.execute("INSERT INTO tests(id, name, kind, mode, status, created_utc, updated_utc, frequency_hz, host) "
                            "VALUES (?, ?, ?, ?, 'running', ?, ?, ?, ?)", (test_id, name, kind, mode, now, now, frequency_hz, os.uname().nodename))
            self.db.execute("INSERT INTO specs VALUES (?, ?, ?)", (test_id, spec_format, spec_body))
        return test_id

    def set_status(self, test_id: str, status: str, end_reason: str | None = None, cycles: int | None = None,
                   a_end_m: float | None = None) -> None:
        if status not in STATUSES:
            raise RecordError(f"status `{status}`: allowed {', '.join(STATUSES)}")
        with self._tx():
            self.db.execute("UPDATE tests SET status = ?, end_reason = COALESCE(?, end_reason), cycles = COALESCE(?, cycles), "
                            "a_end_m = COALESCE(?, a_end_m), updated_utc = ? WHERE id = ?",
                            (status, end_reason, cycles, a_end_m, _now(), test_id))

    def add_event(self, test_id: str, kind: str, detail: str = "", cycle: int | None = None, time_s: float | None = None,
                  source: str = "run") -> None:
        with self._tx():
            self.db.execute("INSERT INTO events VALUES (?, ?, ?, ?, ?, ?)", (test_id, cycle, time_s, kind, detail, source))

    def replace_events(self, test_id: str, source: str, rows: list[tuple[int | None, float | None, str, str]]) -> None:
        """Replace the events of one `source` (those rebuilt from the journal at close)."""
        with self._tx():
            self.db.execute("DELETE FROM events WHERE test_id = ? AND source = ?", (test_id, source))
            self.db.executemany("INSERT INTO events VALUES (?, ?, ?, ?, ?, ?)", [(test_id, *r, source) for r in rows])

    def set_results(self, test_id: str, results: dict[str, Any]) -> None:
        """Keep (or replace) a test's results.

        Parameters
        ----------
        test_id : str
            The test.
        results : dict
            Result name → value, SI and named with their unit (``final_a_m`` [m],
            ``max_abs_df_err_pct`` [%], ``wall_time_s`` [s]); numbers are kept as numbers, anything
            else (lists, tables) as JSON. `get` returns them under ``"results"``.
        """
        with self._tx():
            for k, v in results.items():
                num = float(v) if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) else None
                text = None if num is not None else json.dumps(v, default=float)
                self.db.execute("INSERT INTO results VALUES (?, ?, ?, ?) ON CONFLICT(test_id, key) DO UPDATE "
                                "SET value = excluded.value, text = excluded.text", (test_id, k, num, text))

    def add_file(self, test_id: str, role: str, path: Path) -> None:
        p = Path(path)
        rel = os.path.relpath(p, self.root)
        with self._tx():
            self.db.execute("INSERT INTO files VALUES (?, ?, ?, ?) ON CONFLICT(test_id, role) DO UPDATE "
                            "SET path = excluded.path, bytes = excluded.bytes", (test_id, role, rel, p.stat().st_size))

    def delete(self, test_id: str) -> None:
        """Remove a test from the catalogue and its folder."""
        self.get(test_id)
        with self._tx():
            self.db.execute("DELETE FROM tests WHERE id = ?", (test_id,))
        shutil.rmtree(self.test_dir(test_id), ignore_errors=True)

    # ---- reading ---------------------------------------------------------------------------
    def test_dir(self, test_id: str) -> Path:
        """The folder of a test's own files (journal, ``cycles.parquet``, ``raw.parquet``,
        ``recording.rrd``) under the store's root; it need not exist yet."""
        return self.root / "tests" / test_id

    def list_tests(self) -> list[dict[str, Any]]:
        """Every test in the store, oldest first.

        Returns
        -------
        list of dict
            One catalogue row per test: ``id``, ``name``, ``kind`` (simulated, virtual, rig),
            ``mode``, ``status`` (running, finished, failed, interrupted), ``created_utc``,
            ``updated_utc``, ``end_reason``, ``cycles``, final crack size ``a_end_m`` [m],
            ``frequency_hz`` [Hz] and ``host``.
        """
        cur = self.db.execute("SELECT * FROM tests ORDER BY created_utc, rowid")
        names = [d[0] for d in cur.description]
        return [dict(zip(names, r)) for r in cur.fetchall()]

    def get(self, test_id: str) -> dict[str, Any]:
        """One test with everything the catalogue holds about it (RecordError if there is none).

        Returns
        -------
        dict
            The catalogue row (as `list_tests`, a_end_m [m], frequency_hz [Hz]), plus ``spec``
            (its text) and ``spec_format``, ``events`` (``cycle``, ``time_s`` [s], ``kind``,
            ``detail``, ``source``, in cycle order), ``results`` (name → SI value, see
            `set_results`) and ``files`` (role → ``path``, ``bytes``).
        """
        cur = self.db.execute("SELECT * FROM tests WHERE id = ?", (test_id,))
        row = cur.fetchone()
        if row is None:
            raise RecordError(f"no test `{test_id}` in the store {self.root} (`htm db list` shows them)")
        d = dict(zip([c[0] for c in cur.description], row))
        fmt, body = self.db.execute("SELECT format, body FROM specs WHERE test_id = ?", (test_id,)).fetchone()
        d["spec_format"], d["spec"] = fmt, body
        d["events"] = [dict(zip(("cycle", "time_s", "kind", "detail", "source"), r)) for r in self.db.execute(
            # events without a cycle first, on SQLite and PostgreSQL alike (their NULL orders differ)
            "SELECT cycle, time_s, kind, detail, source FROM events WHERE test_id = ? ORDER BY COALESCE(cycle, -1), rowid",
            (test_id,))]
        d["results"] = {k: (v if t is None else json.loads(t)) for k, v, t in self.db.execute(
            "SELECT key, value, text FROM results WHERE test_id = ?", (test_id,))}
        d["files"] = {r: {"path": os.path.normpath(self.root / p), "bytes": b} for r, p, b in self.db.execute(
            "SELECT role, path, bytes FROM files WHERE test_id = ?", (test_id,))}
        return d

    def cycles(self, test_id: str) -> dict[str, np.ndarray]:
        """The per-cycle table: from `cycles.parquet` once the test is closed, else from its journal."""
        return self._table(test_id, "cycles.parquet", journal.CHUNK)

    def raw(self, test_id: str) -> dict[str, np.ndarray]:
        """Raw high-rate windows and live signal windows (column `t_s` first)."""
        return self._table(test_id, "raw.parquet", journal.SIGNALS)

    def export(self, test_id: str, out: str | Path, fmt: str = "parquet") -> list[Path]:
        """Write one test into the folder `out` (missing or empty): its tables (``cycles`` and
        ``raw``, as ``parquet`` or ``csv``), its other files (recording, report with plots,
        summary), ``test.json`` (catalogue row) and its spec. Returns the files written; a
        non-empty `out` raises RecordError and nothing is overwritten."""
        import pyarrow as pa
        import pyarrow.csv as pacsv
        import pyarrow.parquet as pq

        if fmt not in ("parquet", "csv"):
            raise RecordError(f"export format {fmt!r}: allowed parquet, csv")
        out = Path(out)
        if out.exists() and any(out.iterdir()):
            raise RecordError(f"{out} is not empty; nothing was overwritten")
        t = self.get(test_id)
        out.mkdir(parents=True, exist_ok=True)
        written = []
        for name, table in (("cycles", self.cycles(test_id)), ("raw", self.raw(test_id))):
            if not table:
                continue
            tab = pa.table({k: np.asarray(v) for k, v in table.items()})
            path = out / f"{name}.{fmt}"
            if fmt == "csv":
                pacsv.write_csv(tab, path)
            else:
                pq.write_table(tab, path, compression="zstd")
            written.append(path)
        written += _copy_files(t, out)
        meta = {k: t[k] for k in ("id", "name", "kind", "mode", "status", "end_reason", "cycles", "a_end_m",
                                  "created_utc", "updated_utc", "results", "events")}
        (out / "test.json").write_text(json.dumps(meta, indent=1, default=float))
        (out / f"spec.{t['spec_format']}").write_text(t["spec"])
        return [*written, out / "test.json", out / f"spec.{t['spec_format']}"]

    def _table(self, test_id: str, name: str, kind: bytes) -> dict[str, np.ndarray]:
        self.get(test_id)
        path = self.test_dir(test_id) / name
        if path.exists():
            import pyarrow.parquet as pq

            t = pq.read_table(path)
            return {c: t.column(c).to_numpy() for c in t.column_names}
        return concat([r.arrays for s in journal.read_journal(self.test_dir(test_id)) for r in s.records if r.kind == kind])

    @contextmanager
    def _tx(self) -> Iterator[None]:
        """One write transaction; a catalogue error becomes `RecordError` (nothing half-written)."""
        with self.db.tx():
            yield


def _copy_files(t: dict[str, Any], out: Path) -> list[Path]:
    """The test's other files (recording, report with its plots, summary) into `out`."""
    copied = []
    for role, f in sorted(t["files"].items()):
        src = Path(f["path"])
        if role in ("cycles", "raw") or not src.exists():
            continue
        group = [src]
        if role == "report":  # the report's plots and tables sit beside it
            group += [p for p in src.parent.iterdir() if p.suffix in (".png", ".html") or p.name == "reduced.csv"]
        for p in dict.fromkeys(group):
            if not (out / p.name).exists():
                shutil.copy2(p, out / p.name)
                copied.append(out / p.name)
    return copied


def concat(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Column-wise concatenation of row blocks (columns missing from a block are NaN there)."""
    parts = [p for p in parts if p and len(next(iter(p.values())))]
    if not parts:
        return {}
    names = list(dict.fromkeys(k for p in parts for k in p))
    out = {}
    for k in names:
        blocks = []
        for p in parts:
            n = len(next(iter(p.values())))
            blocks.append(p[k] if k in p else np.full(n, np.nan))
        out[k] = np.concatenate(blocks)
    return out
