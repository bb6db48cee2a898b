"""Crack-growth scatter: per-specimen Paris fits, the joint draw, the life band campaign, the early-data update."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from htm.campaign import lifeband
from htm.campaign import spec as campaign_spec

ROOT = Path(__file__).resolve().parents[1]
SPEC = ROOT / "examples" / "virkler_mt.toml"
# the Virkler specimens inside the repository (data/virkler_2024t3/README.md: origin, licence)
VIRKLER = ROOT / "data" / "virkler_2024t3" / "virkler_a_vs_n_specimens_1_40.csv"


def virkler():
    return lifeband.read_data(VIRKLER, "a_half_crack_mm")


def test_joint_scatter_keeps_the_correlation(tmp_path):
    p = tmp_path / "j.toml"
    p.write_text(f'[campaign]\nname = "j"\nbase = "{SPEC}"\nseed = 2\n[scatter]\nsamples = 300\n[scatter.joint]\n'
                 'fields = ["law.c", "law.m"]\nlog10 = [true, false]\nmean = [-28.8, 3.08]\ncov = [[1.0, -0.1426], [-0.1426, 0.0205]]\n')
    c = campaign_spec.load(p)
    lc = np.log10([i["law.c"] for i in c.inputs])
    m = np.array([i["law.m"] for i in c.inputs])
    assert abs(lc.mean() + 28.8) < 0.15 and abs(m.mean() - 3.08) < 0.02
    assert np.corrcoef(lc, m)[0, 1] < -0.99  # drawn together, not independently
    assert c.scattered == ["law.c", "law.m"] and c.docs[7]["law"]["c"] == c.inputs[7]["law.c"]
    bad = p.read_text().replace("[-0.1426, 0.0205]]", "[0.5, 0.0205]]")
    p.write_text(bad)
    try:
        campaign_spec.load(p)
    except Exception as e:
        assert "positive definite" in str(e)
    else:
        raise AssertionError("a non-symmetric covariance was accepted")


def test_paris_fits_reproduce_each_specimens_life_and_early_points_pick_its_law():
    from htm import spec as test_spec

    datas = virkler()[:6]
    setup = lifeband.setup_of(test_spec.load(SPEC))
    models = lifeband.paris_fits(datas, setup)
    for d, m in zip(datas, models):
        life = m.life(setup, 0.009, 0.0498)["cycles"]
        assert abs(life / lifeband.life_between(d, 0.009, 0.0498) - 1) < 0.02
    j = lifeband.joint(models, datas)
    assert j.corr < -0.9 and 500 < j.point_sigma_cycles < 20_000
    # draws = the six fitted laws; a specimen's first quarter of life moves the prediction to its own life
    draws = [{"law.c": m.core_law(0.2)["c"], "law.m": m.params["m"]} for m in models]
    lives = np.array([m.life(setup, 0.009, 0.0498)["cycles"] for m in models])
    for i in (0, 3):
        actual = lifeband.life_between(datas[i], 0.009, 0.0498)
        w = lifeband.early_weights(draws, lifeband.first_points(datas[i], 60_000), setup, 0.009, j.point_sigma_cycles)
        assert abs(w.sum() - 1) < 1e-12 and w[i] > 1 / len(w)  # its own law more likely than average
        assert abs(w @ lives - actual) < abs(lives.mean() - actual)


def test_life_band_cli_builds_a_band_and_updates_from_early_data(tmp_path):
    early = tmp_path / "running.csv"
    d = virkler()[1]
    k = d.cycles <= 60_000
    early.write_text("cycles,a_m\n" + "".join(f"{n:.0f},{a:.6f}\n" for n, a in zip(d.cycles[k], d.a_m[k])))
    # specimens 1-8 of the set (the CLI's whole path; the README's numbers use all 40)
    src = (VIRKLER).read_text().splitlines()
    data = tmp_path / "virkler_1_8.csv"
    data.write_text("\n".join([src[0]] + [ln for ln in src[1:] if int(ln.split(",")[0]) <= 8]) + "\n")
    cmd = [sys.executable, "-m", "htm.cli", "life-band", str(SPEC), "--data", str(data), "--a-mm-column", "a_half_crack_mm",
           "--hold-out", "2,3", "--samples", "12", "--early", str(early), "--store", str(tmp_path / "store"),
           "--out", str(tmp_path / "out"), "--quiet"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    s = json.loads((tmp_path / "out" / "life_band.json").read_text())
    assert s["specimens_fitted"] == 6 and s["draws"] == 12 and s["held_out"] == 2
    assert 200_000 < s["life_p5"] < s["life_median"] < s["life_p95"] < 320_000
    u = s["early_update"]
    assert u["points"] == int(k.sum()) and u["p5"] <= u["median"] <= u["p95"]
    assert "updated from" in r.stdout and "held-out specimens: " in r.stdout
    # a prediction band for a new specimen, saying what it rests on (issue 33)
    assert s["band"] == "prediction" and s["rests_on_specimens"] == 6 and "resting on 6 specimens" in r.stdout


def test_a_tests_table_gives_its_early_points_thinned_and_cut():
    """The console's update reads a test's per-cycle table: one point per new crack size, up to the
    cycles asked, at most `max_points`; fewer than 2 is a SpecError."""
    from htm.errors import SpecError

    cycles = np.arange(1, 1001)
    a = 0.009 + 1e-6 * (cycles // 10)  # grows every 10 cycles: 101 sizes, the last at cycle 1000
    d = lifeband.early_from_table("t", cycles, a, max_points=30)
    assert len(d.cycles) == 30 and d.cycles[0] == 1 and d.cycles[-1] == 1000
    assert np.all(np.diff(d.a_m) > 0) and np.all(np.diff(d.cycles) > 0)
    d = lifeband.early_from_table("t", cycles, a, up_to_cycles=95)
    assert list(d.cycles) == [1, 10, 20, 30, 40, 50, 60, 70, 80, 90]
    for upto in (5, 9):
        try:
            lifeband.early_from_table("t", cycles, a, up_to_cycles=upto)
        except SpecError as e:
            assert "1 a–N point with a growing crack up to" in str(e) and "at least 2" in str(e)
        else:
            raise AssertionError("one point was accepted")
