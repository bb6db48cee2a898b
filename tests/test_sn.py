"""S-N analysis (issue 33): E739, maximum likelihood with run-outs, staircase, strain-life, Miner,
the `htm sn` / `htm en` commands and their handling of bad input."""
from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest
from scipy import stats

import htm
from htm.cli import main
from htm.fatigue import sn, staircase, strainlife

K, SIGMA = 7.0, 0.22
A = 6 + K * math.log10(300e6)  # N = 1e6 at 300 MPa
LEVELS = np.array([400, 350, 300, 260, 225]) * 1e6


def _data(seed: int, levels=LEVELS, per=6, a=A, k=K, sigma=SIGMA, runout=1e7) -> sn.SNData:
    return sn.simulate_sn(a, -k, sigma, levels, per, runout, np.random.default_rng(seed))


def test_e739_matches_an_independent_least_squares_and_its_t_intervals():
    d = _data(1, runout=1e12)
    f = sn.fit_e739(d)
    r = stats.linregress(np.log10(d.stress_pa), np.log10(d.cycles))
    t = stats.t.ppf(0.95, len(d.cycles) - 2)
    assert f.b == pytest.approx(r.slope, rel=1e-10) and f.a == pytest.approx(r.intercept, rel=1e-10)
    assert f.b_ci90 == pytest.approx((r.slope - t * r.stderr, r.slope + t * r.stderr), rel=1e-9)
    assert f.a_ci90 == pytest.approx((r.intercept - t * r.intercept_stderr, r.intercept + t * r.intercept_stderr), rel=1e-9)
    assert f.linearity["applicable"] and f.linearity["df"] == [3, 25]
    # prediction band for a new specimen is wider than the median's confidence band, which narrows at the centre
    s = np.array([LEVELS.min(), 10 ** f.x_mean, LEVELS.max()])
    clo, chi = f.confidence_band(s)
    plo, phi = f.prediction_band(s)
    assert np.all(phi - plo > chi - clo) and (chi - clo)[1] < (chi - clo)[0]


def test_linearity_test_says_when_it_does_not_apply_and_rejects_a_bent_curve():
    d = _data(2, levels=LEVELS[:2], runout=1e12)
    assert not sn.fit_e739(d).linearity["applicable"]
    assert "replicates at 3 or more" in sn.fit_e739(d).linearity["reason"]
    x = np.repeat(np.linspace(8.3, 8.7, 5), 6)
    y = 60 - 6 * x + 8 * (x - 8.5) ** 2 + 0.02 * np.random.default_rng(0).standard_normal(30)  # curved in log-log
    bent = sn.SNData(10 ** x, 10 ** y, np.zeros(30, bool))
    assert sn.fit_e739(bent).linearity["linear"] is False


def test_maximum_likelihood_without_runouts_is_exactly_e739():
    d = _data(3, runout=1e12)
    e, m = sn.fit_e739(d), sn.fit_ml(d)
    assert m.a == pytest.approx(e.a, rel=1e-7) and m.b == pytest.approx(e.b, rel=1e-7)
    assert m.sigma_log10_n == pytest.approx(e.sigma_log10_n, rel=1e-5)
    assert m.b_ci90 == pytest.approx(e.b_ci90, rel=1e-5) and m.a_ci90 == pytest.approx(e.a_ci90, rel=1e-5)
    assert m.sigma_ci90[0] < e.sigma_log10_n < m.sigma_ci90[1]


def test_runouts_censored_recover_the_curve_that_counting_them_as_failures_biases():
    # a heavily censored set: half the lowest levels run out at 1e6
    d = _data(4, levels=np.array([400, 350, 300, 270, 250]) * 1e6, per=12, runout=1e6)
    assert 10 < d.n_runouts < 40
    ml, raf = sn.fit_ml(d), sn.fit_e739(d, runouts_as_failures=True)
    assert ml.b_ci90[0] <= -K <= ml.b_ci90[1]
    assert abs(ml.b + K) < 0.5 * abs(raf.b + K)  # counting run-outs as failures flattens the curve
    assert raf.b > -K and raf.sigma_log10_n < SIGMA  # flatter and with too little scatter


def test_maximum_likelihood_agrees_with_pylife_maxlikefull_above_the_knee():
    import pandas as pd
    from pylife.materialdata import woehler
    from pylife.utils.functions import scattering_range_to_std

    # failures on four levels above the knee, run-outs far below it (where Basquin's life is >> 1e7)
    d0 = _data(5, levels=np.array([450, 400, 350, 300]) * 1e6, runout=1e12)
    d = sn.SNData(np.r_[d0.stress_pa, [120e6] * 5, [100e6] * 5], np.r_[d0.cycles, [1e7] * 10],
                  np.r_[d0.runout, [True] * 10])
    df = pd.DataFrame({"load": d.stress_pa / 1e6, "cycles": d.cycles, "fracture": ~d.runout})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # the fatigue limit and its scatter (SD, TS) do not enter the finite zone's likelihood: fixed, so that
        # pyLife's simplex has only k, N_D and T_N to find (17 s of CPU otherwise)
        ref = woehler.MaxLikeFull(df).use_all_fractures().analyze(fixed_parameters={"SD": 110.0, "TS": 1.2})
    ours = sn.fit_ml(d).mle
    assert -ours["b"] == pytest.approx(ref.k_1, rel=2e-4)
    assert ours["sigma_log10_n"] == pytest.approx(scattering_range_to_std(ref.TN), rel=2e-4)


