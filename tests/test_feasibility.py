"""Know before you start (issue 19 item 4): `htm run --check`, the refusal before every run, the
override, and a forced test that reports the force error it really reached."""
from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from htm.errors import InfeasibleTest
from htm.spec import load, parse

ROOT = Path(__file__).resolve().parents[1]
BEYOND = ROOT / "examples" / "mt_beyond_capacity.toml"
CT = ROOT / "examples" / "ct_constant_force.toml"
# the thesis rig in tension: 2.5635 cm² × 190 bar less the 53.78 kg moving mass's weight
CAPACITY_N = 2.5635e-3 * 19e6 - 53.78 * 9.80665


def htm_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "htm.cli", *args], capture_output=True, text=True, timeout=120)


def doc(path: Path = CT) -> dict:
    return tomllib.loads(path.read_text())


def refusal(d: dict) -> str:
    with pytest.raises(InfeasibleTest) as e:
        parse(d)
    return str(e.value)


def check(d: dict, name: str):
    return next(c for c in parse(d, check=False).feasibility().checks if c.name == name)


def test_the_88_9_kn_spec_is_refused_by_check_naming_capacity_and_largest_delta_f():
    r = htm_cli("run", "--check", str(BEYOND))
    assert r.returncode == 1, r.stderr
    assert "Traceback" not in r.stderr
    line = next(ln for ln in r.stdout.splitlines() if "force capacity (tension)" in ln)
    assert line.startswith("REFUSED") and "peak force 88.9 kN" in line and "48.2 kN in tension" in line, line
    assert "largest feasible ΔF 43.4 kN" in line, line
    assert "verdict: refused: force capacity (tension)" in r.stdout


def test_htm_run_refuses_it_before_anything_runs(tmp_path):
    out = tmp_path / "out"
    r = htm_cli("run", str(BEYOND), "--out", str(out), "--no-store", "--quiet")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.startswith("htm run: error: the rig cannot run this test"), r.stderr
    for w in ("88.9 kN", "48.2 kN", "largest feasible ΔF 43.4 kN", "override_limits"):
        assert w in r.stderr, r.stderr
    assert not (out / "summary.json").exists()


def test_a_forced_test_reports_its_real_force_error_and_invalid_points(tmp_path):
    """[run] override_limits runs a test past the force capacity (a 60 kN peak from 48 kN): the
    summary says OUTSIDE the band with the measured error, the report states it, and the points
    over those cycles are invalid. (At 88.9 kN the mean itself is above capacity: the actuator
    pins at full force, ΔF collapses and the crack does not grow — no E647 report to read.)"""
    text = BEYOND.read_text().replace('mode = "jump"', 'mode = "jump"\noverride_limits = true') \
        .replace("delta_f_n = 80010.0 ", "delta_f_n = 54000.0 ") \
        .replace("c = 2.0e-28 ", "c = 2.0e-27 ").replace("max_cycles = 200000", "max_cycles = 20000")
    spec = tmp_path / "forced.toml"
    spec.write_text(text)
    out = tmp_path / "out"
    r = htm_cli("run", str(spec), "--out", str(out), "--no-store", "--quiet")
    assert r.returncode == 0, r.stderr
    assert "warning: force_tension" in r.stderr and "override_limits: running anyway" in r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["override_limits"] is True and s["force_in_band"] is False
    assert s["feasibility"] == "refused: force capacity (tension)"
    assert s["max_abs_df_err_pct"] > 10.0, "the actuator cannot give the force: the error is large"
    txt = (out / "summary.txt").read_text()
    assert f"max |ΔF| {s['max_abs_df_err_pct']:.3f} %" in txt and "OUTSIDE the ISO 12108 band ±2 %" in txt
    md = (out / "report.md").read_text()
    assert "stayed inside" not in md and "The force left the ±2 % band" in md
    assert f"measured max |ΔF error| {s['max_abs_df_err_pct']:.3f} %" in md
    rows = (out / "reduced.csv").read_text().splitlines()[1:]
    assert rows and all("force_band" in row for row in rows if ",1," not in row)
    assert sum("force_band" in row for row in rows) > 0.9 * len(rows)


def test_a_test_in_band_reports_inside(tmp_path):
    d = doc()
    d["law"]["c"] *= 10
    d["end"]["a_over_w"] = 0.45  # the size criterion holds all the way
    spec = tmp_path / "ok.toml"
    from htm.spec import dumps
    spec.write_text(dumps(d))
    out = tmp_path / "out"
    r = htm_cli("run", str(spec), "--out", str(out), "--no-store", "--quiet")
    assert r.returncode == 0, r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["force_in_band"] is True and s["feasibility"] == "feasible" and s["override_limits"] is False
    assert "inside the ISO 12108 band ±2 %" in (out / "summary.txt").read_text()
    assert "The force stayed inside the ±2 % band on every cycle" in (out / "report.md").read_text()


def test_force_refusal_lifts_just_below_the_largest_feasible_delta_f():
    d = doc(BEYOND)
    c = check(d, "force_tension")
    assert c.status == "refused" and c.limit == pytest.approx(CAPACITY_N, rel=1e-9)
    assert c.largest_delta_f_n == pytest.approx(0.9 * CAPACITY_N, rel=1e-9), "ΔF = (1 − R)·capacity"
    d["loading"]["delta_f_n"] = 0.99 * c.largest_delta_f_n
    assert parse(d).feasibility().feasible
    assert check(d, "force_tension").status == "marginal", "99 % of the capacity has no headroom"


