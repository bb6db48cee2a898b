"""Life tests (force_life E466, strain_life E606) on the simulated rig with the virtual round bar:
the loop holds the strain, the stabilised loops give the material's cyclic curve back, failure is
found on the measured signals near the virtual specimen's hidden life, run-outs jump, campaigns."""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from htm import core
from htm.campaign import life as life_campaign
from htm.fatigue import lifetest
from htm.fatigue.strainlife import ENData, en_fit

ROOT = Path(__file__).resolve().parents[1]
STRAIN = ROOT / "examples" / "strain_life.toml"
FORCE = ROOT / "examples" / "force_life.toml"
JUMP_EVENT = 16


@pytest.fixture(scope="module")
def strain_runs():
    """Three strain amplitudes on the example's material (no scatter), in one batch."""
    spec = lifetest.load(STRAIN).with_(life_factor=1.0)
    amps = [0.004, 0.006, 0.01]
    outs = core.run_life_batch([{**spec.config, "amplitude": a} for a in amps])
    return spec, amps, outs


def test_strain_life_stabilised_loops_give_the_cyclic_curve_back(strain_runs):
    spec, amps, outs = strain_runs
    c = spec.config
    sa, ep, n = [], [], []
    for a, o in zip(amps, outs, strict=True):
        st = lifetest.stabilised(o)
        truth = core.cyclic_stress(a, c["e_pa"], c["k_prime_pa"], c["n_prime"])
        assert abs(st["stress_amplitude_pa"] / truth - 1) < 0.03, (a, st, truth)
        assert abs(st["strain_amplitude"] / a - 1) < 0.02, (a, st)
        sa.append(st["stress_amplitude_pa"])
        ep.append(st["plastic_strain_amplitude"])
        n.append(o["cycles"])
    fit = en_fit(ENData(np.array(amps), np.array(n, float), np.array(sa), np.array(ep), c["e_pa"], np.zeros(3, bool), "sim"))
    assert abs(10 ** fit.cyclic.p / c["k_prime_pa"] - 1) < 0.10
    assert abs(fit.cyclic.q / c["n_prime"] - 1) < 0.10


def test_strain_life_failure_is_found_on_the_measured_peak_near_the_true_life(strain_runs):
    _, amps, outs = strain_runs
    for a, o in zip(amps, outs, strict=True):
        assert o["failed"], (a, o["end_reason"])
        true50 = o["truth"]["n_phi50"]
        assert o["n_drop50"] is not None and abs(o["n_drop50"] / true50 - 1) < 0.02, (a, o["n_drop50"], true50)
        assert o["n_drop10"] < o["n_drop50"]
        # the cycle jump did the work: far fewer cycles resolved than applied
        assert o["cycles_simulated"] * 10 < o["cycles"]


def test_another_material_with_softening_and_its_own_scatter_draw():
    """Nobody tuned this one: a 7075-T6-like aluminium (Dowling's table), softening 20 % over 30 cycles."""
    spec = lifetest.load(STRAIN)
    al = dict(e_pa=71e9, k_prime_pa=977e6, n_prime=0.106, sigma_f_pa=1466e6, b=-0.143, eps_f=0.262, c=-0.619,
              fracture_toughness_pa_sqrt_m=29e6, transient=0.2, transient_cycles=30.0,
              life_factor=lifetest.specimen_life_factor(0.2, 11))
    o = core.run_life({**spec.config, **al, "amplitude": 0.007})
    assert o["failed"]
    assert abs(o["n_drop50"] / o["truth"]["n_phi50"] - 1) < 0.02, (o["n_drop50"], o["truth"])
    st = lifetest.stabilised(o)
    truth = core.cyclic_stress(0.007, al["e_pa"], al["k_prime_pa"], al["n_prime"])
    assert abs(st["stress_amplitude_pa"] / truth - 1) < 0.03, (st, truth)


def test_loops_are_kept_at_logarithmic_intervals_and_the_table_has_the_e606_columns(strain_runs):
    _, _, outs = strain_runs
    o = outs[1]
    kept = sorted(set(o["loops"]["cycle"].tolist()))
    # five per decade: the first cycle of each new bucket, and the failure loop
    assert kept[0] == 1 and kept[-1] == o["cycles"]
    decades = np.floor(np.log10(kept[:-1]) * 5)
    assert len(set(decades.tolist())) == len(kept) - 1
    assert len(kept) < 5 * math.log10(o["cycles"]) + 3
    t = o["table"]
    for k in ("stress_max_pa", "stress_min_pa", "strain_max", "strain_min", "plastic_strain_range", "modulus_t_pa", "modulus_c_pa"):
        assert np.isfinite(t[k][5:-3]).all(), k
    # unloading moduli: E at the start; the crack lowers the tensile one only
    e = 200e9
    assert abs(np.nanmedian(t["modulus_c_pa"][5:50]) / e - 1) < 0.05
    before_end = np.where((t["events"] & JUMP_EVENT) == 0)[0][-3]
    assert t["modulus_t_pa"][before_end] < 0.9 * t["modulus_c_pa"][before_end]


