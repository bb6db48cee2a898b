"""The fatigue test engine: thesis reproductions (chapter 4), ΔK control, bad specs, `htm run`."""
from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from htm import core
from htm.cli import main
from htm.errors import SpecError
from htm.spec import load, parse

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "ct_constant_force.toml"
EV = core.EVENTS
START, STOP = EV["start"], EV["stop"]


def base_doc() -> dict:
    return tomllib.loads(EXAMPLE.read_text())


def run(doc: dict, mode: str = "full") -> dict:
    return core.run_test(parse(doc).config, mode)


def in_test(t: dict) -> np.ndarray:
    return (t["events"] & (START | STOP)) == 0


def worst(t: dict, sel: np.ndarray) -> np.ndarray:
    return np.maximum(np.abs(t["peak_err_pct"][sel]), np.abs(t["df_err_pct"][sel]))


def fig_4_8_doc(controller: dict, preset: str = "base") -> dict:
    """Fig. 4.8 scenario: C(T) of Table B.1, 4.45 kN at R = 0.1, 9 Hz with 500 Hz control, a
    fast-growing crack (Paris C × 30) from a/W 0.30 to 0.50 so that K_sp falls to ≈ 40 %, on
    the rig `preset`: "base" is the linear-valve plant the thesis's comparison assumes (its
    normalised plant −0.07/s), "thesis" the default rig with the measured valve map."""
    d = base_doc()
    d["rig"] = {"preset": preset}
    d["controller"] = controller
    d["loading"]["frequency_hz"] = 9.0
    d["loading"]["control_rate_hz"] = 500.0
    d["law"]["c"] *= 30
    d["end"]["a_over_w"] = 0.5
    return d


@pytest.mark.parametrize("preset, kp", [("base", -1e-4), ("thesis", -8e-4)])
def test_fixed_gain_force_p_leaves_the_band_as_the_crack_grows(preset, kp):
    """Thesis Fig. 4.8 (the band is left after ≈ 2,500 cycles there). It holds on both rigs, with
    a gain that starts inside the band on each: on the linear-valve "base" plant the thesis's
    −1e-4 V/N; on the default rig the measured valve has a low-gain null region (Table 3.3) and
    −1e-4 V/N is out of band from the first cycle (10.7 %, measured), so the fixed gain is
    −8e-4 V/N; that loop leaves the band at cycle ≈ 2,100 when K_sp has fallen to ≈ 57 %."""
    o = run(fig_4_8_doc({"type": "force_p", "kp_v_per_n": kp, "u_offset_v": -0.115}, preset))
    t = o.table
    sel = in_test(t)
    err = worst(t, sel)
    ksp = t["k_sp_n_m"][sel] / t["k_sp_n_m"][sel][0]
    assert err[:50].max() < 2.0, "starts inside the ±2 % band"
    first_out = np.argmax(err > 2.0)
    assert err.max() > 2.0 and first_out > 100, "leaves the band only after the crack has grown"
    assert ksp[first_out] < 0.8, f"leaves the band when K_sp has fallen (K_sp/K0 = {ksp[first_out]:.2f})"


@pytest.mark.parametrize("preset", ["base", "thesis"])
def test_demod_holds_the_band_in_the_fig_4_8_scenario(preset):
    o = run(fig_4_8_doc({"type": "demodulation"}, preset))
    t = o.table
    assert o.end_reason == "target_crack_length"
    assert worst(t, in_test(t)).max() < 2.0
    assert t["k_sp_n_m"][-1] < 0.5 * t["k_sp_n_m"][0]


def test_demod_holds_two_percent_over_6e4_cycles_while_stiffness_falls():
    """Thesis 4.2.1 / Fig. 4.11–4.13 on the thesis rig (measured valve map, null at −0.115 V):
    6·10⁴ cycles, every cycle through the plant (10 Hz, 1 kHz control), Table B.1 C(T) with the
    example's Paris law; K_sp falls as the crack grows."""
    d = base_doc()
    d["end"]["max_cycles"] = 60_000
    d["law"]["c"] *= 1.3
    o = run(d, "full")
    t = o.table
    sel = in_test(t)
    assert o.cycles == 60_000 and o.end_reason == "cycle_limit"
    assert worst(t, sel).max() < 2.0, f"max error {worst(t, sel).max():.3f} %"
    assert t["k_sp_n_m"][sel][-1] < 0.7 * t["k_sp_n_m"][sel][0], "K_sp must fall markedly"


