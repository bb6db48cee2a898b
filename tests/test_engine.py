"""The fatigue test engine: thesis reproductions (chapter 4), ΔK control, bad specs, `htm run`."""
from __future__ import annotations

import copy
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from htm import _core
from htm.cli import main
from htm.errors import SpecError
from htm.spec import load, parse

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "ct_constant_force.toml"
START, STOP = 1, 128


def base_doc() -> dict:
    return tomllib.loads(EXAMPLE.read_text())


def run(doc: dict, mode: str = "full") -> dict:
    return _core.run_test(parse(doc).to_config(), mode)


def in_test(t: dict) -> np.ndarray:
    return (t["events"] & (START | STOP)) == 0


def worst(t: dict, sel: np.ndarray) -> np.ndarray:
    return np.maximum(np.abs(t["peak_err_pct"][sel]), np.abs(t["df_err_pct"][sel]))


def fig_4_8_doc(controller: dict) -> dict:
    """Fig. 4.8 scenario on the linear-valve plant the thesis's comparison assumes (preset "base"):
    C(T) of Table B.1, 4.45 kN at R = 0.1, 9 Hz with 500 Hz control, a fast-growing crack
    (Paris C × 30) from a/W 0.30 to 0.50 so that K_sp falls to ≈ 40 %."""
    d = base_doc()
    d["rig"] = {"preset": "base"}
    d["controller"] = controller
    d["loading"]["frequency_hz"] = 9.0
    d["loading"]["control_rate_hz"] = 500.0
    d["law"]["c"] *= 30
    d["end"]["a_over_w"] = 0.5
    return d


def test_fixed_gain_force_p_leaves_the_band_as_the_crack_grows():
    o = run(fig_4_8_doc({"type": "force_p", "kp_v_per_n": -1e-4, "u_offset_v": -0.115}))
    t = o["table"]
    sel = in_test(t)
    err = worst(t, sel)
    ksp = t["k_sp_n_m"][sel] / t["k_sp_n_m"][sel][0]
    assert err[:50].max() < 2.0, "starts inside the ±2 % band"
    first_out = np.argmax(err > 2.0)
    assert err.max() > 2.0 and first_out > 100, "leaves the band only after the crack has grown"
    assert ksp[first_out] < 0.8, f"leaves the band when K_sp has fallen (K_sp/K0 = {ksp[first_out]:.2f})"


def test_demod_holds_the_band_in_the_fig_4_8_scenario():
    o = run(fig_4_8_doc({"type": "demodulation"}))
    t = o["table"]
    assert o["end_reason"] == "target_crack_length"
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
    t = o["table"]
    sel = in_test(t)
    assert o["cycles"] == 60_000 and o["end_reason"] == "cycle_limit"
    assert worst(t, sel).max() < 2.0, f"max error {worst(t, sel).max():.3f} %"
    assert t["k_sp_n_m"][sel][-1] < 0.7 * t["k_sp_n_m"][sel][0], "K_sp must fall markedly"


def test_demod_recovers_from_stiffness_steps_to_80_60_50_percent():
    """Fig. 4.6–4.7 scenario: K_sp steps down to 80, 60 and 50 % of nominal (crack held still).
    A step drops the force at once (f = K_sp·Δy); the controller must bring peak and range back
    inside ±2 % within a few cycles and keep them there."""
    d = base_doc()
    d["law"]["c"] = 1e-40
    d["end"]["max_cycles"] = 800
    d["stiffness_steps"] = [[200, 0.8], [400, 0.6], [600, 0.5]]
    o = run(d)
    t = o["table"]
    err = worst(t, np.ones(len(t["cycle"]), bool))
    cyc = t["cycle"]
    for step, factor in [(200, 0.8), (400, 0.6), (600, 0.5)]:
        i = np.searchsorted(cyc, step)
        assert (t["events"][i] & 32) and t["k_sp_n_m"][i] / t["k_sp_n_m"][0] == pytest.approx(factor, rel=1e-6)
        window = err[i:i + 200]
        back = np.argmax(window < 2.0)
        assert back <= 25, f"step to {factor}: back inside after {back} cycles"
        assert window[back + 5:].max() < 2.0, f"step to {factor}: stays inside"
        assert window[:back].max() > 2.0 if back else True


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
    t = o["table"]
    sel = in_test(t)
    dk, target = t["delta_k_pa_sqrt_m"][sel], t["delta_k_target_pa_sqrt_m"][sel]
    assert np.max(np.abs(dk / target - 1)) < 0.02
    if loading["mode"] == "k_gradient":
        a = t["a_m"][sel]
        expected = 20e6 * np.exp(-80.0 * (a - d["specimen"]["a0_m"]))
        assert np.allclose(target, expected, rtol=1e-9)
        assert target[-1] < 0.6 * target[0], "ΔK must fall along the schedule"
    assert o["end_reason"] == "target_crack_length"


