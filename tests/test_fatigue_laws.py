"""Growth-law fitting (rate and life), closing-the-loop diagnosis, the test report."""
import numpy as np
import pytest

from htm import core
from htm.fatigue.data import CrackData, Setup, read_a_n
from htm.fatigue.e647 import reduce
from htm.fatigue.laws import Model, Points, fit_life, fit_rate, life_errors, scatter
from htm.fatigue.loop import analyse, diagnose
from htm.fatigue.report import force_band, write_test_report

MT = Setup.from_loads("mt", 0.1524, 2.54e-3, delta_p_n=18680.0, r_ratio=0.2)


def _specimen(model, setup, a0=9e-3, af=45e-3, npts=120, noise=0.0, seed=0):
    a = np.linspace(a0, af, npts)
    n = model.life_curve(setup, a)
    if noise:
        a = a + np.random.default_rng(seed).normal(0, noise, a.size)
    return CrackData(str(seed), n, a)


def test_rates_come_from_the_core():
    m = Model("forman", {"log10_c": -8.0, "m": 3.0, "kc_mpa": 40.0})
    dk = np.array([10e6, 20e6])
    got = m.rate(dk, dk / 0.8, 0.2)
    want = 1e-8 * (dk / 1e6) ** 3 / (0.8 * 40 - dk / 1e6)
    assert np.allclose(got, want, rtol=1e-12)
    assert np.allclose(core.growth_rate(m.core_law(0.2), dk, 0.2, dk / 0.8), got)


@pytest.mark.parametrize("law,params", [
    ("paris", {"log10_c": -10.5, "m": 3.2}),
    ("forman", {"log10_c": -8.2, "m": 2.8, "kc_mpa": 45.0}),
    ("nasgro", {"log10_c": -10.3, "n": 3.0, "dk_th_mpa": 5.0, "k_crit_mpa": 45.0, "p": 0.5, "q": 1.0}),
])
def test_rate_and_life_fits_recover_known_laws(law, params):
    true = Model(law, params)
    data = _specimen(true, MT)
    pts = Points.from_reduced([reduce(data, MT, n=3, min_spacing_m=0.0)])
    rate = fit_rate(law, pts, MT.r_ratio)
    for k in rate.free:
        assert rate.params[k] == pytest.approx(true.params[k], rel=0.03, abs=0.05), k
    start = Model(law, {**rate.params, "log10_c": rate.params["log10_c"] + 0.05})
    life = fit_life(law, [data], MT, start, free=rate.free)
    assert life.fit["rms_life_rel"] < 1e-3
    for k in rate.free:
        assert life.params[k] == pytest.approx(true.params[k], rel=0.02, abs=0.03), k
    assert life_errors(life, data, MT)["rms_rel"] < 2e-3


def test_pooled_life_fit_and_scatter():
    true = Model("paris", {"log10_c": -10.0, "m": 2.9})
    datas = [_specimen(Model("paris", {"log10_c": -10.0 + d, "m": 2.9}), MT, seed=i) for i, d in enumerate((-0.05, 0.0, 0.05))]
    pooled = fit_life("paris", datas, MT, Model("paris", {"log10_c": -9.9, "m": 2.8}), free=("log10_c", "m"))
    assert abs(pooled.params["m"] - 2.9) < 0.05 and abs(pooled.params["log10_c"] - true.params["log10_c"]) < 0.05
    per = [fit_rate("paris", Points.from_reduced([reduce(d, MT, min_spacing_m=0)]), 0.2) for d in datas]
    sc = scatter(per)
    assert sc["log10_c"]["std"] == pytest.approx(0.05, rel=0.1)
    assert sc["m"]["std"] < 0.01


def test_diagnosis_finds_a_missing_toughness_term_and_the_refit_removes_it():
    true = Model("forman", {"log10_c": -8.2, "m": 2.8, "kc_mpa": 40.0})
    datas = [_specimen(true, MT, npts=150, noise=2e-5, seed=s) for s in range(4)]
    res = analyse(datas, MT, life_fits=False, first_fraction=0.3)
    assert "toughness" in res.diagnosis["missing_terms"]
    assert res.summary["after_law"] != "paris"
    assert res.summary["pooled_rms_log10_after"] < 0.8 * res.summary["pooled_rms_log10_before"]
    assert abs(res.residual_after["delta_k"]["high_end_mean"]) < abs(res.diagnosis["delta_k"]["high_end_mean"]) / 3
    assert res.summary["prediction_rms_rel_loo_after"] < res.summary["prediction_rms_rel_loo_paris"]


def test_diagnosis_finds_nothing_in_pure_paris_data():
    true = Model("paris", {"log10_c": -10.0, "m": 3.0})
    datas = [_specimen(true, MT, npts=150, noise=2e-5, seed=s) for s in range(4)]
    pts = Points.from_reduced([reduce(d, MT) for d in datas])
    d = diagnose(fit_rate("paris", pts, 0.2), pts, MT)
    assert d["missing_terms"] == []


def test_virkler_subset_shows_curvature_that_the_refit_reduces():
    import pathlib
    import tempfile

    src = pathlib.Path(__file__).resolve().parents[1] / "data" / "virkler_2024t3" / "virkler_a_vs_n_specimens_1_40.csv"
    with tempfile.TemporaryDirectory() as t:
        p = pathlib.Path(t) / "v.csv"
        p.write_text(src.read_text().replace("a_half_crack_mm", "a_mm", 1))
        datas = read_a_n(p)[:12]
    res = analyse(datas, MT, life_fits=False)
    assert res.diagnosis["delta_k"]["significant"]
    assert res.diagnosis["missing_terms"]
    assert res.summary["per_specimen_rms_log10_after"] < res.summary["per_specimen_rms_log10_before"]


def test_test_report_writes_markdown_html_and_force_band(tmp_path):
    true = Model("paris", {"log10_c": -10.0, "m": 3.0})
    a = np.linspace(9e-3, 30e-3, 4000)  # a per-cycle-like dense table
    n = true.life_curve(MT, a)
    rng = np.random.default_rng(1)
    pmax = MT.pmax_n * (1 + rng.normal(0, 0.004, a.size))
    pmin = MT.pmax_n * MT.r_ratio + MT.delta_p_n * rng.normal(0, 0.004, a.size)
    pmax[:40] = MT.pmax_n * 1.05  # a disturbed start: 1 % of cycles outside the band
    out = write_test_report(tmp_path, {"cycles": n, "a_m": a, "pmax_n": pmax, "pmin_n": pmin}, MT,
                            specimen_info={"id": "S1", "material": "2024-T3"}, loading_info={"frequency [Hz]": 20})
    fb = out["force_band"]
    assert 0.985 < fb["fraction_inside"] < 0.995
    assert fb["max_peak_dev_rel"] == pytest.approx(0.05 * MT.pmax_n / MT.delta_p_n, rel=1e-6)
    assert abs(out["model"].params["m"] - 3.0) < 0.03
    md = out["markdown"].read_text()
    assert "±2 %" in md and "Validity summary" in md and "ΔK [MPa·√m]" in md and "2024-T3" in md
    html = out["html"].read_text()
    assert html.count("data:image/png;base64,") == 2
    assert (tmp_path / "reduced.csv").read_text().splitlines()[0].startswith("cycles,a_m,a_fit_m")


def test_force_band_counts_cycles_outside():
    fb = force_band(np.array([10.0, 10.1, 10.5]), np.array([2.0, 2.0, 2.0]), 10.0, 2.0)
    assert fb["fraction_inside"] == pytest.approx(2 / 3)