def test_demod_recovers_from_stiffness_steps_to_80_60_50_percent():
    """Fig. 4.6 scenario (the steps the thesis applies to the fixed-gain loop), here with the
    demodulation controller: K_sp steps down to 80, 60 and 50 % of nominal at cycles 200, 400,
    600 (crack held still). A step drops the force at once (f = K_sp·Δy) at a cycle boundary;
    the amplitude and mean loops see it only through their one-cycle estimation window (the
    thesis's low-pass estimators of θ1, θ2), so the recovery window is 2 cycles: the step's cycle
    and the one after. Outside it, amplitude and mean must stay within ±2 %. (Measured: the inner
    force P holds even the step cycles inside, worst 1.99 % at the 60 % step.)"""
    d = base_doc()
    d["law"]["c"] = 1e-40
    d["end"]["max_cycles"] = 800
    d["stiffness_steps"] = [[200, 0.8], [400, 0.6], [600, 0.5]]
    o = run(d)
    t = o.table
    amp_err = ((t["fmax_n"] - t["fmin_n"]) / (t["fmax_target_n"] - t["fmin_target_n"]) - 1) * 100
    mean_err = ((t["fmax_n"] + t["fmin_n"]) / (t["fmax_target_n"] + t["fmin_target_n"]) - 1) * 100
    cyc = t["cycle"]
    judged = in_test(t)
    for step, factor in [(200, 0.8), (400, 0.6), (600, 0.5)]:
        i = np.searchsorted(cyc, step)
        assert (t["events"][i] & EV["stiffness_step"]) and t["k_sp_n_m"][i] / t["k_sp_n_m"][0] == pytest.approx(factor, rel=1e-6)
        assert max(abs(amp_err[i:i + 2]).max(), abs(mean_err[i:i + 2]).max()) < 5.0, "bounded inside the window"
        judged[i:i + 2] = False
    assert abs(amp_err[judged]).max() < 2.0 and abs(mean_err[judged]).max() < 2.0
    assert t["k_sp_n_m"][-1] == pytest.approx(0.5 * t["k_sp_n_m"][0], rel=1e-6)
    # convergence is logged for the start and after every step, from the step's own cycle
    conv = o.convergence
    assert [e["cause"] for e in conv] == ["start", "stiffness_step", "stiffness_step", "stiffness_step"]
    assert [e["first_cycle"] for e in conv[1:]] == [200, 400, 600]
    for e in conv:
        assert e["cycles_to_2pct"] is not None and e["cycles_to_2pct"] <= 2, e
        assert e["cycles_to_0p5pct"] is not None and e["cycles_to_0p5pct"] <= 3, e
    assert conv[0]["cycles_to_2pct"] == 0 and conv[0]["worst_first_df_pct"] < 2.0
    assert min(e["worst_first_df_pct"] for e in conv[1:]) > 0.5, "a stiffness drop is seen in its first cycle"


@pytest.mark.parametrize("loading", [
    {"mode": "constant_delta_k", "delta_k_pa_sqrt_m": 18e6, "r_ratio": 0.1},
    {"mode": "k_gradient", "delta_k_pa_sqrt_m": 20e6, "k_gradient_per_m": -80.0, "r_ratio": 0.1},
])
def test_delta_k_control_holds_the_schedule_within_two_percent(loading):
    d = base_doc()
    d["loading"] = {**{k: d["loading"][k] for k in ("waveform", "frequency_hz", "control_rate_hz")}, **loading}
    d["law"]["c"] *= 20
    d["end"]["a_over_w"] = 0.45
    o = run(d)
    t = o.table
    sel = in_test(t)
    dk, target = t["delta_k_pa_sqrt_m"][sel], t["delta_k_target_pa_sqrt_m"][sel]
    assert np.max(np.abs(dk / target - 1)) < 0.02
    if loading["mode"] == "k_gradient":
        a = t["a_m"][sel]
        expected = 20e6 * np.exp(-80.0 * (a - d["specimen"]["a0_m"]))
        assert np.allclose(target, expected, rtol=1e-9)
        assert target[-1] < 0.6 * target[0], "ΔK must fall along the schedule"
    assert o.end_reason == "target_crack_length"


