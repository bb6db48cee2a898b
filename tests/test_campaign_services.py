"""Campaigns and the catalogue on real services: a Dask scheduler with two workers and a PostgreSQL
server, both on localhost, started by tools/services.sh (`make test` and .ci/run do). Without them
these tests fail: they are never skipped."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from htm.campaign import cluster, engine
from htm.campaign import spec as campaign_spec
from htm.campaign.stress import concurrent_writes
from htm.record.store import Store

ROOT = Path(__file__).resolve().parents[1]
BASE = ROOT / "examples" / "ct_constant_force.toml"


def service(var: str) -> str:
    v = os.environ.get(var)
    if not v:
        pytest.fail(f"{var} is not set: run the tests through tools/services.sh (`make test` and .ci/run do)")
    return v


@pytest.fixture(scope="module")
def client():
    c = cluster.connect(service("HTM_TEST_DASK"))
    c.wait_for_workers(2, timeout=60)
    yield c
    c.close()


def campaign(tmp_path: Path, n_mc: int, chunk: int, name: str) -> campaign_spec.Campaign:
    p = tmp_path / f"{name}.toml"
    p.write_text(f'[campaign]\nname = "{name}"\nbase = "{BASE}"\nchunk_tests = {chunk}\nseed = 5\n'
                 f'[grid]\n"loading.delta_f_n" = [3800.0, 4450.0]\n'
                 f'[scatter]\nsamples = {n_mc}\n"law.c" = {{ lognormal_sigma = 0.3 }}\n')
    return campaign_spec.load(p)


RESULTS = ("idx", "life_cycles", "end_reason", "a_end_m", "max_abs_df_err_pct", "max_abs_peak_err_pct", "valid")


def same(rows_a, rows_b) -> None:
    assert [tuple(r[k] for k in RESULTS) for r in rows_a] == [tuple(r[k] for k in RESULTS) for r in rows_b]


def test_campaign_on_dask_gives_the_in_process_table(tmp_path, client):
    c = campaign(tmp_path, 4, 2, "small")
    with Store(tmp_path / "local") as s:
        engine.run(c, s, engine.local_runner(), progress=False)
        local = engine.table(s, c.id)
    with Store(tmp_path / "dask") as s:
        out = engine.run(c, s, cluster.runner(client), progress=False)
        remote = engine.table(s, c.id)
    assert out["ran"] == len(c) == 8
    same(local, remote)
    # both workers took part (results are not all from this process)
    assert len({r["worker"] for r in remote}) == 2 and all(r["worker"].split(":")[1] != str(os.getpid()) for r in remote)


def test_a_worker_killed_mid_campaign_loses_and_repeats_nothing(tmp_path, client):
    c = campaign(tmp_path, 10, 2, "killed")  # 20 tests in 10 chunks
    with Store(tmp_path / "local") as s:
        engine.run(c, s, engine.local_runner(), progress=False)
        local = engine.table(s, c.id)
    pids = client.run(os.getpid)  # {worker address: pid}
    victim = sorted(pids.values())[0]
    url = tmp_path / "dask"
    at_kill = {}

    def kill_when_started():
        # once the first chunk is in the store, SIGKILL one worker process (its nanny restarts it)
        with Store(url) as s:
            t0 = time.monotonic()
            while time.monotonic() - t0 < 60:
                n = s.db.execute("SELECT COUNT(*) FROM campaign_tests").fetchone()[0] if _has_table(s) else 0
                if n >= 2:
                    at_kill["rows"] = n
                    os.kill(victim, signal.SIGKILL)
                    return
                time.sleep(0.05)

    Store(url).close()
    killer = threading.Thread(target=kill_when_started, daemon=True)
    killer.start()
    with Store(url) as s:
        out = engine.run(c, s, cluster.runner(client), progress=False)
        remote = engine.table(s, c.id)
    killer.join(timeout=30)
    assert 2 <= at_kill.get("rows", 0) < len(c), at_kill  # the kill came mid-campaign
    assert out["ran"] == len(c)
    same(local, remote)  # every test once, with the same results
    client.wait_for_workers(2, timeout=60)  # the nanny brought the worker back for the next tests


def _has_table(s: Store) -> bool:
    try:
        s.db.execute("SELECT 1 FROM campaign_tests LIMIT 1")
        return True
    except Exception:
        return False


def test_campaign_cli_on_dask_into_postgresql(tmp_path):
    pg, dask = service("HTM_TEST_PG"), service("HTM_TEST_DASK")
    p = tmp_path / "cli.toml"
    p.write_text(f'[campaign]\nname = "cli"\nbase = "{BASE}"\nchunk_tests = 2\n'
                 f'[grid]\n"loading.frequency_hz" = [5.0, 10.0]\n[scatter]\nsamples = 2\n"law.m" = {{ normal_sd = 0.05 }}\n')
    env = dict(os.environ, HTM_STORE_FILES=str(tmp_path / "files"))
    cmd = [sys.executable, "-m", "htm.cli", "campaign", str(p), "--store", pg, "--cluster", dask, "--out", str(tmp_path / "out"), "--quiet"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=env)
    assert r.returncode == 0, r.stderr
    assert "4/4 tests in the store" in r.stdout and (tmp_path / "out" / "life.png").stat().st_size > 10_000
    r2 = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=env)
    assert "(4 already there, 0 run now" in r2.stdout
    # the password is nowhere: not in the output, not in the catalogue
    password = Path(os.environ["PGPASSFILE"]).read_text().strip().split(":")[-1]
    with Store(pg) as s:
        dump = repr(s.db.execute("SELECT * FROM campaigns").fetchall()) + repr(s.db.execute("SELECT * FROM campaign_tests").fetchall())
    assert password not in r.stdout + r.stderr + dump


def test_store_on_postgresql_keeps_a_test_as_sqlite_does(tmp_path, monkeypatch):
    monkeypatch.setenv("HTM_STORE_FILES", str(tmp_path / "files"))
    got = []
    for where in (service("HTM_TEST_PG"), str(tmp_path / "sqlite")):
        with Store(where) as s:
            tid = s.create_test("pg-roundtrip", "simulated", "jump", "toml", "x = 1", 10.0)
            s.add_event(tid, "note", "first", cycle=5)
            s.add_event(tid, "note", "second", cycle=5)
            s.add_event(tid, "note", "no cycle")  # NULL cycle: first on both (their NULL orders differ)
            s.set_results(tid, {"cycles": 12345, "gains": {"k1": 0.5}})
            s.set_results(tid, {"cycles": 12346})  # an upsert, not a second row
            s.set_status(tid, "finished", "target_crack_length", 12346, 0.03)
            d = s.get(tid)
            got.append((d["status"], d["cycles"], d["a_end_m"], [e["detail"] for e in d["events"]], d["results"]))
            assert tid in [t["id"] for t in s.list_tests()]
            s.delete(tid)
    assert got[0] == got[1] == ("finished", 12346, 0.03, ["no cycle", "first", "second"], {"cycles": 12346.0, "gains": {"k1": 0.5}})


@pytest.mark.parametrize("backend", ["sqlite", "postgresql"])
def test_four_concurrent_writers_lose_nothing(tmp_path, backend):
    where = service("HTM_TEST_PG") if backend == "postgresql" else str(tmp_path / "store")
    r = concurrent_writes(where, writers=4, rows_per_writer=40)
    assert (r["rows_found"], r["rows_lost"], r["rows_duplicated"], r["writer_failures"]) == (160, 0, 0, 0), r


def test_pg_role_reaches_only_its_own_database():
    import psycopg

    url = service("HTM_TEST_PG")
    with pytest.raises(psycopg.OperationalError):
        psycopg.connect(url.rsplit("/", 1)[0] + "/postgres", connect_timeout=5).close()
    with psycopg.connect(url, connect_timeout=5) as conn:
        su = conn.execute("SELECT rolsuper OR rolcreatedb OR rolcreaterole FROM pg_roles WHERE rolname = current_user").fetchone()[0]
    assert su is False


def test_fleet_diagnosis_on_dask_into_postgresql(tmp_path):
    from htm.fleet import catalogue
    from htm.ident import proving, records

    pg, dask = service("HTM_TEST_PG"), service("HTM_TEST_DASK")
    folder = tmp_path / "fleet"
    rec, _ = proving.make_record({"sensor_offset": {"channel": "p_a", "offset_pa": 4e5}}, seed=1, duration_s=4)
    (folder / "frame-a" / "2026-03-01").mkdir(parents=True)
    records.write_record(rec, folder / "frame-a" / "2026-03-01" / "run1")
    cmd = [sys.executable, "-m", "htm.cli", "fleet", "diagnose", str(folder), "--store", pg, "--cluster", dask, "--work-s", "1"]
    env = dict(os.environ, HTM_STORE_FILES=str(tmp_path / "files"))
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env)
    assert r.returncode == 0, r.stderr
    assert "frame-a 2026-03-01 run1:" in r.stdout and "sensor_offset" in r.stdout
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env)
    assert "1 already diagnosed in the store, diagnosing 0" in again.stdout, again.stdout + again.stderr
    with Store(pg) as s:
        h = catalogue.history(s, "frame-a")
        s.db.execute("DELETE FROM fleet_params WHERE machine = 'frame-a'")  # the database outlives this test
    assert abs(h["sensor_offset_p_a"][0][1] - 4e5) < 1e5 and h["moving_mass_kg"][0][0] == "2026-03-01"


def test_fleet_records_added_to_postgresql_are_diagnosed_on_dask(tmp_path):
    from htm.fleet import catalogue
    from htm.ident import proving, records

    pg, dask = service("HTM_TEST_PG"), service("HTM_TEST_DASK")
    rec, _ = proving.make_record({"sensor_offset": {"channel": "p_a", "offset_pa": 4e5}}, seed=1, duration_s=4)
    table, _ = records.write_record(rec, tmp_path / "in" / "run1")
    env = dict(os.environ, HTM_STORE_FILES=str(tmp_path / "files"))  # the records' Parquet on the shared path
    add = [sys.executable, "-m", "htm.cli", "fleet", "add", str(table), "--machine", "frame-s", "--date", "2026-04-01", "--store", pg]
    r = subprocess.run(add, capture_output=True, text=True, timeout=120, env=env)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "files" / "fleet" / "frame-s" / "2026-04-01" / "run1.parquet").is_file()
    cmd = [sys.executable, "-m", "htm.cli", "fleet", "diagnose", "--from-store", "--store", pg, "--cluster", dask, "--work-s", "1"]
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env)
        assert r.returncode == 0, r.stderr
        assert "frame-s 2026-04-01 run1:" in r.stdout and "sensor_offset" in r.stdout
        again = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env)
        assert "1 already diagnosed in the store, diagnosing 0" in again.stdout, again.stdout + again.stderr
        with Store(pg) as s:
            h = catalogue.history(s, "frame-s")
        assert abs(h["sensor_offset_p_a"][0][1] - 4e5) < 1e5 and h["moving_mass_kg"][0][0] == "2026-04-01"
    finally:
        with Store(pg) as s:  # the database outlives this test
            s.db.execute("DELETE FROM fleet_params WHERE machine = 'frame-s'")
            s.db.execute("DELETE FROM fleet_records WHERE machine = 'frame-s'")
