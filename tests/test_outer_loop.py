"""The displacement-loop identification on synthetic records and on the real UTFSM MTS chirps."""
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from htm import _core
from htm.errors import RecordError
from htm.ident import outer_loop as ol

ROOT = Path(__file__).resolve().parents[1]


def chirp(dt: float, seconds: float, f0: float = 0.8, f1: float = 20.0, amp: float = 2e-3) -> np.ndarray:
    t = np.arange(int(seconds / dt)) * dt
    phase = 2 * np.pi * (f0 * t + (f1 - f0) / (2 * seconds) * t**2)
    return amp * np.sin(phase)


def synthetic(truth: dict, seed: int, *, seconds: float = 20.0, load: bool = True) -> ol.LoopRecord:
    """A record made by the model itself with position noise of 15 µm and a friction-like load."""
    dt = 1e-3
    r = chirp(dt, seconds)
    v = np.gradient(r, dt)
    f = 1500.0 * np.tanh(v / 0.01) if load else np.zeros_like(r)
    y = _core.outer_loop_simulate(truth, r, f, dt)
    rng = np.random.default_rng(seed)
    return ol.LoopRecord(f"syn{seed}", r, y + rng.normal(0, 15e-6, len(y)), f + rng.normal(0, 20, len(f)), dt)


BASE_TRUTH = {"gain": 1.0, "bandwidth_hz": 7.0, "delay_s": 0.004, "offset_m": -5e-5}


def test_baseline_fit_recovers_the_loop_and_a_clean_record_has_no_finding():
    rec = synthetic(BASE_TRUTH, 1)
    p = ol.fit([rec])
    assert p["bandwidth_hz"] == pytest.approx(7.0, rel=0.02)
    assert p["delay_s"] == pytest.approx(0.004, abs=3e-4)
    assert p["offset_m"] == pytest.approx(-5e-5, abs=3e-6)
    findings, rounds = ol.search([rec], p)
    assert findings == []
    assert {t["effect"] for t in rounds[0]} == set(ol.CANDIDATES)
    assert ol.rmse(p, rec) < 1.1 * ol.noise_floor(rec)


@pytest.mark.parametrize("effect,params,rel", [
    ("load_pressure_feedback", {"load_m_s_per_n": 2e-6}, 0.1),
    ("direction_asymmetry", {"asymmetry": 0.08}, 0.1),
    ("actuator_friction", {"friction_m_s": 3e-3}, 0.15),
])
def test_each_effect_is_found_with_its_parameter(effect, params, rel):
    rec = synthetic({**BASE_TRUTH, **params}, 2)
    base = ol.fit([rec])
    findings, _ = ol.search([rec], base)
    assert findings, "no effect found"
    assert findings[0]["effect"] == effect
    for k, v in params.items():
        assert findings[0]["params"][k] == pytest.approx(v, rel=rel)
    assert findings[0]["rmse_after"][rec.name] < 0.7 * findings[0]["rmse_before"][rec.name]
    assert [f["effect"] for f in findings] == [effect], "an effect that is not in the record was claimed"


def test_garbage_is_refused_with_a_reason():
    dt = 1e-3
    with pytest.raises(RecordError, match="at least 50"):
        ol.LoopRecord("tiny", np.zeros(3), np.zeros(3), np.zeros(3), dt)
    with pytest.raises(RecordError, match="constant"):
        ol.LoopRecord("flat", np.zeros(500), np.zeros(500), np.zeros(500), dt)
    y = np.zeros(500)
    y[10] = np.nan
    with pytest.raises(RecordError, match="NaN"):
        ol.LoopRecord("nan", np.sin(np.arange(500.0)), y, np.zeros(500), dt)
    with pytest.raises(_core.ParameterError, match="asymmetry"):
        _core.outer_loop_simulate({"asymmetry": 2.0}, np.zeros(10), np.zeros(10), dt)


@pytest.fixture(scope="module")
def utfsm(tmp_path_factory):
    sys.path.insert(0, str(ROOT / "examples"))
    try:
        import utfsm_chirp
    finally:
        sys.path.pop(0)
    out = tmp_path_factory.mktemp("utfsm")
    assert utfsm_chirp.main(["--out", str(out)]) == 0
    return json.loads((out / "report.json").read_text()), out


def test_utfsm_baseline_from_0a_is_a_7_hz_loop_with_a_few_ms_delay(utfsm):
    rep, _ = utfsm
    b = rep["baseline"]
    assert b["identified_on"] == "0A"
    assert 5.0 < b["params"]["bandwidth_hz"] < 10.0
    assert 0.0 < b["params"]["delay_s"] < 0.02
    assert b["params"]["gain"] == pytest.approx(1.0, abs=0.05)
    # the 0 A model applied to the 1 A chirp: already close, since the loop is stiff
    assert b["rmse"]["1A"] < 2.5 * rep["records"]["1A"]["noise_floor_m"]


def test_utfsm_effects_cut_the_error_on_both_records(utfsm):
    rep, out = utfsm
    assert rep["findings"], "no effect found on the real records"
    for f in rep["findings"]:
        assert f["delta_bic"] < -10
        assert f["validation_rmse_after"] < f["validation_rmse_before"]
    for n in ("0A", "1A"):
        assert rep["final"]["rmse"][n] < 0.85 * rep["baseline"]["rmse"][n]
    # the specimen's load was examined: alone it explains part of the 1 A residual
    load = next(t for t in rep["screening"] if t["effect"] == "load_pressure_feedback")
    assert load["params"]["load_m_s_per_n"] > 0
    assert load["rmse_after"]["1A"] < load["rmse_before"]["1A"]
    text = (out / "report.md").read_text()
    assert "load_pressure_feedback" in text and (out / "residuals.png").stat().st_size > 10_000
    assert isinstance(rep["unexplained"], bool)