def test_precrack_phase_then_test_phase():
    d = base_doc()
    d["precrack"] = {"mode": "constant_force", "delta_f_n": 5000.0, "r_ratio": 0.1, "end_a_m": 0.0165}
    d["law"]["c"] *= 20
    d["end"]["a_over_w"] = 0.4
    t = run(d).table
    change = np.nonzero(t["events"] & EV["phase_change"])[0]
    assert len(change) == 1
    assert np.all(t["phase"][:change[0] + 1] == 0) and np.all(t["phase"][change[0] + 1:] == 1)
    assert t["fmax_target_n"][0] == pytest.approx(5000 / 0.9) and t["fmax_target_n"][-1] == pytest.approx(4450 / 0.9)


def test_jump_mode_matches_full_fidelity():
    d = base_doc()
    d["law"]["c"] *= 10
    full, jump = run(d, "full"), run(d, "jump")
    assert jump.end_reason == full.end_reason == "target_crack_length"
    assert jump.a_end_m == pytest.approx(full.a_end_m, abs=0.05e-3)
    assert abs(jump.cycles / full.cycles - 1) < 0.005
    assert jump.cycles_simulated < full.cycles_simulated / 3


def test_batch_returns_each_result_in_order():
    docs = []
    for scale in (5, 10):
        d = base_doc()
        d["law"]["c"] *= scale
        docs.append(parse(d).config)
    outs = core.run_batch(docs, "jump", 2)
    singles = [core.run_test(c, "jump") for c in docs]
    assert [o.cycles for o in outs] == [s.cycles for s in singles]
    assert outs[0].cycles > outs[1].cycles


@pytest.mark.parametrize("edit, words", [
    (lambda d: d["loading"].update(r_ratio=1.0), ["loading.r_ratio", "[-1, 1)"]),
    (lambda d: d["loading"].update(r_ratio=-1.5), ["loading.r_ratio", "-1.5"]),
    (lambda d: d["loading"].update(frequency_hz=0.0), ["loading.frequency_hz", "(0, 6250]"]),
    (lambda d: d["loading"].update(frequency_hz=80.0, control_rate_hz=4000.0), ["frequency_hz", "resonance"]),
    (lambda d: d["specimen"].update(a0_m=0.005), ["specimen.a0_m", "a/W in [0.2, 0.975]"]),
    (lambda d: d["end"].update(a_over_w=0.99), ["end.a_over_w", "0.975"]),
    (lambda d: d["material"].update(fracture_toughness_pa_sqrt_m=15e6), ["K_IC"]),
    (lambda d: d["loading"].update(colour="red"), ["unknown key", "colour"]),
    (lambda d: d.update(extra={}), ["unknown key", "extra"]),
    (lambda d: d["loading"].update(mode="k_gradient", delta_k_pa_sqrt_m=15e6, k_gradient_per_m=-100.0, delta_f_n=None) or d["loading"].pop("delta_f_n"),
     ["k_gradient_per_m", "0.08 mm⁻¹"]),
])
def test_bad_specs_fail_before_anything_runs(edit, words):
    d = base_doc()
    edit(d)
    with pytest.raises(SpecError) as e:
        parse(d)
    for w in words:
        assert w in str(e.value), str(e.value)


