"""Classic identification (thesis chapter 3) on records from the simulated rig."""
import json
import subprocess
import sys

import numpy as np
import pytest

from htm.errors import RecordError
from htm.ident import write_record
from htm.ident.classic import identify
from htm.ident.experiments import position_record, ramp_reference
from htm.params import thesis_rig

SPEEDS = [0.005, 0.01, 0.02, 0.04, 0.08, 0.15, 0.3, 0.45]


@pytest.fixture(scope="module")
def offset_record():
    """Constant-velocity ramps at 500 Hz with the thesis's 4 bar offset on the p_a transducer.
    The position loop does not use p_a, so adding the offset to the recorded column is exact."""
    rec = position_record(thesis_rig(), ramp_reference(SPEEDS, 500.0), 500.0, name="offset4bar")
    rec.columns["p_a"] = rec.columns["p_a"] + 4.0e5
    return rec


def test_the_offset_term_exposes_a_4_bar_chamber_a_transducer_offset(offset_record):
    r = identify(offset_record)
    off = r["offset"]
    assert off["as_chamber_a_pressure_pa"] == pytest.approx(4.0e5, rel=0.05)
    # without the offset term the Stribeck model cannot explain the data
    assert off["r2_without"] < 0.9 < 0.9999 < off["r2_with"]
    # with it, the friction of eq. 3.20 comes back
    for name in ("stribeck_sig", "stribeck_sig_nls"):
        fp = r["friction"][name]["params"]
        assert fp["viscous_n_s_m"] == pytest.approx(5017.35, rel=0.05)
        assert fp["coulomb_n"] == pytest.approx(792.33, rel=0.05)
        assert fp["static_n"] == pytest.approx(102.61, rel=0.25)
    assert r["friction"]["linear"]["r2"] < r["friction"]["stribeck_sig"]["r2"]


def test_clean_record_needs_no_offset(offset_record):
    rec = position_record(thesis_rig(), ramp_reference(SPEEDS, 500.0), 500.0, name="clean")
    r = identify(rec)
    assert abs(r["offset"]["as_chamber_a_pressure_pa"]) < 2e3


def test_velocity_gain_and_hydraulic_null(offset_record):
    vg = identify(offset_record)["velocity_gain"]
    assert vg["gain_m_s_per_v"] == pytest.approx(-0.07, rel=0.1)  # thesis: y' ~ -0.07 u
    assert vg["null_command_v"] == pytest.approx(-0.115, abs=0.02)
    assert vg["r2"] > 0.99


def test_mass_from_acceleration_when_the_sampling_resolves_the_motion():
    rec = position_record(thesis_rig(), ramp_reference([0.04, 0.08, 0.15, 0.3, 0.45], 5000.0), 5000.0)
    assert identify(rec)["mass"]["moving_mass_kg"] == pytest.approx(53.78, rel=0.05)


def test_records_without_motion_cannot_be_identified():
    rec = position_record(thesis_rig(), np.full(1000, 0.1), 500.0)
    with pytest.raises(RecordError, match="cannot identify"):
        identify(rec)


def test_htm_identify_cli_writes_report(tmp_path, offset_record):
    table, _ = write_record(offset_record, tmp_path / "rec")
    r = subprocess.run([sys.executable, "-m", "htm.cli", "identify", str(table), "--out", str(tmp_path / "id")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    result = json.loads((tmp_path / "id" / "identification.json").read_text())
    assert result["offset"]["as_chamber_a_pressure_pa"] == pytest.approx(4e5, rel=0.05)
    md = (tmp_path / "id" / "report.md").read_text()
    assert "bar on chamber A" in md and (tmp_path / "id" / "friction.png").stat().st_size > 1000
    bad = subprocess.run([sys.executable, "-m", "htm.cli", "identify", str(tmp_path / "nope.csv"), "--out", str(tmp_path / "x")],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
