"""Campaigns and the catalogue on real services: a Dask scheduler with two workers and a PostgreSQL
server, both on localhost, started by tools/services.sh (`make test` and .ci/run do). Without them
these tests fail: they are never skipped."""
from __future__ import annotations

import json
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


# ---- life campaigns (S-N, ε-N, staircase) on the cluster --------------------------------------------

FORCE_LIFE = ROOT / "examples" / "force_life.toml"
STRAIN_LIFE = ROOT / "examples" / "strain_life.toml"
LIFE_RESULTS = ("idx", "loading.stress_amplitude_pa", "loading.strain_amplitude", "material.life_factor", "life_cycles",
                "end_reason", "valid", "error", "results")


def life_file(tmp_path: Path, name: str, body: str) -> Path:
    p = tmp_path / f"{name}.toml"
    p.write_text(f'[life_campaign]\nname = "{name}"\n{body}')
    return p


def same_life(rows_a, rows_b) -> None:
    assert [tuple(r.get(k) for k in LIFE_RESULTS) for r in rows_a] == [tuple(r.get(k) for k in LIFE_RESULTS) for r in rows_b]


def on_workers(rows, client) -> None:
    """Every row was run by one of the cluster's worker processes (not here, not in a CLI process)."""
    pids = {str(p) for p in client.run(os.getpid).values()}
    assert {r["worker"].split(":")[1] for r in rows} <= pids, ([r["worker"] for r in rows], pids)


def test_sn_campaign_on_dask_into_postgresql_gives_the_local_data_and_fit(tmp_path, client):
    """`htm campaign` of an S-N campaign (3 levels × 2 force_life specimens, run-outs at 10⁷ at the
    lowest level) on the Dask workers into PostgreSQL, against the same file run here into SQLite:
    the same specimens, lives, run-out flags and fit.json; run again, it runs nothing."""
    from htm.campaign import life

    pg, dask = service("HTM_TEST_PG"), service("HTM_TEST_DASK")
    name = f"sn-{os.getpid()}-{time.time_ns()}"  # the database outlives the test: a campaign of its own
    p = life_file(tmp_path, name, f'kind = "sn"\ntest = "{FORCE_LIFE}"\nseed = 3\nchunk_tests = 2\n'
                                  "levels_pa = [320e6, 400e6, 460e6]\nspecimens_per_level = 2\n")
    env = dict(os.environ, HTM_STORE_FILES=str(tmp_path / "files"))
    lc = life.load(p)  # here: the same functions `htm campaign` calls, into SQLite
    with Store(tmp_path / "sqlite") as s:
        ran_here = life.run(lc, s, engine.local_runner(), progress=False)["ran"]
        loc = life.outputs(lc, engine.table(s, lc.campaign.id), tmp_path / "local")
    cmd = [sys.executable, "-m", "htm.cli", "campaign", str(p), "--out", str(tmp_path / "dask"), "--quiet", "--json",
           "--store", pg, "--cluster", dask]
    c = lc.campaign
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=180, env=env)
        assert r.returncode == 0, r.stderr
        rem = json.loads(r.stdout)
        assert rem["where"].startswith("Dask") and rem["session"]["ran"] == 6 == ran_here
        assert (rem["specimens"], rem["failures"], rem["runouts"]) == (loc["specimens"], loc["failures"], loc["runouts"])
        assert rem["runouts"] >= 1 and rem["failures"] >= 3  # run-outs flagged, a curve to fit
        assert (tmp_path / "dask" / "sn.csv").read_text() == (tmp_path / "local" / "sn.csv").read_text()
        fits = [json.loads((tmp_path / w / "fit.json").read_text()) for w in ("local", "dask")]
        for f in fits:
            f.pop("data")
        assert fits[0] == fits[1] and fits[0]["method"] == "maximum_likelihood" and fits[0]["b"] < -3
        with Store(pg) as s:
            rows = engine.table(s, c.id)
        with Store(tmp_path / "sqlite") as s:
            same_life(rows, engine.table(s, c.id))
        assert len(rows) == 6 and [r["loading.stress_amplitude_pa"] for r in rows] == [320e6] * 2 + [400e6] * 2 + [460e6] * 2
        assert [r["results"]["runout"] for r in rows] == [r["end_reason"] == "runout" for r in rows]
        assert all(r["life_cycles"] == 10_000_000 for r in rows if r["results"]["runout"])
        on_workers(rows, client)
        again = subprocess.run(cmd, capture_output=True, text=True, timeout=180, env=env)
        assert again.returncode == 0, again.stderr
        a = json.loads(again.stdout)
        assert (a["session"]["skipped"], a["session"]["ran"]) == (6, 0)
    finally:
        with Store(pg) as s:  # the database outlives this test
            s.db.execute("DELETE FROM campaign_tests WHERE campaign_id = ?", (c.id,))
            s.db.execute("DELETE FROM campaigns WHERE id = ?", (c.id,))