def test_htm_run_writes_outputs_and_rejects_bad_spec(tmp_path, capsys):
    out = tmp_path / "ct"
    assert main(["run", str(EXAMPLE), "--out", str(out), "--quiet"]) == 0
    s = json.loads((out / "summary.json").read_text())
    for k in ("cycles", "end_reason", "final_a_m", "max_abs_df_err_pct", "max_abs_peak_err_pct", "wall_time_s"):
        assert k in s
    # in the band from the first full-amplitude cycle, and said so
    assert s["convergence"][0]["cause"] == "start" and s["cycles_to_2pct"] == 0 and s["worst_first_cycles_df_pct"] < 2.0
    assert "inside ±2 % from the first cycle" in (out / "summary.txt").read_text()
    assert s["end_reason"] == "target_crack_length" and s["final_a_m"] >= 0.6 * 0.0508
    assert s["max_abs_df_err_pct"] < 2 and s["max_abs_peak_err_pct"] < 2
    import pyarrow.parquet as pq
    t = pq.read_table(out / "cycles.parquet")
    assert {"cycle", "fmax_n", "fmin_n", "a_m", "delta_k_pa_sqrt_m", "k_sp_n_m", "dadn_m_per_cycle", "events"} <= set(t.column_names)
    # the E647 test report of the run (issue 4 item 6): B.1-style table, plots, force band, validity
    md = (out / "report.md").read_text()
    assert "±2 % band" in md and "Validity summary" in md and "Table B.1" in md and "![da/dN-dK]" in md
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") >= 2
    assert "target_crack_length" in capsys.readouterr().out
    bad = tmp_path / "bad.toml"
    bad.write_text(EXAMPLE.read_text().replace("r_ratio = 0.1", "r_ratio = 1.2"))
    assert main(["run", str(bad), "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert "loading.r_ratio" in err and "Traceback" not in err
    assert not (tmp_path / "b").exists()
    assert load(EXAMPLE).mode == "jump"


WAVES = {"sine": {}, "triangle": {}, "trapezoid": {"rise_fraction": 0.2, "hold_fraction": 0.3}}


@pytest.mark.parametrize("mode", ["full", "jump"])
@pytest.mark.parametrize("wave", list(WAVES))
def test_every_waveform_holds_two_percent_after_ramp_in(wave, mode):
    """ISO 12108 judges peaks and valleys; the demodulation loops hold the fundamental and mean.
    Peak-valley compensation (control.rs PeakValley) closes the gap for shapes with corners:
    sine, triangle and trapezoid at 10 Hz on the default rig, example C(T), every test cycle
    after the ramp-in within ±2 % in ΔF and peak (measured: ≤ 1.05 %)."""
    d = base_doc()
    d["loading"].update(waveform=wave, **WAVES[wave])
    d["law"]["c"] *= 10
    o = run(d, mode)
    assert o.end_reason == "target_crack_length"
    assert o.max_abs_df_err_pct < 2.0 and o.max_abs_peak_err_pct < 2.0, (o.max_abs_df_err_pct, o.max_abs_peak_err_pct)
    t = o.table
    assert worst(t, in_test(t)).max() < 2.0


@pytest.mark.parametrize("wave", list(WAVES))
@pytest.mark.parametrize("f_hz, df_n", [(30.0, 4450.0), (40.0, 4450.0), (40.0, 6000.0), (45.0, 3000.0)])
def test_in_the_band_from_the_first_full_amplitude_cycle_at_high_frequency(wave, f_hz, df_n):
    """Feasible tests up to 45 Hz: with the default ramp-in (20 cycles or 1 s, whichever is
    longer) the first 20 full-amplitude cycles are inside ±2 % (a 20-cycle ramp left the 6 kN
    40 Hz triangle at 2.05 %); the ramp lasts the second."""
    d = base_doc()
    d["loading"].update(waveform=wave, frequency_hz=f_hz, delta_f_n=df_n, **WAVES[wave])
    d["end"]["max_cycles"] = 5 + int(f_hz) + 25
    spec = parse(d)
    assert spec.feasibility().feasible
    o = core.run_test(spec.config, "full")
    e = o.convergence[0]
    assert e["worst_first_df_pct"] < 2.0 and e["cycles_to_2pct"] == 0, e
    ramp = o.table["events"] & START != 0
    assert ramp.sum() == 5 + int(f_hz), "5 mean cycles, then the amplitude over 1 s"
    assert core.start_amplitude_cycles(f_hz) == int(f_hz), "the core says the same ramp-in"


def test_a_waveform_beyond_the_valve_is_refused_while_a_sine_runs_in_band():
    """With a small valve (12 L/min), a steep trapezoid (rise 5 % of the cycle) needs 6.4× the
    sine's piston speed: refused before anything runs, with the speeds named; the sine on the
    same rig runs inside ±2 %."""
    d = base_doc()
    d["rig"] = {"overrides": {"valve_rated_flow_m3_s": 2e-4}}
    d["law"]["c"] *= 10
    o = run(d, "jump")
    assert o.end_reason == "target_crack_length" and max(o.max_abs_df_err_pct, o.max_abs_peak_err_pct) < 2.0
    d["loading"].update(waveform="trapezoid", rise_fraction=0.05, hold_fraction=0.4)
    with pytest.raises(SpecError) as e:
        parse(d)
    msg = str(e.value)
    for w in ("loading.frequency_hz", "trapezoid waveform", "mm/s", "rated flow"):
        assert w in msg, msg


@pytest.mark.parametrize("wave,extra", [("triangle", ""), ("trapezoid", "rise_fraction = 0.2\nhold_fraction = 0.3\n")])
def test_triangle_and_trapezoid_specs_run_through_htm_run_inside_the_band(tmp_path, wave, extra, capsys):
    text = EXAMPLE.read_text().replace('waveform = "sine"', f'waveform = "{wave}"\n{extra}')
    spec = tmp_path / f"{wave}.toml"
    spec.write_text(text)
    out = tmp_path / wave
    assert main(["run", str(spec), "--out", str(out), "--quiet"]) == 0, capsys.readouterr().err
    s = json.loads((out / "summary.json").read_text())
    assert s["end_reason"] == "target_crack_length"
    import pyarrow.parquet as pq
    t = pq.read_table(out / "cycles.parquet").to_pydict()
    assert len(t["df_err_pct"]) == len(t["cycle"]) > 100
    assert all(x == x for x in t["df_err_pct"] + t["peak_err_pct"]), "an error for every cycle, no NaN"
    assert 0.0 < s["max_abs_df_err_pct"] < 2.0 and 0.0 < s["max_abs_peak_err_pct"] < 2.0


def test_mt_specimen_runs_through_htm_run(tmp_path, capsys):
    """An M(T) panel (ASTM E647): K from eq. A2.1, K_sp from the grip-to-grip compliance; the
    stiffness falls as the crack grows and the force stays in band."""
    text = EXAMPLE.read_text().replace('geometry = "ct"', 'geometry = "mt"').replace("width_m = 0.0508", "width_m = 0.1") \
        .replace("thickness_m = 0.00635", "thickness_m = 0.006").replace("a0_m = 0.0152 ", "a0_m = 0.0100 ") \
        .replace("delta_f_n = 4450.0", "delta_f_n = 40000.0").replace("a_over_w = 0.6", "a_over_w = 0.5") \
        .replace("c = 1.1413e-29", "c = 1.1413e-28")
    spec = tmp_path / "mt.toml"
    spec.write_text(text)
    assert load(spec).geometry == "mt"
    out = tmp_path / "mt"
    assert main(["run", str(spec), "--out", str(out), "--quiet"]) == 0, capsys.readouterr().err
    s = json.loads((out / "summary.json").read_text())
    assert s["end_reason"] == "target_crack_length"
    assert s["final_a_m"] == pytest.approx(0.025, abs=0.1e-3), "2a/W = 0.5 on W = 100 mm"
    assert s["max_abs_df_err_pct"] < 2.0 and s["max_abs_peak_err_pct"] < 2.0
    import pyarrow.parquet as pq
    t = pq.read_table(out / "cycles.parquet").to_pydict()
    assert t["k_sp_n_m"][-1] < 0.85 * t["k_sp_n_m"][0]
    assert "MT W = 100.0 mm" in capsys.readouterr().out


def test_negative_r_runs_with_delta_k_equal_to_kmax():
    """R < 0 is supported down to −1: E647 takes ΔK = Kmax (compressive part excluded)."""
    d = base_doc()
    d["loading"]["r_ratio"] = -0.5
    d["law"]["c"] *= 10
    o = run(d, "jump")
    t = o.table
    sel = in_test(t) & ((t["events"] & EV["jump"]) == 0)
    assert o.end_reason == "target_crack_length" and o.max_abs_df_err_pct < 2.0
    assert np.allclose(t["fmin_target_n"][sel], -0.5 * t["fmax_target_n"][sel])
    assert np.all(t["fmin_n"][sel] < 0), "the valley is compressive"
    assert np.allclose(t["delta_k_pa_sqrt_m"][sel], t["kmax_pa_sqrt_m"][sel])


def test_rig_overrides_in_the_spec_reach_the_plant():
    """[rig] overrides: a larger valve null bias moves the command that holds the mean by the
    same amount; a heavier moving mass lowers the resonance and with it the highest frequency."""
    def u2(bias: float) -> float:
        d = base_doc()
        d["rig"] = {"overrides": {"valve_null_bias_v": bias}}
        d["end"]["max_cycles"] = 100
        return float(np.median(run(d).table["ctrl_u2_v"][-20:]))
    assert u2(0.415) - u2(0.115) == pytest.approx(-0.3, abs=0.02)
    d = base_doc()
    d["loading"].update(frequency_hz=40.0)
    parse(d)  # fine on the default rig (limit 53 Hz)
    d["rig"] = {"overrides": {"moving_mass_kg": 4 * 53.78}}
    with pytest.raises(SpecError, match="frequency_hz.*resonance"):
        parse(d)
    d["rig"] = {"overrides": {"moving_mass": 100.0}}
    with pytest.raises(SpecError, match="unknown parameter `moving_mass`"):
        parse(d)


def test_all_three_controllers_are_chosen_from_a_spec():
    """controller.type: demodulation (thesis 4.2), force_p (the thesis's comparison case) and
    position_pff (thesis 4.1: position P + velocity feed-forward, the force setpoint turned into a
    position through the specimen stiffness measured each cycle). Position control alone holds the
    stiff C(T)'s force to a few % only; the peak-valley compensation corrects its force as it does
    the demodulation controller's, so all but the uncompensated force P start inside ±0.5 %."""
    def worst_err(ctrl: dict) -> float:
        d = base_doc()
        d["controller"] = ctrl
        d["end"]["max_cycles"] = 300
        o = run(d)
        assert o.end_reason == "cycle_limit"
        return max(o.max_abs_df_err_pct, o.max_abs_peak_err_pct)
    demod = worst_err({"type": "demodulation"})
    force_p = worst_err({"type": "force_p", "kp_v_per_n": -8e-4, "u_offset_v": -0.115})
    pff = worst_err({"type": "position_pff", "u_offset_v": -0.115})
    p_only = worst_err({"type": "position_pff", "u_offset_v": -0.115, "kff_v_per_m_s": 0.0})
    assert demod < 0.5 and force_p < 2.0
    assert pff < 0.5 and p_only < 0.5, (pff, p_only)
    with pytest.raises(SpecError, match="controller \\(type position_pff\\): unknown key kp_v_per_n"):
        parse({**base_doc(), "controller": {"type": "position_pff", "kp_v_per_n": 1.0}})


def test_progress_bar_draws_its_last_line_once(capsys):
    from htm.run import run_spec
    spec = parse(base_doc())
    out, _ = run_spec(spec, "jump", progress=True)
    err = capsys.readouterr().err
    last = f"  {int(out.cycles):,} cycles"
    assert err.count(last) == 1, err[-400:]
    # off a terminal: plain lines (no carriage return), the last complete with the end reason
    assert err.endswith("\n") and "\r" not in err
    assert "100.0 %" in err.splitlines()[-1] and out.end_reason in err.splitlines()[-1]
