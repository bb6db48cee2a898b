"""The crack measured on the rig (issue 29): a K-decreasing test through `htm.Session` on a
virtual rig whose specimen grows by a law the spec does not know, run on the clip gauge's
compliance; the gauges' faults hold the test with a named event and it resumes; the spec's
`[measurement]` and the rig's crack channels are checked before anything runs."""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from htm.control.session import Session, specimen_of
from htm.devices.config import virtual_config
from htm.errors import DeviceError, HtmError
from htm.spec import SpecError, parse

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
import crack_rig  # noqa: E402


def test_k_decreasing_on_the_measured_crack_holds_delta_k_on_the_true_crack():
    """C(T) of examples/ct_constant_force.toml, ΔK 14 → 7 MPa·√m at C = −0.08 mm⁻¹, the rig's
    law C × 1.4, closure at 30 % of Fmax (both laws × 600: about 1100 cycles)."""
    r = crack_rig.run("ct", 600.0, 0.1, "compliance", 3, 0.3)
    assert r["end"] == "target_crack_length" and r["trips"] == [], r
    assert r["dk_true_err_max_pct"] < 2.0, r
    assert r["a_err_max_mm"] < r["a_resolution_mm"], r
    assert r["opening_force_err_max_pct_fmax"] < 5.0, r


def _rig(**virtual):
    return virtual_config("lockstep", analog={"channels": {"cod": "ai4", "dcpd": "ai5", "dcpd_current": "ai6"}},
                          virtual={"specimen": {"c_factor": 1.4}, **virtual})


@pytest.mark.parametrize(("crack", "fault", "detector"), [
    ("compliance", "gauge_slip", "gauge_slip"),
    ("compliance", "gauge_out_of_range", "gauge_range"),
    ("potential_drop", "dcpd_current_lost", "dcpd_current"),
])
def test_a_gauge_fault_holds_the_test_and_it_resumes(crack, fault, detector):
    doc = crack_rig.spec_doc("ct", 100.0, 0.1, crack)
    spec = parse(doc, "faults", check=False)
    s = Session().open(_rig(), virtual=True, specimen=specimen_of(spec), thread=False)
    try:
        s.step(5)
        s.start(spec, record=False)
        s.step(50 * 40)
        ctrl = s.loop.ctrl
        assert ctrl.state == "running", [e["message"] for e in s.events_since(0)]
        n0 = ctrl.cycle
        s.rig.inject(fault)
        s.step(50 * 4)
        trips = [e for e in s.events_since(0) if e["kind"] == "trip"]
        assert [e["detector"] for e in trips] == [detector], [e["message"] for e in trips]
        assert ctrl.state == "holding"
        held = ctrl.cycle
        assert held <= n0 + 2, "the hold came within the cycle of the fault"
        s.step(50 * 5)
        assert ctrl.cycle == held, "held cycles are not counted"
        s.rig.clear_faults()
        s.step(10)
        assert s.reset() == []
        s.resume()
        s.step(50 * 30)
        assert ctrl.state == "running" and ctrl.cycle > held + 20
        rows = [c for c in s.cycles_since(0)]
        cycles = [c["cycle"] for c in rows]
        assert cycles == list(range(1, len(cycles) + 1)), "no cycle lost or repeated"
        # the crack reading goes on after the fault: the measured crack follows the true one
        assert abs(ctrl.a_m - s.rig.plant.a_m) < 1e-4, (ctrl.a_m, s.rig.plant.a_m)
    finally:
        s.close()


