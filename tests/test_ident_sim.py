"""Record re-simulation: the base model from metadata, the sensor model inside the loop, closed
and open-loop predictions, and the batch that the model fit runs on all cores."""
import numpy as np
import pytest

from htm import Params
from htm.errors import InputError, RecordError, SolverError
from htm.ident import proving, sim
from htm.ident.records import Record


def truth_params(rec, truth):
    p = sim.params_from_meta(rec.meta)
    for k, v in truth["params"].items():
        p[k] = v
    return p


def rmse(a, b):
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b)) ** 2)))


def test_params_from_meta_is_the_effects_base_model_with_the_nominal_rig():
    rec, _ = proving.make_record({}, seed=0, duration_s=2, noise=False)
    meta = rec.meta
    meta["rig"]["moving_mass_kg"] = 61.0
    p = sim.params_from_meta(meta)
    assert p["moving_mass_kg"] == 61.0 and p["bulk_modulus_pa"] == meta["rig"]["bulk_modulus_pa"]
    for eid in sim.EFFECT_FIELDS:
        if eid in ("friction_asymmetry", "load_pressure_feedback"):
            continue
        assert all(v == 0.0 for v in sim.effect_values(p, eid).values()), eid
    assert p["friction_coulomb_pos_n"] == p["friction_coulomb_neg_n"]
    for c in sim.CHANNELS:
        assert (p[f"sensor_offset_{c}"], p[f"sensor_gain_{c}"], p[f"sensor_delay_{c}_s"]) == (0.0, 1.0, 0.0)
    assert p.valve_map == ([], []) and p["valve_linear_flow"] == 0.0
    assert p["valve_polarity"] == -1.0, "kp < 0 in the declared loop means the thesis valve polarity"
    assert p["specimen_stiffness_n_m"] == 0.0 and p["gravity_m_s2"] > 9
    lin = sim.params_from_meta({**meta, "rig": {**meta["rig"], "valve_flow_law": "linear", "orientation": "horizontal"},
                                "specimen": {"stiffness_n_m": 3e6, "zero_force_position_m": 0.09}})
    assert lin["valve_linear_flow"] == 1.0 and lin["gravity_m_s2"] == 0.0
    assert lin["specimen_stiffness_n_m"] == 3e6 and lin["specimen_zero_force_position_m"] == 0.09
    on = sim.with_effect(lin, "load_pressure_feedback", {})
    assert on["valve_linear_flow"] == 0.0


def test_params_from_meta_rejects_bad_metadata_by_name():
    with pytest.raises(RecordError, match="rig"):
        sim.params_from_meta({"format": "htm-record/1"})
    rec, _ = proving.make_record({}, seed=0, duration_s=2, noise=False)
    bad = {**rec.meta, "rig": {**rec.meta["rig"], "moving_mass_kg": "heavy"}}
    with pytest.raises(RecordError, match="moving_mass_kg"):
        sim.params_from_meta(bad)
    bad = {**rec.meta, "rig": {**rec.meta["rig"], "bulk_modulus_pa": -5.0}}
    with pytest.raises(RecordError, match="bulk_modulus_pa"):
        sim.params_from_meta(bad)


def test_a_rig_that_states_its_metering_edges_and_friction_sign_is_replayed_in_that_form():
    """A record's metadata may state the base model's form where a rig's is known: the width over
    which the valve's metering edges open and the form of friction's smoothed sign (0: the thesis's
    v/(|v| + eps), 1: tanh(v/eps)). The shared external generator builds both so (sharp edges, tanh):
    its record `rec_h8` re-simulated at the generator's parameters in htm's base form is 3.0 times
    y's noise off, in the stated form 0.6 (`benchmarks/external_form.py`)."""
    rec, truth = proving.make_record({}, seed=3, duration_s=6, noise=False)
    rig = rec.meta["rig"]
    p = sim.params_from_meta(rec.meta)
    assert p["friction_sign_shape"] == 0.0 and p["valve_lap_smoothing_v"] == Params("base")["valve_lap_smoothing_v"]
    stated = {**rec.meta, "rig": {**rig, "friction_sign_shape": 1.0, "valve_lap_smoothing_v": 1e-5, "friction_smoothing_m_s": 2e-4}}
    q = sim.params_from_meta(stated)
    assert (q["friction_sign_shape"], q["valve_lap_smoothing_v"], q["friction_smoothing_m_s"]) == (1.0, 1e-5, 2e-4)
    # tanh moves the readings where the piston reverses (the friction force crosses its level
    # within a few eps instead of tens)
    base = sim.predict(truth_params(rec, truth), rec)
    tanh = truth_params(rec, truth)
    tanh["friction_sign_shape"] = 1.0
    moved = sim.predict(tanh, rec)
    assert rmse(moved["p_a"], base["p_a"]) > 1e3, "the sign's form moves the chamber pressures by kPa"
    assert rmse(moved["y"], base["y"]) < 1e-4, "and leaves the position loop following its reference"
    for key, value in (("friction_sign_shape", 2.0), ("valve_lap_smoothing_v", 0.0), ("friction_sign_shape", "tanh")):
        with pytest.raises(RecordError, match=key):
            sim.params_from_meta({**rec.meta, "rig": {**rig, key: value}})


