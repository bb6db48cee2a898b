"""The proving ground: records per DATA_FORMAT.md with effects on, spread rigs, realistic sensors
and a reference rich enough to identify from."""
import numpy as np
import pytest

from htm.errors import InputError
from htm.ident import proving, sim
from htm.ident.records import read_record, validate_record, write_record


def test_record_follows_data_format_and_round_trips(tmp_path):
    rec, truth = proving.make_record({}, seed=11, duration_s=5)
    assert validate_record(rec) == []
    meta = rec.meta
    assert meta["format"] == "htm-record/1" and meta["sample_rate_hz"] == 500
    assert meta["controller"]["type"] == "position_pff" and "law" in meta["controller"]
    assert meta["specimen"] is None and "f" not in rec.columns
    assert set(rec.columns) == {"t", "u", "y", "v", "p_a", "p_b", "p_s", "y_ref"}
    assert len(rec.columns["t"]) == 2500
    write_record(rec, tmp_path / "r")
    back = read_record(tmp_path / "r.csv")
    for c in rec.columns:
        np.testing.assert_array_equal(back.columns[c], rec.columns[c])
    assert back.meta == {**meta}
    assert truth["effects"] == {} and truth["outside"] is None


def test_rig_parameters_spread_around_the_nominal_values_the_metadata_states():
    nominal = sim.params_from_meta(proving.make_record({}, seed=0, duration_s=2)[0].meta)
    factors = []
    for seed in range(6):
        rec, truth = proving.make_record({}, seed=seed, duration_s=2, noise=False)
        assert rec.meta["rig"]["moving_mass_kg"] == nominal["moving_mass_kg"]
        for field in ("moving_mass_kg", "bulk_modulus_pa", "valve_rated_flow_m3_s", "dead_volume_a_m3", "friction_viscous_n_s_m"):
            f = truth["params"][field] / nominal[field]
            assert 0.7 <= f <= 1.3
            factors.append(f)
        assert truth["params"]["friction_coulomb_pos_n"] == truth["params"]["friction_coulomb_neg_n"]
        # everything that is not a spread field stays at the base model
        for field in ("valve_null_bias_v", "valve_tau_s", "supply_pressure_pa", "valve_underlap_v", "sensor_gain_p_a"):
            assert truth["params"][field] == nominal[field]
    assert max(factors) - min(factors) > 0.3, "the draws really spread"
    assert proving.make_record({}, seed=3, duration_s=2)[1]["params"] == proving.make_record({}, seed=3, duration_s=2)[1]["params"]


def test_sensors_have_noise_and_quantization_and_the_truth_explains_the_record_to_the_noise_floor():
    rec, truth = proving.make_record({}, seed=12, duration_s=8, rate_hz=1000)
    assert rec.meta["sample_rate_hz"] == 1000 and len(rec.columns["t"]) == 8000
    for c, q in proving.QUANTUM.items():
        if c in rec.columns:
            steps = rec.columns[c] / q
            np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)
    p = sim.params_from_meta(rec.meta)
    for k, v in truth["params"].items():
        p[k] = v
    pred = sim.predict(p, rec)
    for c, pc in pred.items():
        r = float(np.sqrt(np.mean((pc - rec.columns[c]) ** 2)))
        floor = np.hypot(proving.NOISE_STD[c], proving.QUANTUM[c] / np.sqrt(12))
        assert r == pytest.approx(floor, rel=0.15), (c, r, floor)


def test_reference_holds_ramps_at_several_speeds_sines_and_steps():
    ref = proving.rich_reference(20, 500)
    v = np.diff(ref) * 500
    assert (np.abs(v) < 1e-9).mean() > 0.1, "holds"
    speeds = {round(abs(x), 4) for x in v if abs(x) > 1e-4}
    ramp_speeds = [s for s in (0.01, 0.03, 0.08) if any(abs(x - s) < 1e-3 for x in speeds)]
    assert len(ramp_speeds) == 3, speeds
    assert np.sum(np.abs(np.diff(ref)) > 5e-3) >= 3, "steps"
    acc = np.diff(ref, 2) * 500**2
    assert np.sum(np.abs(acc) > 0.01) > 500, "sines (smoothly varying velocity)"