def test_staircase_dixon_mood_by_hand_and_within_one_step_on_simulated_specimens():
    # x failure, o run-out on levels 200 + 10·i MPa
    lv = np.array([2, 1, 0, 1, 2, 1, 2, 3, 2, 1, 2, 1, 0, 1, 2]) * 10e6 + 200e6
    ro = np.array([0, 0, 1, 1, 0, 1, 1, 0, 0, 1, 0, 0, 1, 1, 0], bool)
    st = staircase.dixon_mood(lv, ro)
    # the first specimen goes (the outcome first changes at the third); of the 14 left, 7 failures and
    # 7 run-outs: failures counted (a tie), at 210 MPa (i = 0) 2, 220 (i = 1) 4, 230 (i = 2) 1
    assert st.event == "failures" and st.step_pa == pytest.approx(10e6) and st.n_used == 14
    F, A, B = 7, 4 + 2, 4 + 4
    assert st.strength_pa == pytest.approx(210e6 + 10e6 * (A / F - 0.5))
    ratio = (F * B - A * A) / F ** 2
    assert st.ratio == pytest.approx(ratio)
    assert st.sd_pa == pytest.approx(1.62 * 10e6 * (ratio + 0.029) if ratio >= 0.3 else 0.53 * 10e6)
    hits = 0
    for seed in range(20):
        s, r = staircase.simulate_staircase(180e6, 8e6, 200e6, 8e6, 15, np.random.default_rng(seed))
        hits += abs(staircase.dixon_mood(s, r).strength_pa - 180e6) <= 8e6
    assert hits >= 18


def test_strain_life_recovers_the_material_and_its_cyclic_curve():
    true = dict(sigma_f_pa=900e6, b=-0.09, epsilon_f=0.4, c=-0.6, modulus_pa=200e9)
    d = strainlife.simulate_en(**true, strains=np.array([0.002, 0.003, 0.005, 0.008, 0.012]), per_level=4,
                               sigma_log10_life=0.1, rng=np.random.default_rng(7))
    f = strainlife.en_fit(d)
    assert abs(f.basquin.q / true["b"] - 1) < 0.1 and abs(f.coffin.q / true["c"] - 1) < 0.1
    assert abs(f.sigma_f_pa / true["sigma_f_pa"] - 1) < 0.1 and abs(f.epsilon_f / true["epsilon_f"] - 1) < 0.3
    n_prime, k_prime = true["b"] / true["c"], true["sigma_f_pa"] / true["epsilon_f"] ** (true["b"] / true["c"])
    assert f.cyclic.q == pytest.approx(n_prime, rel=0.1) and 10 ** f.cyclic.p == pytest.approx(k_prime, rel=0.1)
    lo, med, hi = f.prediction_band([0.004])
    assert lo[0] < med[0] < hi[0] and 0.2 < hi[0] - lo[0] < 1.5


def test_miner_damage_of_a_constant_amplitude_history_is_n_over_N():
    f = sn.fit_e739(_data(8, runout=1e12))
    hist = np.tile([300e6, -300e6], 500)  # 500 cycles (about 1000 reversals) at 300 MPa amplitude
    res = htm.miner_damage(hist, f)
    n_life = 10 ** float(f.median_log10_n(300e6))
    assert res["cycles_counted"] == pytest.approx(499.5, abs=0.6)
    assert res["damage_median"] == pytest.approx(res["cycles_counted"] / n_life, rel=1e-9)
    assert res["damage_lower_band"] > res["damage_median"]


