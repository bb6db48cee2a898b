"""Virtual rigs with hidden physics (issue 30, item 3): `[virtual.effects]` in the rig
configuration switches EFFECTS.md effects on in the virtual rig's plant only — with the same
`htm.ident.sim.with_effect` the diagnosis simulates — and bad entries are refused in one line."""
import pytest

from htm.control import Session
from htm.devices.config import load_config, virtual_config
from htm.devices.rig import plant_params
from htm.errors import DeviceError


@pytest.mark.parametrize("effects,message", [
    ({"no_such_effect": {"x": 1.0}}, "virtual.effects.no_such_effect: unknown effect"),
    ({"valve_null_bias": {"bias": 0.1}}, "virtual.effects.valve_null_bias: effect `valve_null_bias` has no parameter `bias`"),
    ({"valve_null_bias": {}}, "virtual.effects.valve_null_bias: needs bias_v"),
    ({"sensor_offset": {"offset_pa": 3e5}}, "virtual.effects.sensor_offset: effect `sensor_offset` needs a channel"),
    ({"sensor_offset": {"channel": "p_q", "offset_pa": 3e5}}, "needs a channel among y, v, p_a"),
    ({"valve_null_bias": {"bias_v": 99.0}}, "valve_null_bias_v` = 99 is out of range"),
    ({"internal_leakage": {"coeff_m3_per_s_pa": "lots"}}, "virtual.effects.internal_leakage.coeff_m3_per_s_pa = 'lots'"),
])
def test_bad_effects_are_refused_in_one_line(effects, message):
    with pytest.raises(DeviceError) as e:
        virtual_config("lockstep", virtual={"effects": effects})
    assert message in str(e.value) and "\n" not in str(e.value)


def test_toml_effects_reach_only_the_plant(tmp_path):
    f = tmp_path / "rig.toml"
    f.write_text('[loop]\nmode = "lockstep"\n[virtual.effects]\ninternal_leakage = { coeff_m3_per_s_pa = 3e-12 }\n'
                 'valve_null_bias = { bias_v = 0.12 }\nsensor_offset = { channel = "p_a", offset_pa = 3e5 }\n')
    cfg = load_config(f)
    p = plant_params(cfg)
    assert (p["leakage_coeff_m3_per_s_pa"], p["valve_null_bias_v"], p["sensor_offset_p_a"]) == (3e-12, 0.12, 3e5)
    none = plant_params(virtual_config("lockstep", virtual={"effects": {}}))
    assert none["valve_null_bias_v"] == 0.0 and none["sensor_offset_p_a"] == 0.0, "an empty table: the base model"
    assert plant_params(virtual_config("lockstep"))["valve_null_bias_v"] == 0.115, "no table: the preset as it is"


def _pressures(effects: dict) -> tuple[float, float]:
    """Chamber pressures the loop reads (virtual CAN + simulated DAQ + calibration) after the
    same start-up on a virtual rig with `effects`."""
    s = Session().open(virtual_config("lockstep", virtual={"effects": effects}), virtual=True, thread=False)
    try:
        s.position()
        s.step(200)
        m = s.loop.meas
        return m["p_a"], m["p_b"]
    finally:
        s.close()


def test_a_hidden_sensor_offset_shows_in_what_the_loop_reads():
    p_a0, p_b0 = _pressures({})
    p_a1, p_b1 = _pressures({"sensor_offset": {"channel": "p_a", "offset_pa": 3e5}})
    assert p_a1 - p_a0 == pytest.approx(3e5, abs=0.3e5), (p_a0, p_a1)
    assert p_b1 == pytest.approx(p_b0, abs=0.3e5)
