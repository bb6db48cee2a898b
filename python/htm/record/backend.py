"""Where the store's catalogue lives: a SQLite file (the default) or a PostgreSQL database
(`--store postgresql://USER@HOST:PORT/DB`), behind one small interface so the store's SQL and its
migrations are written once.

The SQL is written in the dialect both accept (upserts as `INSERT ... ON CONFLICT`); the few
differences are translated here: parameters `?` → `%s`, SQLite's implicit `rowid` (insertion order
of a row) → PostgreSQL's `ctid` (its physical place: insertion order for the store's insert-only
event rows), and in migrations SQLite's 8-byte `REAL`/`INTEGER` → `DOUBLE PRECISION`/`BIGINT`
(PostgreSQL's REAL is 4 bytes). The schema version is SQLite's `user_version`, and on PostgreSQL a
one-row table; migrations run under an advisory lock so processes opening a new database at once
migrate it once.

PostgreSQL credentials come from libpq's own sources (PGPASSWORD, PGPASSFILE, ~/.pgpass, PGUSER...),
never from the URL: a URL holding a password is refused, so none reaches a command line, a log,
a report or the catalogue.
"""
from __future__ import annotations

import re
import sqlite3
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from htm.errors import RecordError

PG_SCHEMES = ("postgresql://", "postgres://")
# any constant: the key of the advisory lock held while migrating a PostgreSQL catalogue
PG_MIGRATION_LOCK = 0x4854_4D20  # "HTM "


def is_postgres(where: str | Path | None) -> bool:
    return isinstance(where, str) and where.startswith(PG_SCHEMES)


def check_url(url: str) -> str:
    """The URL as it may be shown (it holds no password); raises RecordError if it does."""
    from urllib.parse import urlsplit

    try:
        parts = urlsplit(url)
    except ValueError as e:
        raise RecordError(f"--store {url.split('@')[-1]}: not a PostgreSQL URL ({e})") from None
    if parts.password is not None:
        raise RecordError("--store: the PostgreSQL URL holds a password; give it in PGPASSWORD or ~/.pgpass "
                          "(libpq's password file), never on the command line")
    return url


class SqliteCatalogue:
    kind = "sqlite"

    def __init__(self, path: Path):
        self.where = str(path)
        fresh = not path.exists()
        try:
            self.conn = sqlite3.connect(path, isolation_level=None, timeout=30.0)
            if not fresh:
                bad = self.conn.execute("PRAGMA quick_check").fetchone()[0]
                if bad != "ok":
                    raise sqlite3.DatabaseError(bad)
        except sqlite3.DatabaseError as e:
            raise RecordError(f"catalogue {path} is not readable ({e}); nothing was changed — "
                              "restore it from a backup or point --store elsewhere") from None
        self.conn.execute("PRAGMA foreign_keys = ON")

    def execute(self, sql: str, params: Sequence[Any] = ()) -> Any:
        try:
            return self.conn.execute(sql, params)
        except sqlite3.Error as e:
            raise RecordError(f"catalogue {self.where}: {e}") from None

    def executemany(self, sql: str, rows: Sequence[Sequence[Any]]) -> None:
        try:
            self.conn.executemany(sql, rows)
        except sqlite3.Error as e:
            raise RecordError(f"catalogue {self.where}: {e}") from None

    @contextmanager
    def tx(self) -> Iterator[None]:
        """One write transaction (taken at once: writers queue on the file lock, up to 30 s)."""
        self.execute("BEGIN IMMEDIATE")
        try:
            yield
            self.execute("COMMIT")
        except BaseException:
            self.conn.execute("ROLLBACK")
            raise

    def version(self) -> int:
        return int(self.execute("PRAGMA user_version").fetchone()[0])

    def migrate(self, migrations: Sequence[str]) -> None:
        for v in range(self.version(), len(migrations)):
            try:
                with self.tx():
                    if self.version() != v:  # another process migrated meanwhile
                        continue
                    for stmt in migrations[v].split(";"):
                        if stmt.strip():
                            self.execute(stmt)
                    self.execute(f"PRAGMA user_version = {v + 1}")
            except RecordError as e:
                raise RecordError(f"catalogue {self.where}: migration {v} -> {v + 1} failed ({e}); nothing was changed") from None

    def close(self) -> None:
        self.conn.close()


_PARAM = re.compile(r"\?")
_ROWID = re.compile(r"\browid\b")
_TYPES = [(re.compile(r"\bREAL\b"), "DOUBLE PRECISION"), (re.compile(r"\bINTEGER\b"), "BIGINT")]


def _pg_sql(sql: str) -> str:
    return _ROWID.sub("ctid", _PARAM.sub("%s", sql))


class PostgresCatalogue:
    kind = "postgresql"

    def __init__(self, url: str):
        import psycopg

        self.where = check_url(url)
        self._errors = psycopg.Error
        try:
            # autocommit: every statement outside `tx()` is its own transaction, as in SQLite
            self.conn = psycopg.connect(url, autocommit=True, connect_timeout=10)
        except psycopg.Error as e:
            raise RecordError(f"catalogue {self.where}: cannot connect ({_one_line(e)})") from None

    def execute(self, sql: str, params: Sequence[Any] = ()) -> Any:
        try:
            return self.conn.execute(_pg_sql(sql), params)
        except self._errors as e:
            raise RecordError(f"catalogue {self.where}: {_one_line(e)}") from None

    def executemany(self, sql: str, rows: Sequence[Sequence[Any]]) -> None:
        try:
            self.conn.cursor().executemany(_pg_sql(sql), rows)
        except self._errors as e:
            raise RecordError(f"catalogue {self.where}: {_one_line(e)}") from None

    @contextmanager
    def tx(self) -> Iterator[None]:
        try:
            with self.conn.transaction():
                yield
        except self._errors as e:
            raise RecordError(f"catalogue {self.where}: {_one_line(e)}") from None

    def version(self) -> int:
        if self.execute("SELECT to_regclass('htm_schema')").fetchone()[0] is None:
            return 0
        row = self.execute("SELECT version FROM htm_schema").fetchone()
        return 0 if row is None else int(row[0])

    def migrate(self, migrations: Sequence[str]) -> None:
        if self.version() >= len(migrations):
            return
        try:
            with self.tx():
                self.execute("SELECT pg_advisory_xact_lock(?)", (PG_MIGRATION_LOCK,))
                self.execute("CREATE TABLE IF NOT EXISTS htm_schema(version BIGINT NOT NULL)")
                start = self.version()
                for v in range(start, len(migrations)):
                    for stmt in migrations[v].split(";"):
                        if stmt.strip():
                            for pat, repl in _TYPES:
                                stmt = pat.sub(repl, stmt)
                            self.execute(stmt)
                self.execute("DELETE FROM htm_schema")
                self.execute("INSERT INTO htm_schema VALUES (?)", (len(migrations),))
        except RecordError as e:
            raise RecordError(f"migration to schema {len(migrations)} failed ({e}); nothing was changed") from None

    def close(self) -> None:
        self.conn.close()


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split())


def open_catalogue(where: str | Path) -> SqliteCatalogue | PostgresCatalogue:
    """The catalogue at a PostgreSQL URL or a SQLite file path."""
    if is_postgres(where):
        return PostgresCatalogue(str(where))
    return SqliteCatalogue(Path(where))