def test_force_life_runs_out_by_cycle_jump_and_fails_by_separation():
    spec = lifetest.load(FORCE).with_(life_factor=1.0)
    low = core.run_life({**spec.config, "amplitude": 250e6 * spec.area_m2})
    assert low["end_reason"] == "runout" and low["cycles"] == 10_000_000 and not low["failed"]
    assert low["cycles_simulated"] < 200
    high = core.run_life({**spec.config, "amplitude": 450e6 * spec.area_m2})
    assert high["end_reason"] == "separation"
    assert abs(high["cycles"] / high["truth"]["n_sep"] - 1) < 0.02, (high["cycles"], high["truth"])


def test_htm_run_writes_a_life_test_and_refuses_bad_input_in_one_line(tmp_path):
    out = tmp_path / "en"
    r = subprocess.run([sys.executable, "-m", "htm.cli", "run", str(STRAIN), "--out", str(out), "--json"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert s["mode"] == "strain_life" and s["failed"] and s["end_reason"] == "load_drop"
    assert pq.read_table(out / "cycles.parquet").num_rows > 10
    loops = pq.read_table(out / "loops.parquet").to_pydict()
    assert set(loops["cycle"]) == set(s["loops_kept"])
    bad = tmp_path / "bad.toml"
    bad.write_text(STRAIN.read_text().replace("strain_amplitude = 0.006", "strain_amplitude = 0.5"))
    r = subprocess.run([sys.executable, "-m", "htm.cli", "run", str(bad), "--out", str(tmp_path / "b")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "loading.strain_amplitude" in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_staircase_next_level_follows_the_last_outcome_and_estimates_the_strength():
    spec = lifetest.load(FORCE)
    step = 15e6
    d = life_campaign.staircase_campaign(spec, 380e6, step, 8, seed=4)
    for i in range(1, len(d.stress_pa)):
        assert d.stress_pa[i] == pytest.approx(d.stress_pa[i - 1] + (step if d.runout[i - 1] else -step))
    assert d.runout.any() and (~d.runout).any()
    truth = life_campaign.true_strength(spec, 1e7)
    assert abs(truth - float(np.mean(d.stress_pa[2:]))) < 3 * step


@pytest.mark.parametrize("example", [STRAIN, FORCE])
def test_the_rig_loop_runs_the_same_controller_code_as_the_simulator(example):
    """A rig loop (one control period at a time through `LifeController` against the virtual rig's
    sensors) and the simulator give the same table, bit for bit: one copy of the logic."""
    spec = lifetest.load(example).with_(life_factor=1.0, runout_cycles=30, jump=False)
    rig = lifetest.run_on_rig(spec, core.LifeRig(spec.config))
    sim = core.run_life(spec.config)
    assert rig["end_reason"] == sim["end_reason"] == "runout" and rig["cycles"] == sim["cycles"] == 30
    for k in ("fmax_n", "fmin_n", "strain_max", "strain_min", "plastic_strain_range", "modulus_t_pa"):
        np.testing.assert_array_equal(rig["table"][k], sim["table"][k], err_msg=k)
    # and the loop holds its amplitude once started
    amp = spec.config["amplitude"]
    if spec.mode == "strain_life":
        got = 0.5 * (rig["table"]["strain_max"][-1] - rig["table"]["strain_min"][-1])
    else:
        got = 0.5 * (rig["table"]["fmax_n"][-1] - rig["table"]["fmin_n"][-1])
    assert abs(got / amp - 1) < 0.02


def test_htm_run_records_a_life_test_in_the_store_and_the_recording(tmp_path):
    from rerun.chunk import RrdReader

    from htm.record.store import Store

    store = tmp_path / "store"
    r = subprocess.run([sys.executable, "-m", "htm.cli", "run", str(STRAIN), "--out", str(tmp_path / "o"), "--json",
                        "--store", str(store)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    with Store(store) as st:
        row = st.get(s["test_id"])
        assert row["status"] == "finished" and row["end_reason"] == "load_drop" and row["cycles"] == s["cycles"]
        assert row["results"]["n_drop50"] == s["n_drop50"]
        cyc = st.cycles(s["test_id"])
        assert int(cyc["cycle"][-1]) == s["cycles"]
        rrd = Path(row["files"]["recording"]["path"])
    loops_at, series = set(), set()
    for ch in RrdReader(rrd).stream():
        if ch.is_static:
            continue
        b = ch.to_record_batch()
        if ch.entity_path == "/life/loop":
            loops_at |= set(b.column("cycle").cast("int64").to_pylist())
        else:
            series.add(ch.entity_path)
    assert loops_at == set(s["loops_kept"])
    assert {"/life/stress_pa", "/life/strain", "/life/modulus_pa", "/life/tensile_peak_n"} <= series


def test_an_sn_campaign_feeds_htm_sn_fit(tmp_path):
    """A small S-N campaign (3 levels × 3 specimens with scatter) through `htm campaign`, its
    sn.csv fitted by `htm sn fit`: the fitted slope has the sign and size of the virtual material's."""
    camp = tmp_path / "c.toml"
    camp.write_text(f'[life_campaign]\nkind = "sn"\ntest = "{FORCE}"\nseed = 2\nlevels_pa = [400e6, 450e6, 520e6]\n'
                    "specimens_per_level = 3\n")
    r = subprocess.run([sys.executable, "-m", "htm.cli", "campaign", str(camp), "--out", str(tmp_path / "o"), "--json"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert s["specimens"] == 9 and s["failures"] == 9
    r = subprocess.run([sys.executable, "-m", "htm.cli", "sn", "fit", s["data"], "--out", str(tmp_path / "fit")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    fit = json.loads((tmp_path / "fit" / "fit.json").read_text())
    # the virtual material's own local slope between the outer levels (median lives)
    spec = lifetest.load(FORCE)
    n1, n2 = life_campaign.true_life(spec, 400e6), life_campaign.true_life(spec, 520e6)
    b_true = (math.log10(n2) - math.log10(n1)) / (math.log10(520e6) - math.log10(400e6))
    assert fit["b_ci90"][0] < b_true < fit["b_ci90"][1], (fit["b"], fit["b_ci90"], b_true)
    assert fit["b"] < -3
    # the campaign wrote the same fit.json itself (its `data` names the same CSV)
    assert json.loads((tmp_path / "o" / "fit.json").read_text()) == fit


def test_strain_life_acceptance_on_the_rig_path():
    """E606 on the rig loop (one control period at a time against the virtual rig's sensors, every
    cycle resolved): a bar whose short crack grows fast enough to finish in seconds."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from life_tests import strain_on_core_loop

    r = strain_on_core_loop([0.008, 0.01, 0.012])
    for lv in r["levels"]:
        assert lv["end_reason"] in ("load_drop", "separation"), lv
        assert abs(lv["stress_err_pct"]) < 3 and abs(lv["life_err_pct"]) < 2, lv
    assert abs(r["k_prime_err_pct"]) < 10 and abs(r["n_prime_err_pct"]) < 10, r


@pytest.mark.parametrize("body, names", [
    (f'kind = "sn"\ntest = "{FORCE}"\nlevels_pa = [300e6, 400e3, 5e12]\n', "levels_pa = 5e+12"),
    (f'kind = "sn"\ntest = "{STRAIN}"\nlevels_strain = [0.004, 0.5]\n', "loading.strain_amplitude = 0.5"),
    (f'kind = "sn"\ntest = "{FORCE}"\nlevels_strain = [0.004, 0.006]\n', "give its levels as levels_pa"),
    (f'kind = "staircase"\ntest = "{FORCE}"\nstart_pa = 300e6\nstep_pa = 400e6\n', "step_pa"),
])
def test_a_bad_life_campaign_is_one_line_and_runs_nothing(tmp_path, body, names):
    """Found before the first specimen: one line naming the file and field, exit 2, the store untouched."""
    from htm.record.store import Store

    camp = tmp_path / "bad.toml"
    camp.write_text(f"[life_campaign]\n{body}")
    store = tmp_path / "store"
    r = subprocess.run([sys.executable, "-m", "htm.cli", "campaign", str(camp), "--store", str(store), "--out", str(tmp_path / "o")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and names in r.stderr and str(camp) in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    if store.exists():
        with Store(store) as s:
            assert s.db.execute("SELECT COUNT(*) FROM campaign_tests").fetchone()[0] == 0