def test_sn_fit_cli_writes_fit_json_and_report(tmp_path, capsys):
    p = sn.write_sn_csv(tmp_path / "sn.csv", _data(9))
    assert main(["sn", "fit", str(p), "--out", str(tmp_path / "o")]) == 0
    text = capsys.readouterr().out
    assert "log10 S[MPa]" in text and "Basquin exponent" in text
    doc = json.loads((tmp_path / "o" / "fit.json").read_text())
    for key in ("a", "b", "a_ci90", "b_ci90", "sigma_log10_n", "n_specimens", "n_failures", "n_runouts", "method"):
        assert key in doc
    assert doc["n_specimens"] == 30 and doc["a_ci90"][0] < doc["a"] < doc["a_ci90"][1]
    assert "resting on 30 specimens" in doc["prediction_band_90"]["note"]
    assert (tmp_path / "o" / "sn_curve.png").stat().st_size > 10_000 and (tmp_path / "o" / "report.html").exists()
    assert main(["sn", "fit", str(p), "--out", str(tmp_path / "o2"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["b"] == pytest.approx(doc["b"])
    assert htm.sn_fit(p).b == pytest.approx(doc["b"])


def test_sn_damage_and_staircase_and_en_commands(tmp_path, capsys):
    p = sn.write_sn_csv(tmp_path / "sn.csv", _data(10))
    main(["sn", "fit", str(p), "--out", str(tmp_path / "f")])
    (tmp_path / "h.csv").write_text("stress_mpa\n" + "\n".join(["250", "-250"] * 100) + "\n")
    capsys.readouterr()
    assert main(["sn", "damage", str(tmp_path / "h.csv"), "--fit", str(tmp_path / "f" / "fit.json"), "--column", "stress_mpa",
                 "--scale", "1e6", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["cycles_counted"] == pytest.approx(99.5, abs=0.6)
    lv = np.array([2, 1, 0, 1, 2, 1, 2, 3, 2, 1]) * 10e6 + 200e6
    ro = [0, 0, 1, 1, 0, 1, 1, 0, 0, 1]
    (tmp_path / "st.csv").write_text("stress_amplitude_pa,runout\n" + "".join(f"{s:g},{r}\n" for s, r in zip(lv, ro)))
    assert main(["sn", "staircase", str(tmp_path / "st.csv"), "--out", str(tmp_path / "s")]) == 0
    assert "fatigue strength (50 %)" in capsys.readouterr().out
    d = strainlife.simulate_en(900e6, -0.09, 0.4, -0.6, 200e9, np.array([0.002, 0.004, 0.008]), 3, 0.1, np.random.default_rng(1))
    (tmp_path / "en.csv").write_text("strain_amplitude,cycles,stress_amplitude_pa\n" + "".join(
        f"{e:.6g},{n:.6g},{s:.6g}\n" for e, n, s in zip(d.strain_amplitude, d.cycles, d.stress_pa)))
    assert main(["en", "fit", str(tmp_path / "en.csv"), "--out", str(tmp_path / "e"), "--modulus-pa", "200e9"]) == 0
    out = capsys.readouterr().out
    assert "σ'f" in out and "n'" in out
    assert json.loads((tmp_path / "e" / "fit.json").read_text())["c"] < 0


@pytest.mark.parametrize("content, words", [
    (b"\x89PNG\r\n\x1a\n\x00\x00\x00", ["binary"]),
    (b"stress_amplitude_pa,cycles\n300e6,1e5\n", ["`runout`", "missing"]),
    (b"stress_amplitude_pa,cycles,runout\n300e6,1e5,0\n250e6,nan,0\n", ["row 3", "`cycles`"]),
    (b"stress_amplitude_pa,cycles,runout\n300e6,1e5,0\n250e6,1e6,2\n", ["row 3", "`runout`", "0 or 1"]),
    (b"stress_amplitude_pa,cycles,runout\n300e6,1e7,1\n250e6,1e7,1\n", ["all 2 specimens are run-outs"]),
    (b"stress_amplitude_pa,cycles,runout\n300,1e5,0\n250,1e6,0\n", ["MPa"]),
])
def test_bad_input_is_one_line_naming_file_row_field_and_exit_2(tmp_path, capsys, content, words):
    p = tmp_path / "bad.csv"
    p.write_bytes(content)
    assert main(["sn", "fit", str(p), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "bad.csv" in err and "Traceback" not in err
    for w in words:
        assert w in err


@pytest.mark.parametrize("cmd, content, words", [
    (["en", "fit"], b"strain_amplitude,cycles\n0.005,1e4\n", ["`stress_amplitude_pa`", "missing"]),
    (["en", "fit"], b"strain_amplitude,cycles,stress_amplitude_pa\n0.5,1e4,300e6\n", ["`strain_amplitude`", "m/m"]),
    (["en", "fit"], b"strain_amplitude,cycles,stress_amplitude_pa\n0.005,1e4,300e6\n", ["--modulus-pa"]),
    (["sn", "staircase"], b"stress_amplitude_pa,runout\n200e6,1\n210e6,1\n220e6,1\n", ["all 3 specimens are run-outs"]),
    (["sn", "staircase"], b"stress_amplitude_pa,runout\n200e6,1\n210e6,yes\n", ["row 3", "`runout`"]),
])
def test_en_and_staircase_bad_input_is_one_line_and_exit_2(tmp_path, capsys, cmd, content, words):
    p = tmp_path / "bad.csv"
    p.write_bytes(content)
    assert main([*cmd, str(p), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "bad.csv" in err and "Traceback" not in err
    for w in words:
        assert w in err