def test_effect_table_maps_every_effects_id_to_params_fields():
    p = Params("base")
    for eid in sim.EFFECT_IDS:
        ch = "p_a" if eid in sim.SENSOR_EFFECTS else None
        for field in sim.effect_fields(eid, ch).values():
            assert field in p, (eid, field)
    assert sim.effect_fields("sensor_offset", "y") == {"offset_m": "sensor_offset_y"}
    assert sim.effect_fields("sensor_offset", "v") == {"offset_m_s": "sensor_offset_v"}
    assert sim.effect_fields("sensor_offset", "f") == {"offset_n": "sensor_offset_f"}
    assert sim.effect_fields("sensor_delay", "p_b") == {"delay_s": "sensor_delay_p_b_s"}
    q = sim.with_effect(p, "valve_dynamics", {"tau_s": 0.01})
    assert q["valve_tau_s"] == 0.01 and p["valve_tau_s"] == 0.0
    with pytest.raises(InputError, match="tau"):
        sim.with_effect(p, "valve_dynamics", {"tau": 0.01})
    with pytest.raises(InputError, match="channel"):
        sim.effect_fields("sensor_gain", None)


def test_closed_loop_prediction_with_the_true_parameters_reproduces_a_noise_free_record():
    rec, truth = proving.make_record({"valve_dynamics": {}, "sensor_offset": {"channel": "p_b"}}, seed=3,
                                     duration_s=6, noise=False)
    base = sim.params_from_meta(rec.meta)
    known = proving.supply_profile(np.asarray(rec.columns["y_ref"]), 500)  # the power unit's switch
    good, nominal = sim.predict([truth_params(rec, truth), base], rec, supply=known)
    assert rmse(good["y"], rec.columns["y"]) < 2e-7
    assert rmse(good["p_a"], rec.columns["p_a"]) < 3e3 and rmse(good["p_b"], rec.columns["p_b"]) < 3e3
    assert rmse(nominal["y"], rec.columns["y"]) > 50 * rmse(good["y"], rec.columns["y"])
    assert set(good) == {"y", "v", "p_a", "p_b", "p_s"}, "only the record's channels"