def test_compression_is_checked_against_the_other_side():
    d = doc(BEYOND)
    d["loading"].update(r_ratio=-1.0, delta_f_n=60e3)  # R < 0: ΔF = Fmax, valley −60 kN
    c = check(d, "force_compression")
    assert c.status == "refused" and c.need == pytest.approx(60e3)
    assert "valley force -60 kN" in refusal(d)


def test_valve_flow_refusal_names_speeds_and_the_largest_frequency():
    d = doc()
    d["rig"] = {"overrides": {"valve_rated_flow_m3_s": 2e-5}}
    msg = refusal(d)
    for w in ("loading.frequency_hz = 10 Hz", "sine waveform", "mm/s", "rated flow", "largest feasible frequency"):
        assert w in msg, msg
    c = check(d, "valve_flow")
    d["loading"]["frequency_hz"] = 0.99 * c.largest_frequency_hz
    assert check(d, "valve_flow").status != "refused"


def test_frequency_refusal_names_the_resonance_and_the_largest_frequency():
    d = doc()
    d["loading"].update(frequency_hz=80.0, control_rate_hz=4000.0)
    msg = refusal(d)
    assert "loading.frequency_hz = 80 Hz" in msg and "resonance" in msg and "largest feasible frequency 53.1 Hz" in msg, msg
    d["loading"]["frequency_hz"] = 53.0
    assert check(d, "frequency").status == "marginal"


def test_size_criterion_refused_from_the_start_and_warned_part_way():
    d = doc()
    d["material"]["yield_strength_pa"] = 60e6
    msg = refusal(d)
    assert "at a = 15.20 mm the ligament is 35.60 mm" in msg and "over the whole crack range" in msg, msg
    c = check(d, "size_criterion")
    d["loading"]["delta_f_n"] = 0.99 * c.largest_delta_f_n
    assert check(d, "size_criterion").status == "ok"
    # the example: the steel's ligament runs out near a = 30 mm, before a/W = 0.6: a warning
    c = check(doc(), "size_criterion")
    assert c.status == "marginal" and 29.5e-3 < c.a_m < 30.5e-3 and "the points beyond are invalid" in c.text


def test_stroke_refusal():
    d = doc()
    d["rig"] = {"overrides": {"specimen_zero_force_position_m": 0.19895}}
    msg = refusal(d)
    assert "mm of stroke are left" in msg and "largest feasible ΔF" in msg, msg


def test_a_variable_amplitude_sequence_is_judged_by_its_levels():
    """[loading]'s constant ΔF fits the actuator; one block of the sequence does not: the check
    judges the levels that run, and says how far the whole sequence could be scaled."""
    d = doc(BEYOND)
    d["run"] = {"mode": "full"}
    d["loading"]["delta_f_n"] = 20e3
    assert check(d, "force_tension").status == "ok"
    d["variable_amplitude"] = {"blocks": [[50, 20e3, 0.1], [5, 63e3, 0.1], [20, 15e3, 0.5]]}
    c = check(d, "force_tension")
    assert c.status == "refused" and c.need == pytest.approx(70e3) and c.delta_f_n == pytest.approx(63e3)
    msg = refusal(d)
    assert "peak force 70 kN" in msg and "for the sequence's level of ΔF 63 kN" in msg, msg
    assert f"scale the sequence by {0.9 * CAPACITY_N / 63e3:.3g}" in msg, msg
    d["variable_amplitude"]["blocks"][1][1] = 0.99 * c.largest_delta_f_n
    assert check(d, "force_tension").status == "marginal"
    # the deepest valley of the sequence is judged against compression
    d["variable_amplitude"] = {"blocks": [[50, 20e3, 0.1], [1, 60e3, -1.0]]}
    c = check(d, "force_compression")
    assert c.status == "refused" and c.need == pytest.approx(60e3)


def test_the_override_is_explicit_and_a_boolean():
    d = doc(BEYOND)
    d["run"]["override_limits"] = True
    assert parse(d).override_limits
    d["run"]["override_limits"] = "yes"
    with pytest.raises(Exception, match="override_limits = 'yes' must be true or false"):
        parse(d)


@pytest.mark.parametrize("name", ["ct_constant_force.toml", "virkler_mt.toml"])
def test_the_examples_pass_the_check(name):
    r = htm_cli("run", "--check", str(ROOT / "examples" / name))
    assert r.returncode == 0, r.stdout + r.stderr
    assert "REFUSED" not in r.stdout and load(ROOT / "examples" / name).feasibility().feasible


def test_the_live_rig_report_says_outside_when_the_force_left_the_band():
    import numpy as np

    from htm.control.recorder import summary_markdown

    spec = load(CT)
    row = {"id": "t1", "status": "finished", "end_reason": "operator stop", "events": []}

    def table(err: float) -> dict:
        n = 30
        return {"cycle": np.arange(n), "a_m": np.full(n, spec.a0_m), "starting": np.zeros(n, bool),
                "df_err_pct": np.full(n, err), "peak_err_pct": np.full(n, 0.5)}

    assert "max |ΔF| 1.500 %, max |peak| 0.500 %: inside the ISO 12108 band ±2 %" in summary_markdown(spec, row, table(1.5), None)
    assert "max |ΔF| 37.000 %, max |peak| 0.500 %: OUTSIDE the ISO 12108 band ±2 %" in summary_markdown(spec, row, table(37.0), None)