def test_strain_life_campaign_on_dask_gives_the_local_loops_and_fit(tmp_path, client):
    """An ε-N campaign (strain_life specimens at three strain amplitudes) on the workers: the same
    lives, stabilised loops and ε-N fit as on this machine's cores."""
    from htm.campaign import life

    p = life_file(tmp_path, "en", f'kind = "sn"\ntest = "{STRAIN_LIFE}"\nseed = 4\nchunk_tests = 1\n'
                                  "levels_strain = [0.005, 0.006, 0.008]\nspecimens_per_level = 1\n")
    got = {}
    for where, runner in (("local", engine.local_runner()), ("dask", cluster.runner(client))):
        lc = life.load(p)
        with Store(tmp_path / f"store-{where}") as s:
            out = life.run(lc, s, runner, progress=False)
            rows = engine.table(s, lc.campaign.id)
        assert out["ran"] == 3
        summary = life.outputs(lc, rows, tmp_path / where)
        got[where] = (rows, summary, json.loads((tmp_path / where / "fit.json").read_text()))
    (lrows, lsum, lfit), (rrows, rsum, rfit) = got["local"], got["dask"]
    same_life(lrows, rrows)
    on_workers(rrows, client)
    keys = ("specimens", "failures", "runouts", "truth")
    assert [lsum[k] for k in keys] == [rsum[k] for k in keys] and rsum["failures"] == 3
    assert all(r["end_reason"] in ("load_drop", "separation") and r["results"]["stabilised"]["stress_amplitude_pa"] > 3e8 for r in rrows)
    assert (tmp_path / "dask" / "en.csv").read_text() == (tmp_path / "local" / "en.csv").read_text()
    lfit.pop("data"), rfit.pop("data")
    assert lfit == rfit and "sigma_f_pa" in rfit and "K_prime_pa" in rfit


def test_staircase_on_dask_one_specimen_per_task_follows_the_local_sequence_and_resumes(tmp_path, client):
    """A staircase on the cluster: every specimen one task, its level from the outcome before it;
    stopped after four specimens and started again, it replays the stored outcomes, runs the rest,
    and ends with the sequence (levels, lives, run-outs) the local run gives."""
    from htm.campaign import life

    p = life_file(tmp_path, "stair", f'kind = "staircase"\ntest = "{FORCE_LIFE}"\nseed = 4\n'
                                     "start_pa = 365e6\nstep_pa = 15e6\nspecimens = 8\n")
    lc = life.load(p)
    with Store(tmp_path / "local") as s:
        life.run(lc, s, engine.local_runner(), progress=False)
        local = engine.table(s, lc.campaign.id)
    tasks = []

    def stopping(runner, after: int):
        def run(chunks, mode):
            tasks.append([i for ch in chunks for i, _ in ch])
            if len(tasks) > after:
                raise KeyboardInterrupt
            yield from runner(chunks, mode)
        return run

    with Store(tmp_path / "dask") as s:
        with pytest.raises(KeyboardInterrupt):
            life.run(life.load(p), s, stopping(cluster.runner(client), 4), progress=False)
        assert len(engine.held(s, lc.campaign.id)) == 4
        again = life.run(life.load(p), s, cluster.runner(client), progress=False)
        remote = engine.table(s, lc.campaign.id)
    assert tasks[:4] == [[0], [1], [2], [3]]  # one specimen per task, in order
    assert (again["skipped"], again["ran"]) == (4, 4)
    same_life(local, remote)
    on_workers(remote, client)
    lv = [r["loading.stress_amplitude_pa"] for r in remote]
    ro = [r["results"]["runout"] for r in remote]
    assert any(ro) and not all(ro)
    for i in range(1, len(lv)):
        assert lv[i] == pytest.approx(lv[i - 1] + (15e6 if ro[i - 1] else -15e6))