def test_a_pressure_offset_shifts_only_that_reading_and_a_velocity_gain_scales_only_v():
    rec, _ = proving.make_record({}, seed=1, duration_s=4, noise=False)
    base = sim.params_from_meta(rec.meta)
    off = sim.with_effect(base, "sensor_offset", {"offset_pa": 4e5}, "p_a")
    gain = sim.with_effect(base, "sensor_gain", {"gain": 1.2}, "v")
    a, b, c = sim.predict([base, off, gain], rec)
    np.testing.assert_allclose(b["p_a"] - a["p_a"], 4e5, atol=1e-6)
    np.testing.assert_array_equal(b["y"], a["y"])
    np.testing.assert_allclose(c["v"], 1.2 * a["v"], rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(c["p_b"], a["p_b"])


def test_a_delayed_position_sensor_acts_inside_the_loop():
    # the controller reads y 20 ms late: the motion itself changes, not just the reading's timing
    rec, _ = proving.make_record({}, seed=2, duration_s=6, noise=False)
    base = sim.params_from_meta(rec.meta)
    late = sim.with_effect(base, "sensor_delay", {"delay_s": 0.02}, "y")
    a, b = sim.predict([base, late], rec)
    shift = 10  # 20 ms at 500 Hz
    assert rmse(b["y"][shift:], a["y"][:-shift]) > 1e-5
    assert rmse(b["p_a"], a["p_a"]) > 1e4, "chamber pressures show the different motion"


def test_delayed_pressure_reading_is_the_ideal_reading_shifted():
    rec, _ = proving.make_record({}, seed=2, duration_s=4, noise=False)
    base = sim.params_from_meta(rec.meta)
    a, b = sim.predict([base, sim.with_effect(base, "sensor_delay", {"delay_s": 0.006}, "p_a")], rec)
    np.testing.assert_allclose(b["p_a"][3:], a["p_a"][:-3], atol=1e-6)  # 3 samples at 500 Hz
    np.testing.assert_array_equal(b["y"], a["y"])


def test_specimen_closure_stiffens_the_force_below_the_closure_position():
    rec, truth = proving.make_record({"specimen_nonlinearity": {}}, seed=4, duration_s=8, noise=False)
    y, f = rec.columns["y"], rec.columns["f"]
    p = truth["params"]
    y0, yc = p["specimen_zero_force_position_m"], p["specimen_zero_force_position_m"] + p["specimen_closure_offset_m"]
    above, below = y > yc + 5e-4, y < yc - 5e-4
    assert above.sum() > 100 and below.sum() > 100
    k_above = np.polyfit(y[above], f[above], 1)[0]
    k_below = np.polyfit(y[below], f[below], 1)[0]
    assert k_above == pytest.approx(p["specimen_stiffness_n_m"], rel=1e-3)
    assert k_below == pytest.approx(p["specimen_stiffness_n_m"] + p["specimen_closure_stiffness_n_m"], rel=1e-3)
    assert abs(np.interp(y0, np.sort(y[above]), f[above][np.argsort(y[above])])) < 50


def test_open_loop_prediction_restarts_from_the_measurement_every_horizon():
    rec, truth = proving.make_record({}, seed=5, duration_s=6, noise=False)
    rec.meta["controller"] = None
    assert not sim.closed_loop(rec)
    known = proving.supply_profile(np.asarray(rec.columns["y_ref"]), 500)  # the power unit's switch
    good = sim.predict(truth_params(rec, truth), rec, supply=known)
    assert rmse(good["y"], rec.columns["y"]) < 1e-6
    wrong = truth_params(rec, truth)
    wrong["valve_rated_flow_m3_s"] *= 1.3
    short, long = (sim.predict(wrong, rec, horizon_s=h)["y"] for h in (0.1, 2.0))
    e_short, e_long = rmse(short, rec.columns["y"]), rmse(long, rec.columns["y"])
    assert e_long > 3 * e_short, (e_short, e_long)
    k = int(round(0.1 * 500)) * 7  # a restart sample: the prediction equals the measurement there
    assert short[k] == pytest.approx(rec.columns["y"][k], abs=1e-12)


def test_batch_runs_in_parallel_equal_single_runs_and_failures_are_nan():
    rec, truth = proving.make_record({}, seed=6, duration_s=3)
    base = sim.params_from_meta(rec.meta)
    broken = base.copy()
    broken["moving_mass_kg"] = -1.0  # set without validation: the simulation must fail, not raise
    batch = sim.predict([base, truth_params(rec, truth), broken, base], rec, threads=2)
    single = sim.predict(base, rec)
    for c in single:
        np.testing.assert_array_equal(batch[0][c], single[c])
        np.testing.assert_array_equal(batch[3][c], single[c])
        assert np.all(np.isnan(batch[2][c]))
    assert not np.array_equal(batch[1]["y"], single["y"])
    with pytest.raises((SolverError, Exception), match="moving_mass_kg"):
        sim.predict(broken, rec)


def test_predict_refuses_a_declared_controller_without_its_reference():
    rec, _ = proving.make_record({}, seed=0, duration_s=2)
    cols = {k: v for k, v in rec.columns.items() if k != "y_ref"}
    with pytest.raises(RecordError, match="y_ref"):
        sim.predict(sim.params_from_meta(rec.meta), Record(cols, rec.meta, "no_ref"))
    meta = {**rec.meta, "controller": {"type": "pid", "kp": 1}}
    with pytest.raises(RecordError, match="pid"):
        sim.predict(sim.params_from_meta(rec.meta), Record(dict(rec.columns), meta, "pid"))


def test_a_switched_supply_is_followed_and_its_sag_left_for_the_model():
    # The proving ground switches the power unit to 60 % part-way; with supply sag the gauge
    # dips in every motion, which the set-point must not follow (the sag is the model's job).
    rec, truth = proving.make_record({"supply_pressure_sag": {}}, seed=5, duration_s=8)
    s = sim.supply_schedule(rec)
    t = np.asarray(rec.columns["t"])
    drop = np.flatnonzero(proving.supply_profile(np.asarray(rec.columns["y_ref"]), 500) < 0.999)
    t_switch = t[drop[0]]
    assert t_switch >= proving.SUPPLY_SWITCH_AT * 8 and np.all(np.diff(rec.columns["y_ref"])[drop[0] - 20:drop[0] + 20] == 0), "at rest"
    high, low = s[t < t_switch - 0.2], s[t > t_switch + 1.0]
    ps0 = truth["params"]["supply_pressure_pa"]
    # (a dip that runs into the switch may leak into the envelope by a sag's share: 2 %)
    assert np.all(np.abs(high - 1.0) < 0.02) and np.all(np.abs(low - proving.SUPPLY_LOW) < 0.02), (high.min(), low.max())
    assert abs(np.median(high) - 1.0) < 0.005 and abs(np.median(low) - proving.SUPPLY_LOW) < 0.005
    ps = np.asarray(rec.columns["p_s"])
    assert ps[t < t_switch].min() < 0.9 * ps0, "the record's supply does sag in motion"
    # the true model reads the record's supply within its noise given the true schedule, and
    # within a few noise levels given the estimate (fast motions' un-sagged tops are narrow)
    known = proving.supply_profile(np.asarray(rec.columns["y_ref"]), 500)
    exact = sim.predict(truth_params(rec, truth), rec, supply=known)
    assert rmse(exact["p_s"], ps) < 1.1 * proving.NOISE_STD["p_s"]
    pred = sim.predict(truth_params(rec, truth), rec)
    assert rmse(pred["p_s"], ps) < 3 * proving.NOISE_STD["p_s"]
    # a constant supply (noise only) has no schedule: the model's own constant set-point
    const = Record({**rec.columns, "p_s": ps0 + np.random.default_rng(0).normal(0, 3e4, len(t))}, rec.meta, "const")
    assert sim.supply_schedule(const) is None
    assert sim.supply_schedule(Record({k: v for k, v in rec.columns.items() if k != "p_s"}, rec.meta, "no_ps")) is None


def test_command_mode_plays_the_recorded_u_of_a_closed_loop_record_and_noise_enters_the_loop():
    rec, truth = proving.make_record({"valve_hysteresis": {}}, seed=9, duration_s=4)
    p = truth_params(rec, truth)
    played = sim.predict(p, rec, command=True, horizon_s=0.2)
    stripped = Record(dict(rec.columns), {**rec.meta, "controller": None}, "stripped")
    same = sim.predict(p, stripped, horizon_s=0.2)
    for c in played:
        np.testing.assert_array_equal(played[c], same[c])
    free = sim.predict(p, rec)
    assert not np.array_equal(free["y"], played["y"])
    # synthetic noise is added to the readings and the controller acts on it: a channel it does
    # not read carries exactly the added noise, the fed-back position a different motion
    n = len(rec.columns["t"])
    rng = np.random.default_rng(1)
    z = {c: rng.normal(0.0, proving.NOISE_STD[c], n) for c in ("y", "p_a")}
    noisy = sim.predict(p, rec, noise=z)
    assert rmse(noisy["y"] - z["y"], free["y"]) > 0.2 * proving.NOISE_STD["y"]  # the loop moved otherwise
    quiet = sim.predict(p, rec, noise={"p_a": z["p_a"]})
    np.testing.assert_allclose(quiet["p_a"] - z["p_a"], free["p_a"], atol=1e-6)
    np.testing.assert_array_equal(quiet["y"], free["y"])
