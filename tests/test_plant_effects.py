"""Each optional effect of EFFECTS.md that lives in the plant changes what it should, and only that."""
import numpy as np
import pytest

import htm
from htm.params import thesis_rig


def run(u, **overrides):
    p = thesis_rig(**overrides)
    m = htm.Machine(p)
    return p, m.simulate(np.asarray(u, dtype=float), 1e-3)


def test_null_bias_moves_the_hydraulic_null():
    # critically lapped and linear so only the bias decides where the piston stands still
    base = dict(valve_underlap_v=0.0, gravity_m_s2=0.0)
    p, tr = run(np.full(300, -0.3), valve_null_bias_v=0.3, **base)
    assert abs(tr["v"][-1]) < 2e-5
    _, tr0 = run(np.full(300, -0.3), valve_null_bias_v=0.0, **base)
    assert tr0["v"][-1] > 5e-3, "without the bias the same command moves the piston up"


def test_deadband_stops_flow_inside_the_band_and_shifts_gain_outside():
    base = dict(valve_underlap_v=0.0, valve_null_bias_v=0.0, gravity_m_s2=0.0)
    _, inside = run(np.full(300, 0.4), valve_deadband_half_width_v=0.5, **base)
    assert abs(inside["v"][-1]) < 2e-5
    _, shifted = run(np.full(300, 1.5), valve_deadband_half_width_v=0.5, **base)
    _, plain = run(np.full(300, 1.0), **base)
    assert shifted["v"][-1] == pytest.approx(plain["v"][-1], rel=0.02)


def test_hysteresis_is_play_between_command_and_spool():
    base = dict(valve_underlap_v=0.0, valve_null_bias_v=0.0, gravity_m_s2=0.0)
    # up to +1 V, then back to +0.8 V: inside the 0.3 V play the spool stays at 0.7 V
    u = np.r_[np.full(200, 1.0), np.full(200, 0.8)]
    _, tr = run(u, valve_hysteresis_half_width_v=0.3, **base)
    _, ref = run(np.full(400, 0.7), **base)
    assert tr["v"][-1] == pytest.approx(ref["v"][-1], rel=0.02)
    assert tr["v"][199] == pytest.approx(ref["v"][199], rel=0.02)


def test_supply_sag_lowers_supply_pressure_with_inflow():
    p, tr = run(np.full(100, 5.0), supply_resistance_pa_s_per_m3=5e9)
    q_in = p["area_a_m2"] * abs(tr["v"][-1])
    assert tr["p_s"][-1] == pytest.approx(p["supply_pressure_pa"] - 5e9 * q_in, rel=0.05)
    _, stiff = run(np.full(100, 5.0))
    assert stiff["p_s"][-1] == p["supply_pressure_pa"] and abs(stiff["v"][-1]) > abs(tr["v"][-1])


def test_internal_leakage_lets_a_sealed_cylinder_sink_under_gravity():
    base = dict(valve_underlap_v=0.0)
    p, sealed = run(np.full(1000, -0.115), **base)
    _, leaky = run(np.full(1000, -0.115), leakage_coeff_m3_per_s_pa=1e-11, **base)
    # Q = c (p_a - p_b) bypasses the piston, so it sinks at Q / A (friction carries part of
    # the weight at this creep speed, which is why p_a - p_b is read back rather than assumed)
    dp = leaky["p_a"][-1] - leaky["p_b"][-1]
    assert abs(sealed["v"][-1]) < 1e-5
    assert dp > 0
    assert leaky["v"][-1] == pytest.approx(-1e-11 * dp / p["area_a_m2"], rel=0.05)


def test_friction_asymmetry_and_pressure_dependence_change_the_load_pressure():
    g = dict(gravity_m_s2=0.0)

    def load_force(u, **kw):
        p, tr = run(np.full(150, u), **kw, **g)
        return p["area_a_m2"] * tr["p_a"][-1] - p["area_b_m2"] * tr["p_b"][-1], tr["v"][-1]

    up, v_up = load_force(-1.0, friction_coulomb_pos_n=1500.0, friction_coulomb_neg_n=500.0)
    down, v_down = load_force(1.0, friction_coulomb_pos_n=1500.0, friction_coulomb_neg_n=500.0)
    assert v_up > 0 > v_down
    assert up - 5017.35 * v_up == pytest.approx(1500 + 102.61 * np.exp(-v_up / 0.01), rel=0.03)
    assert -(down - 5017.35 * v_down) == pytest.approx(500 + 102.61 * np.exp(v_down / 0.01), rel=0.05)
    plain, _ = load_force(-1.0)
    heavy, _ = load_force(-1.0, friction_pressure_coeff_n_per_pa=1e-5)
    assert heavy - plain > 100.0  # c * (p_a + p_b) ~ 1e-5 * 19e6


def test_entrained_air_softens_the_oil_column():
    # dp/dt = β(p)/V·(q − A·v): with the same state and command, the ratio of the chambers'
    # pressure rates with and without air is the ratio of the bulk moduli. Air is compressed
    # away at high pressure, so the oil softens a lot at 2 MPa and hardly at 20 MPa; nothing
    # but the pressure rates changes.
    def rates(p_pa, air):
        m = htm.Machine(thesis_rig(air_fraction=air))
        x = m.rest_state(0.1).copy()
        x[0] = x[1] = p_pa
        x[3] = 0.01  # piston moving at 10 mm/s
        return m.rhs(x, -0.115)
    ratios = []
    for p_pa in (2e6, 5e6, 10e6, 20e6):
        clean, aerated = rates(p_pa, 0.0), rates(p_pa, 0.05)
        assert np.array_equal(clean[2:], aerated[2:])
        ratios.append(aerated[:2] / clean[:2])
    ratios = np.array(ratios)
    assert ratios[:, 0] == pytest.approx(ratios[:, 1], rel=1e-9)  # both chambers alike
    assert ratios[0, 0] < 0.5 and ratios[-1, 0] > 0.95
    assert np.all(np.diff(ratios[:, 0]) > 0)


def test_linear_flow_valve_ignores_load_pressure():
    # against a stiff spring the orifice valve's flow falls as the load pressure rises; the
    # linear valve keeps pushing at its no-load rate
    k = 2e7
    def speed(lin):
        p = thesis_rig(specimen_stiffness_n_m=k, valve_linear_flow=lin)
        m = htm.Machine(p)
        m.state = m.rest_state(0.1)
        tr = m.simulate(np.full(60, -3.0), 1e-3)
        return tr["v"][-1], tr["f"][-1]
    (_, f_orifice), (_, f_linear) = speed(0.0), speed(1.0)
    assert f_linear > f_orifice