def test_every_effects_id_changes_the_record_it_is_switched_on_in():
    for eid in proving.DEFAULT_EFFECTS:
        rec, truth = proving.make_record({eid: {}}, seed=7, duration_s=6, noise=False)
        assert list(truth["effects"]) == [eid]
        base = sim.params_from_meta(rec.meta)
        true, off = base.copy(), base.copy()
        for k, v in truth["params"].items():
            true[k] = off[k] = v
        # the same rig with only this effect switched back to the base model
        fields = dict(sim.effect_fields(eid, truth["effects"][eid]["channel"]))
        if eid == "load_pressure_feedback":
            assert rec.meta["rig"]["valve_flow_law"] == "linear" and true["valve_linear_flow"] == 0.0
            fields = {"": "valve_linear_flow"}
        for field in fields.values():
            off[field] = base[field]
        # the power unit's true schedule (estimating it from p_s is sim.supply_schedule's test)
        known = proving.supply_profile(np.asarray(rec.columns["y_ref"]), rec.meta["sample_rate_hz"])
        with_e, without = sim.predict([true, off], rec, rtol=1e-6, supply=known)
        for c in with_e:
            assert np.max(np.abs(with_e[c] - rec.columns[c])) < 0.5 * proving.NOISE_STD[c], (eid, c)
        worst = max(np.max(np.abs(without[c] - rec.columns[c])) / proving.NOISE_STD[c] for c in with_e)
        assert worst > 5, (eid, worst)


def test_sensor_effects_name_their_channel_and_force_effects_bring_a_specimen():
    rec, truth = proving.make_record({"sensor_gain": {"channel": "v", "gain": 0.9}}, seed=1, duration_s=2)
    assert truth["effects"]["sensor_gain"] == {"channel": "v", "params": {"gain": 0.9}}
    assert truth["params"]["sensor_gain_v"] == 0.9
    rec, truth = proving.make_record({"sensor_offset": {"channel": "f"}}, seed=1, duration_s=2)
    assert "f" in rec.columns and rec.meta["specimen"]["stiffness_n_m"] > 0
    assert truth["effects"]["sensor_offset"]["params"] == {"offset_n": proving.DEFAULT_OFFSET["f"]}


def test_effect_outside_the_table_is_in_the_truth_but_not_among_the_effects():
    rec, truth = proving.make_record({}, seed=2, duration_s=6, noise=False, effect_outside_table="friction_bump")
    clean, _ = proving.make_record({}, seed=2, duration_s=6, noise=False)
    assert truth["outside"] == "friction_bump" and truth["effects"] == {}
    assert truth["params"]["friction_bump_n"] > 0
    dp = (rec.columns["p_a"] - rec.columns["p_b"]) - (clean.columns["p_a"] - clean.columns["p_b"])
    assert np.max(np.abs(dp)) > 1e5, "the bump's friction shows in the load pressure"


def test_bad_requests_are_named():
    with pytest.raises(InputError, match="valve_stiction"):
        proving.make_record({"valve_stiction": {}}, seed=0)
    with pytest.raises(InputError, match="channel"):
        proving.make_record({"sensor_offset": {"channel": "q"}}, seed=0)
    with pytest.raises(InputError, match="rate_hz"):
        proving.make_record({}, seed=0, rate_hz=5)
    with pytest.raises(InputError, match="resonance"):
        proving.make_record({}, seed=0, effect_outside_table="resonance")
    for bad in ({"q": {"resolution": 1e-6}}, {"y": {"resolution": -1.0}}, {"y": {"noise_std": float("nan")}},
                {"y": {"bits": 12}}, {"y": 5e-6}):
        with pytest.raises(InputError, match="sensors"):
            proving.make_record({}, seed=0, sensors=bad)


def test_a_sensor_given_its_own_quantum_and_noise_reads_so_and_declares_them():
    """`sensors`: y read at a 5 µm quantum with 0.05 µm of noise — the reading moves in whole
    quanta and the metadata states both; the other channels keep the proving rig's."""
    rec, _ = proving.make_record({}, seed=3, duration_s=4, sensors={"y": {"resolution": 5e-6, "noise_std": 5e-8}})
    y = np.asarray(rec.columns["y"])
    assert np.allclose(y / 5e-6, np.round(y / 5e-6), atol=1e-6)
    assert rec.meta["sensors"]["y"] == {"resolution": 5e-6, "noise_std": 5e-8}
    assert rec.meta["sensors"]["p_a"] == {"resolution": proving.QUANTUM["p_a"], "noise_std": proving.NOISE_STD["p_a"]}