def test_measurement_spec_and_rig_channels_are_checked_before_anything_runs():
    doc = crack_rig.spec_doc("ct", 1.0, 0.1, "compliance")
    doc["measurement"]["crack"] = "laser"
    with pytest.raises(SpecError, match="measurement.crack"):
        parse(doc, "x", check=False)
    doc["measurement"] = {"crack": "compliance", "gauge_x_over_w": -0.3}
    with pytest.raises(SpecError, match="measurement.gauge_x_over_w"):
        parse(doc, "x", check=False)
    doc["measurement"] = {"crack": "potential_drop"}  # probes not placed
    with pytest.raises(SpecError, match="measurement.gauge_y_m"):
        parse(doc, "x", check=False)
    with pytest.raises(DeviceError, match="dcpd_current"):
        virtual_config("lockstep", analog={"channels": {"dcpd": "ai5"}})
    with pytest.raises(DeviceError, match="ai0..ai7"):
        virtual_config("lockstep", analog={"channels": {"cod": "ai8"}})
    # a compliance test on a rig without a clip gauge is refused before it starts
    spec = parse(crack_rig.spec_doc("ct", 100.0, 0.1, "compliance"), "x", check=False)
    s = Session().open(virtual_config("lockstep"), virtual=True, specimen=specimen_of(spec), thread=False)
    try:
        with pytest.raises(HtmError, match="analog.channels.cod"):
            s.start(spec, record=False)
    finally:
        s.close()
    assert math.isfinite(spec.config.params["supply_pressure_pa"])


def test_htm_run_reports_the_measured_crack_beside_the_law(tmp_path, capsys):
    """`htm run` of a spec with a measured crack: summary.json and summary.txt say which crack the
    test ran on, how many readings, where the law's crack stands at the end and the opening
    forces; crack_vs_law.png is drawn. A spec on the law's crack has none of it."""
    import json

    from htm.cli import main

    out = tmp_path / "kdec"
    assert main(["run", str(ROOT / "examples" / "ct_k_decreasing_measured.toml"), "--out", str(out), "--no-store", "--quiet"]) == 0
    m = json.loads((out / "summary.json").read_text())["measurement"]
    assert m["crack"] == "compliance" and m["readings"] > 50 and m["failed_readings"] == 0
    # in simulation the true crack grows by the spec's own law: measured and law agree to the
    # measurement's resolution, and the closure set in the spec shows in the opening forces
    assert abs(m["a_end_m"] - m["a_law_end_m"]) < 1e-4
    assert m["opening_force_n"][0] > 0 and m["delta_k_eff_ratio"][0] < 0.9
    assert (out / "crack_vs_law.png").stat().st_size > 10_000
    assert "measured crack  compliance" in (out / "summary.txt").read_text()
    plain = tmp_path / "ct"
    assert main(["run", str(ROOT / "examples" / "ct_constant_force.toml"), "--out", str(plain), "--no-store", "--quiet"]) == 0
    assert "measurement" not in json.loads((plain / "summary.json").read_text())
    assert not (plain / "crack_vs_law.png").exists()


def test_htm_run_report_md_plots_measured_and_law_crack_and_lists_the_opening_force(tmp_path):
    """report.md of a constant-force test run on a measured crack (compliance, closure at 30 % of
    Fmax): the a–N of the measured crack with the law's beside it, and the opening forces and
    ΔK_eff per reading, near the closure put on the simulated specimen."""
    from htm.cli import main

    text = (ROOT / "examples" / "ct_constant_force.toml").read_text()
    spec = tmp_path / "ct_measured.toml"
    spec.write_text(text + '\n[measurement]\ncrack = "compliance"\nclosure_opening_fraction = 0.3\nnoise = 2e-7\n')
    out = tmp_path / "run"
    assert main(["run", str(spec), "--out", str(out), "--no-store", "--quiet"]) == 0
    md = (out / "report.md").read_text()
    assert "## Measured crack and the law" in md and "![a-N measured and law](a_n_vs_law.png)" in md
    assert (out / "a_n_vs_law.png").stat().st_size > 10_000
    assert "## Crack closure (opening force, ΔK_eff)" in md
    sec = md.split("## Crack closure")[1].split("\n## ")[0]
    rows = [r.split("|") for r in sec.splitlines() if r.startswith("|") and r[1:3].strip()[:1].isdigit()]
    share = np.array([float(r[3]) for r in rows])
    dk, dke = np.array([float(r[4]) for r in rows]), np.array([float(r[5]) for r in rows])
    assert len(rows) >= 10 and np.all(np.abs(share - 0.3) < 0.05), share
    assert np.all(dke < dk)
    # the same spec on the law: no measured section
    plain = tmp_path / "plain"
    assert main(["run", str(ROOT / "examples" / "ct_constant_force.toml"), "--out", str(plain), "--no-store", "--quiet"]) == 0
    md = (plain / "report.md").read_text()
    assert "Measured crack and the law" not in md and "Crack closure" not in md
