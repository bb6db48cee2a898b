"""Fleet diagnosis: a machine's parameter history in the catalogue and its drift flag (diagnosing a
folder of records on the Dask cluster into PostgreSQL: tests/test_campaign_services.py)."""
from __future__ import annotations

import numpy as np

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