def test_precrack_phase_then_test_phase():
    d = base_doc()
    d["precrack"] = {"mode": "constant_force", "delta_f_n": 5000.0, "r_ratio": 0.1, "end_a_m": 0.0165}
    d["law"]["c"] *= 20
    d["end"]["a_over_w"] = 0.4
    t = run(d)["table"]
    change = np.nonzero(t["events"] & 64)[0]
    assert len(change) == 1
    assert np.all(t["phase"][:change[0] + 1] == 0) and np.all(t["phase"][change[0] + 1:] == 1)
    assert t["fmax_target_n"][0] == pytest.approx(5000 / 0.9) and t["fmax_target_n"][-1] == pytest.approx(4450 / 0.9)


def test_jump_mode_matches_full_fidelity():
    d = base_doc()
    d["law"]["c"] *= 10
    full, jump = run(d, "full"), run(d, "jump")
    assert jump["end_reason"] == full["end_reason"] == "target_crack_length"
    assert jump["a_end_m"] == pytest.approx(full["a_end_m"], abs=0.05e-3)
    assert abs(jump["cycles"] / full["cycles"] - 1) < 0.005
    assert jump["cycles_simulated"] < full["cycles_simulated"] / 3


def test_batch_returns_each_result_in_order():
    docs = []
    for scale in (5, 10):
        d = base_doc()
        d["law"]["c"] *= scale
        docs.append(parse(d).to_config())
    outs = _core.run_batch(docs, "jump", 2)
    singles = [_core.run_test(c, "jump") for c in docs]
    assert [o["cycles"] for o in outs] == [s["cycles"] for s in singles]
    assert outs[0]["cycles"] > outs[1]["cycles"]


@pytest.mark.parametrize("edit, words", [
    (lambda d: d["loading"].update(r_ratio=1.0), ["loading.r_ratio", "[-1, 1)"]),
    (lambda d: d["loading"].update(r_ratio=-1.5), ["loading.r_ratio", "-1.5"]),
    (lambda d: d["loading"].update(frequency_hz=0.0), ["loading.frequency_hz", "(0, inf)"]),
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


@pytest.mark.parametrize("wave,extra", [("triangle", ""), ("trapezoid", "rise_fraction = 0.2\nhold_fraction = 0.3\n")])
def test_triangle_and_trapezoid_tests_run_to_the_end_and_flag_force_errors(tmp_path, wave, extra, capsys):
    text = EXAMPLE.read_text().replace('waveform = "sine"', f'waveform = "{wave}"\n{extra}')
    spec = tmp_path / f"{wave}.toml"
    spec.write_text(text)
    out = tmp_path / wave
    assert main(["run", str(spec), "--out", str(out), "--quiet"]) == 0, capsys.readouterr().err
    s = json.loads((out / "summary.json").read_text())
    assert s["end_reason"] == "target_crack_length"
    # The demodulation carrier is sinusoidal, so the sharp peaks of these waveforms are not held
    # to +-2 % yet (known gap of issue 3); the per-cycle table must say so rather than hide it.
    import pyarrow.parquet as pq
    t = pq.read_table(out / "cycles.parquet").to_pydict()
    assert len(t["df_err_pct"]) == len(t["cycle"]) > 100
    assert all(x == x for x in t["df_err_pct"] + t["peak_err_pct"]), "an error for every cycle, no NaN"
    assert 0.0 < s["max_abs_df_err_pct"] < 100.0 and 0.0 < s["max_abs_peak_err_pct"] < 100.0
