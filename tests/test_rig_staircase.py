"""A staircase on the rig, one specimen at a time (issue 33 item 3): each force_life specimen a
test through `htm.Session` on the virtual rig (python-can virtual bus, simulated DAQ), its level
set by the last outcome, its end judged by the controller on the measured rows; the virtual rig
grips a new bar of its own per specimen (a life the controller does not know). The same sequence
code as the simulated and the Dask staircases (`htm.campaign.life.staircase_steps`)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from htm.campaign import life as life_campaign
from htm.campaign.engine import LIFE_ENDS
from htm.cli import main as htm_main
from htm.devices.config import virtual_config
from htm.fatigue import lifetest
from htm.record import Store
from htm.rigcampaign import staircase_on_rig

# a short-life bar (as tests/test_life_rig.py): a few hundred cycles to failure near 560 MPa
LIFE_TOML = """
[specimen]
geometry = "round_bar"
diameter_m = 6.35e-3
gauge_length_m = 0.025
a_init_m = 0.3e-3
load_train_n_m = 5e8
[material]
youngs_modulus_pa = 200e9
cyclic_k_prime_pa = 1200e6
cyclic_n_prime = 0.14
fatigue_strength_coefficient_pa = 1000e6
fatigue_strength_exponent = -0.09
fatigue_ductility_coefficient = 0.1
fatigue_ductility_exponent = -0.6
cyclic_transient = 0.0
fracture_toughness_pa_sqrt_m = 150e6
life_scatter_log10 = 0.0
[law]
law = "paris"
c = 1e-20
m = 2.0
[loading]
mode = "force_life"
stress_amplitude_pa = 560e6
r_ratio = -1.0
frequency_hz = 10.0
control_rate_hz = 500.0
[end]
drop = 0.5
separation = 0.1
runout_cycles = 400
"""
RIG_TRUTH = {"k_prime_factor": 1.0, "life_scatter_log10": 0.25, "seed": 40, "c_factor": 1.0}


def test_staircase_on_the_virtual_rig_follows_each_outcome(tmp_path):
    (tmp_path / "bar.toml").write_text(LIFE_TOML)
    spec = lifetest.load(tmp_path / "bar.toml")
    lc = life_campaign.staircase_plan(spec, 560e6, 25e6, 5, seed=1)
    # the load-plausibility band widened for this bar, as a lab would: at 19 kN its cracked bar's
    # transients part the load cell and the chamber pressures by > 3 kN (the default band)
    cfg = virtual_config("lockstep", 500.0, virtual={"specimen": RIG_TRUTH}, limits={"load_plausibility": {"hi": 6000.0}})
    mounted: list[tuple[int, float]] = []
    rows = staircase_on_rig(lc, cfg, virtual=True, store=tmp_path / "store", mount=lambda i, x: mounted.append((i, x)))
    levels = [x for _, x in mounted]
    assert [i for i, _ in mounted] == list(range(5))
    outcomes = [r["end_reason"] for r in rows]
    assert all(r["valid"] for r in rows), rows
    assert set(outcomes) <= set(LIFE_ENDS)
    # ISO 12107: one step up after a run-out, one down after a failure
    for k in range(1, 5):
        step = 25e6 if outcomes[k - 1] == "runout" else -25e6
        assert math.isclose(levels[k], levels[k - 1] + step), (levels, outcomes)
    assert "runout" in outcomes and any(o != "runout" for o in outcomes), f"a staircase that never turned: {outcomes}"
    runout_lives = [r["life_cycles"] for r in rows if r["end_reason"] == "runout"]
    assert all(n == 400 for n in runout_lives)
    # each specimen its own bar: the failures' lives are not one function of the level
    with Store(tmp_path / "store") as st:
        tests = st.list_tests()
    assert len(tests) == 5 and all(t["kind"] == "force_life" for t in tests), tests
    assert [t["cycles"] for t in tests] == [r["life_cycles"] for r in rows]


def test_htm_rig_staircase_cli_writes_the_sequence_and_the_estimate(tmp_path, capsys):
    (tmp_path / "bar.toml").write_text(LIFE_TOML)
    (tmp_path / "stair.toml").write_text('[life_campaign]\nkind = "staircase"\ntest = "bar.toml"\nseed = 1\n'
                                         'start_pa = 560e6\nstep_pa = 25e6\nspecimens = 4\n')
    rig = Path("examples/rig_virtual.toml").read_text()
    assert 'mode = "lockstep"' in rig
    (tmp_path / "rig.toml").write_text(rig + '\n[virtual.specimen]\nlife_scatter_log10 = 0.25\nseed = 40\n')
    code = htm_main(["rig", "staircase", str(tmp_path / "stair.toml"), "--config", str(tmp_path / "rig.toml"), "--virtual",
                     "--out", str(tmp_path / "out"), "--store", str(tmp_path / "store")])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "specimen 1 of 4: 560.0 MPa" in out
    lines = (tmp_path / "out" / "staircase.csv").read_text().splitlines()
    assert lines[0].startswith("stress_amplitude_pa,runout") and len(lines) == 5
    s = np.array([float(x.split(",")[0]) for x in lines[1:]])
    ro = np.array([int(x.split(",")[1]) for x in lines[1:]])
    assert np.allclose(np.diff(s), np.where(ro[:-1] == 1, 25e6, -25e6))
    fit = (tmp_path / "out" / "fit.json").read_text()
    assert "strength" in fit
    # a trip on the rig stops the staircase with one line, the rig safe, the outcomes so far kept
    (tmp_path / "stair5.toml").write_text('[life_campaign]\nkind = "staircase"\ntest = "bar.toml"\nseed = 1\n'
                                          'start_pa = 560e6\nstep_pa = 25e6\nspecimens = 6\n')
    capsys.readouterr()
    assert htm_main(["rig", "staircase", str(tmp_path / "stair5.toml"), "--config", str(tmp_path / "rig.toml"), "--virtual",
                     "--out", str(tmp_path / "o5"), "--store", str(tmp_path / "store5")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "load_plausibility" in err[0] and "rig is safe" in err[0], err
    assert len((tmp_path / "o5" / "staircase.csv").read_text().splitlines()) == 1 + 4
    # not a staircase: one line, exit 2
    (tmp_path / "sn.toml").write_text('[life_campaign]\nkind = "sn"\ntest = "bar.toml"\nseed = 1\nlevels_pa = [500e6, 560e6]\n'
                                      'per_level = 2\n')
    assert htm_main(["rig", "staircase", str(tmp_path / "sn.toml"), "--config", str(tmp_path / "rig.toml"), "--virtual",
                     "--out", str(tmp_path / "o2")]) == 2
