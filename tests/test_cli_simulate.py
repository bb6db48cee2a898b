"""`htm simulate` writes DATA_FORMAT records; bad input ends in one clear line, never a traceback."""
import json
import subprocess
import sys

import numpy as np
import pytest

from htm.ident import read_record


def htm_cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "htm.cli", *args], capture_output=True, text=True, cwd=cwd, timeout=120)


def test_open_loop_profile_writes_a_record_that_reads_back(tmp_path):
    out = tmp_path / "steps"
    r = htm_cli("simulate", "--profile", "hold:value=-0.115,duration=0.2;hold:value=1,duration=0.3",
                "--profile", "ramp:start=1,end=-1,duration=0.2;sine:amplitude=0.5,frequency=5,duration=0.3",
                "--rate", "1000", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "velocity" in r.stdout and "real time" in r.stdout
    rec = read_record(tmp_path / "steps.csv")
    meta = json.loads((tmp_path / "steps.json").read_text())
    assert meta["format"] == "htm-record/1" and meta["sample_rate_hz"] == 1000
    assert meta["controller"] is None and meta["specimen"] is None
    assert meta["rig"]["area_a_m2"] == pytest.approx(2.5635e-3) and meta["rig"]["orientation"] == "vertical"
    assert set(rec.columns) == {"t", "u", "y", "v", "p_a", "p_b", "p_s"}, "no force column without a specimen"
    t = rec.columns["t"]
    assert len(t) == 1000 and np.allclose(np.diff(t), 1e-3)
    assert rec.columns["u"][250] == pytest.approx(1.0)
    # positive command retracts the thesis rig's piston
    assert rec.columns["v"][450] < -0.05


def test_position_control_record_declares_its_controller_and_tracks(tmp_path):
    r = htm_cli("simulate", "--controller", "position_pff", "--kp", "-150", "--kff", "-14.3",
                "--profile", "hold:value=0.1,duration=0.3;ramp:start=0.1,end=0.12,duration=0.5", "--gz",
                "--specimen-stiffness-n-m", "1e6", "--start-position-m", "0.1", "--out", str(tmp_path / "pos"))
    assert r.returncode == 0, r.stderr
    rec = read_record(tmp_path / "pos.csv.gz")
    c = rec.meta["controller"]
    assert c["type"] == "position_pff" and c["kp_v_per_m"] == -150 and "law" in c
    assert rec.meta["specimen"] == {"stiffness_n_m": 1e6}
    assert "y_ref" in rec.columns and "f" in rec.columns
    assert abs(rec.columns["y"][-1] - rec.columns["y_ref"][-1]) < 2e-3


def test_force_control_record(tmp_path):
    r = htm_cli("simulate", "--controller", "force_p", "--kp=-1e-4", "--specimen-stiffness-n-m", "1.04e8",
                "--rate", "1000", "--profile", "sine:amplitude=2000,frequency=10,offset=20000,duration=0.5",
                "--out", str(tmp_path / "force"))
    assert r.returncode == 0, r.stderr
    rec = read_record(tmp_path / "force.csv")
    assert "f_ref" in rec.columns and rec.columns["f"].max() > 5000


@pytest.mark.parametrize(
    "args,needle",
    [
        (["--profile", "wiggle:value=1,duration=1"], "unknown kind"),
        (["--profile", "hold:value=1"], "missing duration"),
        (["--profile", "hold:value=abc,duration=1"], "not a number"),
        (["--profile", "hold:value=1,duration=1", "--param", "moving_mass_kg=0"], "moving_mass_kg"),
        (["--profile", "hold:value=1,duration=1", "--param", "stroke_m=-0.2"], "stroke_m"),
        (["--profile", "hold:value=1,duration=1", "--param", "warp_drive=1"], "unknown parameter"),
        (["--profile", "hold:value=1,duration=1", "--controller", "position_pff"], "--kp"),
        (["--profile", "csv:path=/nonexistent.csv"], "/nonexistent.csv: no such"),
        (["--profile", "hold:value=1,duration=1", "--rate", "0"], "rate"),
    ],
)
def test_bad_input_gives_one_clear_line_and_exit_2(tmp_path, args, needle):
    r = htm_cli("simulate", "--out", str(tmp_path / "x"), *args)
    assert r.returncode == 2
    assert needle in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "x.csv").exists()


def test_csv_profile_and_refusal_to_overwrite(tmp_path):
    prof = tmp_path / "cmd.csv"
    prof.write_text("t,u\n" + "".join(f"{k * 0.002},{0.5 if k < 100 else -0.5}\n" for k in range(200)))
    base = str(tmp_path / "rec")
    assert htm_cli("simulate", "--profile", f"csv:path={prof}", "--out", base).returncode == 0
    before = (tmp_path / "rec.csv").read_text()
    r = htm_cli("simulate", "--profile", f"csv:path={prof}", "--out", base)
    assert r.returncode == 2 and "refusing to overwrite" in r.stderr
    assert (tmp_path / "rec.csv").read_text() == before


def test_every_subcommand_has_help():
    from htm.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert {"simulate", "params"} <= set(sub.choices)
    for name in sub.choices:
        r = htm_cli(name, "--help")
        assert r.returncode == 0 and "usage:" in r.stdout, name


@pytest.mark.parametrize("edit,message", [
    (("tolerance_cycles = 10", "tolerance_cycles = 99999999999999999999999"), "end.tolerance_cycles = 99999999999999999999999 must be an integer in [0, "),
    (("frequency_hz = 10.0", "frequency_hz = 1e300"), "loading.frequency_hz = 1e+300 is out of range: allowed (0, 6250] Hz"),
])
def test_out_of_range_spec_numbers_are_one_clear_line(tmp_path, edit, message):
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "examples" / "ct_constant_force.toml").read_text()
    assert edit[0] in text
    spec = tmp_path / "s.toml"
    spec.write_text(text.replace(edit[0], edit[1]))
    r = htm_cli("run", str(spec), "--out", str(tmp_path / "o"), "--no-store", "--quiet")
    assert r.returncode == 2 and "Traceback" not in r.stderr and message in r.stderr, r.stderr


def test_a_profile_too_long_to_hold_and_an_unknown_key_are_clear_errors(tmp_path):
    r = htm_cli("simulate", "--profile", "hold:value=1,duration=1e7", "--out", str(tmp_path / "x"))
    assert r.returncode == 2 and "at most 10,000,000" in r.stderr and "Traceback" not in r.stderr, r.stderr
    r = htm_cli("simulate", "--profile", "sine:amplitude=1,frequency=2,duration=1,ofset=3", "--out", str(tmp_path / "x"))
    assert r.returncode == 2 and "unknown key(s) ofset" in r.stderr and "optional offset, phase" in r.stderr, r.stderr


def test_run_into_an_unwritable_out_stores_nothing(tmp_path):
    (tmp_path / "file").write_text("")
    store = tmp_path / "store"
    from pathlib import Path

    spec = Path(__file__).resolve().parents[1] / "examples" / "ct_constant_force.toml"
    r = htm_cli("run", str(spec), "--out", str(tmp_path / "file" / "out"), "--store", str(store), "--quiet")
    assert r.returncode == 2 and "cannot write there" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not (store / "catalogue.sqlite").exists() or htm_cli("db", "list", "--store", str(store)).stdout.startswith("no tests")
