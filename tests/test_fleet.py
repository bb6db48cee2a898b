"""Fleet diagnosis: a machine's parameter history in the catalogue and its drift flag (diagnosing a
folder of records on the Dask cluster into PostgreSQL: tests/test_campaign_services.py)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from htm.fleet import catalogue, drift
from htm.record.store import Store


def htm_here(capsys, *args: str) -> tuple[int, str, str]:
    """The command in this process (no interpreter start-up): exit code, stdout, stderr."""
    from htm.cli import main

    code = main(list(args))
    out = capsys.readouterr()
    return code, out.out, out.err


def report(leak: float, mass: float) -> dict:
    return {"final": {"params": {"leakage_coeff_m3_per_s_pa": leak, "moving_mass_kg": mass}}, "findings": [], "unexplained": False}


def test_drift_is_judged_against_the_parameters_own_scatter():
    steady = [(f"2026-0{i}-01", 1e-12 * (1 + 0.02 * s)) for i, s in enumerate([0.3, -0.5, 0.8, -0.2], start=1)]
    assert drift.judge(steady)["drift"] is False
    jumped = steady + [("2026-06-01", 1.3e-12)]
    v = drift.judge(jumped)
    assert v["drift"] is True and v["z"] > 3 and v["date"] == "2026-06-01"
    assert drift.judge(steady[:3])["drift"] is None  # two earlier dates: no scatter to judge by


def test_fleet_trend_flags_the_machine_that_drifts(tmp_path, capsys):
    store = tmp_path / "store"
    rng = np.random.default_rng(4)
    with Store(store) as s:
        for i in range(6):
            date = f"2026-{i + 1:02d}-15"
            # frame-a's leakage grows at the last date (a worn seal); frame-b stays put
            leak_a = 2e-12 * (1 + 0.02 * rng.standard_normal()) * (1.5 if i == 5 else 1.0)
            catalogue.add(s, "frame-a", date, "rec1", report(leak_a, 52 * (1 + 0.01 * rng.standard_normal())))
            catalogue.add(s, "frame-b", date, "rec1", report(3e-12 * (1 + 0.02 * rng.standard_normal()), 60.0))
        catalogue.add(s, "frame-b", "2026-06-15", "rec1", report(3e-12, 60.0))  # diagnosed again: replaced, not added
        assert len(catalogue.history(s, "frame-b")["moving_mass_kg"]) == 6
    code, out, err = htm_here(capsys, "fleet", "trend", "frame-a", "--store", str(store), "--out", str(tmp_path / "a.png"))
    assert code == 0, err
    lines = {ln.split()[0]: ln for ln in out.splitlines() if ln and not ln.startswith(("plot", "frame"))}
    assert "DRIFT" in lines["leakage_coeff_m3_per_s_pa"] and "DRIFT" not in lines["moving_mass_kg"]
    assert "frame-a: drift in leakage_coeff_m3_per_s_pa" in out and (tmp_path / "a.png").stat().st_size > 5000
    code, out, _ = htm_here(capsys, "fleet", "trend", "frame-b", "--store", str(store))
    assert code == 0 and "frame-b: no drift beyond its own scatter" in out
    code, _, err = htm_here(capsys, "fleet", "trend", "frame-z", "--store", str(store))
    assert code == 2 and "frame-a, frame-b" in err


def proving_record(folder, name: str, seed: int, effects: dict | None = None):
    """A short proving-ground record written as NAME.csv + NAME.json into `folder`; returns it and its table."""
    from htm.ident import proving, records

    rec, _ = proving.make_record(effects or {}, seed=seed, duration_s=4)
    table, _ = records.write_record(rec, folder / name)
    return rec, table


def test_records_added_to_the_store_are_diagnosed_from_it_once(tmp_path, capsys):
    from htm.ident import records

    store = tmp_path / "store"
    rec_a, table_a = proving_record(tmp_path / "in", "run1", 1, {"sensor_offset": {"channel": "p_a", "offset_pa": 4e5}})
    _, table_b = proving_record(tmp_path / "in", "run2", 2)
    code, out, err = htm_here(capsys, "fleet", "add", str(table_a), "--machine", "frame-a", "--date", "2026-03-01", "--store", str(store))
    assert code == 0, err
    assert "fleet: added frame-a 2026-03-01 run1" in out
    code, out, err = htm_here(capsys, "fleet", "add", str(table_b), "--machine", "frame-b", "--date", "2026-03-02",
                              "--name", "morning", "--store", str(store))
    assert code == 0, err
    # the store keeps the table as Parquet with its metadata beside it, and the catalogue row says where
    kept = store / "fleet" / "frame-a" / "2026-03-01" / "run1.parquet"
    back = records.read_record(kept)
    assert set(back.columns) == set(rec_a.columns) and back.meta["format"] == records.FORMAT
    assert all(np.array_equal(back.columns[c], rec_a.columns[c], equal_nan=True) for c in rec_a.columns)
    with Store(store) as s:
        held = catalogue.stored(s)
        assert list(held) == [("frame-a", "2026-03-01", "run1"), ("frame-b", "2026-03-02", "morning")]
        assert held[("frame-a", "2026-03-01", "run1")] == kept
        assert s.db.execute("SELECT samples, bytes, path FROM fleet_records WHERE record = 'run1'").fetchone() == (
            len(rec_a.columns["t"]), kept.stat().st_size, "fleet/frame-a/2026-03-01/run1.parquet")
    assert sorted(p.name for p in kept.parent.iterdir()) == ["run1.json", "run1.parquet"]  # nothing left aside
    # the same record under the same machine, date and name again: refused, nothing changed
    code, _, err = htm_here(capsys, "fleet", "add", str(table_a), "--machine", "frame-a", "--date", "2026-03-01", "--store", str(store))
    assert code == 2 and "already in the store" in err and "Traceback" not in err

    code, out, err = htm_here(capsys, "fleet", "diagnose", "--from-store", "--store", str(store), "--work-s", "1")
    assert code == 0, err
    assert "2 records in the store" in out and "0 already diagnosed in the store, diagnosing 2" in out
    assert "frame-a 2026-03-01 run1:" in out and "sensor_offset" in out and "frame-b 2026-03-02 morning:" in out
    with Store(store) as s:
        a, b = catalogue.history(s, "frame-a"), catalogue.history(s, "frame-b")
        assert catalogue.held(s) == {("frame-a", "2026-03-01", "run1"), ("frame-b", "2026-03-02", "morning")}
    assert abs(a["sensor_offset_p_a"][0][1] - 4e5) < 1e5 and a["moving_mass_kg"][0][0] == "2026-03-01"
    assert b["moving_mass_kg"][0][0] == "2026-03-02" and "sensor_offset_p_a" not in b

    # a second run diagnoses nothing again; a record added since is the only one diagnosed
    code, out, err = htm_here(capsys, "fleet", "diagnose", "--from-store", "--store", str(store), "--work-s", "1")
    assert code == 0 and "2 already diagnosed in the store, diagnosing 0" in out, out + err
    code, _, err = htm_here(capsys, "fleet", "add", str(table_b), "--machine", "frame-a", "--date", "2026-03-09", "--store", str(store))
    assert code == 0, err
    code, out, err = htm_here(capsys, "fleet", "diagnose", "--from-store", "--store", str(store), "--work-s", "1")
    assert code == 0 and "3 records in the store" in out and "2 already diagnosed in the store, diagnosing 1" in out, out + err
    assert "frame-a 2026-03-09 run2:" in out and "run1:" not in out

    code, out, err = htm_here(capsys, "fleet", "trend", "frame-a", "--store", str(store), "--out", str(tmp_path / "a.png"))
    assert code == 0, err
    line = next(ln for ln in out.splitlines() if ln.startswith("sensor_offset_p_a"))
    assert "on 2026-03-01" in line  # the offset run2 does not have: only the first date holds it
    mass = next(ln for ln in out.splitlines() if ln.startswith("moving_mass_kg"))
    assert "on 2026-03-09" in mass and "2 date(s): too little history" in mass
    assert (tmp_path / "a.png").stat().st_size > 5000


def test_fleet_store_bad_input_is_named_without_a_traceback(tmp_path, capsys):
    store = tmp_path / "store"
    rec, table = proving_record(tmp_path / "in", "good", 3)
    # a record without its position column `y`, and one without the valve command `u`
    for name, drop in (("no_y", "y"), ("no_u", "u")):
        cols = {k: v for k, v in rec.columns.items() if k != drop}
        (tmp_path / "in" / f"{name}.csv").write_text(",".join(cols) + "\n" + "\n".join(
            ",".join(repr(float(cols[c][i])) for c in cols) for i in range(len(rec.columns["t"]))) + "\n")
        (tmp_path / "in" / f"{name}.json").write_text((tmp_path / "in" / "good.json").read_text())
        code, _, err = htm_here(capsys, "fleet", "add", str(tmp_path / "in" / f"{name}.csv"), "--machine", "frame-a",
                                "--date", "2026-03-01", "--store", str(store))
        assert code == 2 and f"column `{drop}`" in err and "missing" in err and "Traceback" not in err, err
    for args, says in ((["--machine", "frame-a", "--date", "2026-13-01"], "YYYY-MM-DD"),
                       (["--machine", "../up", "--date", "2026-03-01"], "--machine '../up'")):
        code, _, err = htm_here(capsys, "fleet", "add", str(table), *args, "--store", str(store))
        assert code == 2 and says in err and "Traceback" not in err, err
    with Store(store) as s:
        assert catalogue.stored(s) == {}  # nothing half-added
    assert not (store / "fleet").exists() or not any((store / "fleet").rglob("*.parquet"))

    # an unknown store: a folder holding no catalogue is named (and not created), a database that does not answer too
    missing = tmp_path / "nowhere"
    code, _, err = htm_here(capsys, "fleet", "diagnose", "--from-store", "--store", str(missing))
    assert code == 2 and f"--store {missing}: no store there" in err and not missing.exists()
    code, _, err = htm_here(capsys, "fleet", "trend", "frame-a", "--store", str(missing))
    assert code == 2 and "no store there" in err and not missing.exists()
    code, _, err = htm_here(capsys, "fleet", "diagnose", "--from-store", "--store", "postgresql://nobody@127.0.0.1:1/nodb")
    assert code == 2 and "cannot connect" in err and "Traceback" not in err, err
    # an empty store, and both or neither of FOLDER and --from-store
    code, _, err = htm_here(capsys, "fleet", "diagnose", "--from-store", "--store", str(store))
    assert code == 2 and "holds no records" in err
    for args in ([str(tmp_path / "in"), "--from-store"], []):
        code, _, err = htm_here(capsys, "fleet", "diagnose", *args, "--store", str(store))
        assert code == 2 and "either FOLDER" in err


def test_a_version_4_catalogue_gains_the_records_table_and_keeps_its_diagnoses(tmp_path):
    import sqlite3

    from htm.record.store import MIGRATIONS, SCHEMA_VERSION

    root = tmp_path / "s"
    (root / "tests").mkdir(parents=True)
    db = sqlite3.connect(root / "catalogue.sqlite")
    db.executescript("".join(MIGRATIONS[:4]) + "PRAGMA user_version = 4;")
    db.execute("INSERT INTO fleet_params VALUES ('frame-a', '2026-01-01', 'r', 'moving_mass_kg', 52.0, '[]', 0, 't')")
    db.commit()
    db.close()
    with Store(root) as s:
        assert s.db.version() == SCHEMA_VERSION == 6
        assert catalogue.stored(s) == {} and catalogue.history(s, "frame-a") == {"moving_mass_kg": [("2026-01-01", 52.0)]}


def test_an_add_that_fails_writing_leaves_no_row_and_the_next_add_succeeds(tmp_path, monkeypatch):
    import os

    rec, _ = proving_record(tmp_path / "in", "run1", 5)
    real = os.replace

    def full_disk(src, dst):
        raise OSError(28, "No space left on device")

    with Store(tmp_path / "store") as s:
        monkeypatch.setattr(catalogue.os, "replace", full_disk)
        try:
            catalogue.put_record(s, rec, "frame-a", "2026-03-01", "run1")
            raise AssertionError("the add did not fail")
        except OSError:
            pass
        assert catalogue.stored(s) == {}  # rolled back with the files
        monkeypatch.setattr(catalogue.os, "replace", real)
        row = catalogue.put_record(s, rec, "frame-a", "2026-03-01", "run1")
        assert list(catalogue.stored(s)) == [("frame-a", "2026-03-01", "run1")] and row["bytes"] > 0


def test_re_identifying_a_rig_adds_to_its_fleet_history(tmp_path, capsys):
    """`htm fleet identify` (issue 30 item 6): each identification of a machine is kept in the fleet
    catalogue under its date, so `htm fleet trend` follows the machine's own parameters — here a
    virtual rig whose valve null drifted between two identifications (short experiments, ~15 s each)."""
    from htm.cli import main

    tag = f"fleetid-{tmp_path.name[-12:]}"
    for date, bias in (("2026-11-01", 0.12), ("2026-11-20", 0.16)):
        (tmp_path / "rig.toml").write_text(f'[bus]\ninterface = "virtual"\nchannel = "{tag}"\n[analog]\ndevice = "{tag}"\n'
                                           f'[loop]\nmode = "lockstep"\nrate_hz = 500.0\n[virtual.effects]\n'
                                           f'valve_null_bias = {{ bias_v = {bias} }}\n')
        assert main(["fleet", "identify", str(tmp_path / "rig.toml"), "--machine", "frame-1", "--date", date,
                     "--out", str(tmp_path / date), "--store", str(tmp_path / "st"), "--ramp-speeds", "5", "--sweep-s", "3"]) == 0
        assert "findings: valve_null_bias" in capsys.readouterr().out
    assert main(["fleet", "trend", "frame-1", "--store", str(tmp_path / "st"), "--json"]) == 0
    hist = json.loads(capsys.readouterr().out)["params"]["valve_null_bias_v"]["history"]
    assert [d for d, _ in hist] == ["2026-11-01", "2026-11-20"]
    assert [v for _, v in hist] == [pytest.approx(0.12, rel=0.05), pytest.approx(0.16, rel=0.05)]
