"""Careless input, every command: a binary, non-UTF-8, empty or header-only file, a NaN or a
1e400 where a number belongs, a misspelt required key and a file of another kind (a model, spec
or table meant for another command) each end in exit 2 with ONE line on stderr naming the file
(and the field, where there is one), and no traceback.

The corpus is generated here from valid inputs by fixed rules (the first number of a file, the
first key, the first column), not picked to pass; the valid inputs are checked to be accepted,
so a refusal is the bad part's doing."""
from __future__ import annotations

import functools
import json
import re
import shutil
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from htm import cli
from htm.ident.records import Record, write_record

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
BINARY = bytes(range(256)) * 4  # every byte value, NULs included
LATIN1 = "cycles,a_mm\n0,15.2\n1000,15.9 µm\n".encode("latin-1")  # text, but not UTF-8
VARIANTS = ("binary", "latin1", "empty", "header_only", "nan", "1e400", "misspelt_key", "wrong_kind")


def misspell(key: str) -> str:
    """A plausible typo of `key`: the case of a one- or two-letter name, else two letters swapped."""
    if len(key) <= 2:
        return key.upper()
    swapped = key[0] + key[2] + key[1] + key[3:]
    return swapped if swapped != key else key[0] + key[1] * 2 + key[2:]


# ---- valid inputs of each kind --------------------------------------------------------------

def spec_text() -> str:
    return (EXAMPLES / "ct_constant_force.toml").read_text()


def a_n_text() -> str:
    n = np.linspace(0, 60_000, 25)
    a = 15.2e-3 + 12e-3 * (n / n[-1]) ** 2
    return "cycles,a_m\n" + "".join(f"{x:.0f},{y:.6e}\n" for x, y in zip(n, a))


def crack_model() -> dict:
    return {"law": "paris", "parameters": {"log10_c": {"value": -11.0}, "m": {"value": 3.0}}}


def rig_model() -> dict:
    from htm.core import Params

    p = Params("thesis")
    return {"format": "htm-model/1", "family": "valve", "params": {"supply_pressure_pa": p["supply_pressure_pa"]},
            "channels": ["y"], "record": "r"}


@functools.cache
def _ramps() -> Record:
    """A record of the simulated rig: constant-velocity ramps (what `htm identify` needs)."""
    from htm.ident.experiments import position_record, ramp_reference
    from htm.params import thesis_rig

    return position_record(thesis_rig(), ramp_reference([0.01, 0.02, 0.05, 0.1, 0.2, 0.4], 500.0), 500.0, name="rec")


@functools.cache
def _ramps_files(tmp: Path) -> tuple[Path, Path]:
    rec = _ramps()
    return write_record(Record(dict(rec.columns), dict(rec.meta), "rec"), tmp / "_ramps" / "rec")


def record_files(tmp: Path, name: str = "rec") -> tuple[Path, Path]:
    """The ramps record as NAME.csv + NAME.json in `tmp` (written once, then copied)."""
    table, meta = _ramps_files(tmp.parent)
    tmp.mkdir(parents=True, exist_ok=True)
    shutil.copy(table, tmp / f"{name}.csv")
    shutil.copy(meta, tmp / f"{name}.json")
    return tmp / f"{name}.csv", tmp / f"{name}.json"


# ---- the variants of a file, by its format ----------------------------------------------------

NUM_TOML = re.compile(r'^(\s*)([A-Za-z_][\w.]*)(\s*=\s*)([-+]?\d[\d_.eE+-]*)(\s*(#.*)?)$', re.M)
KEY_TOML = re.compile(r'^(\s*)([A-Za-z_][\w]*)(\s*=)', re.M)


def toml_variant(text: str, kind: str) -> tuple[str, str | None]:
    """(text, the field the error must name) of a TOML file's variant."""
    if kind == "header_only":
        return "".join(line + "\n" for line in text.splitlines() if line.strip().startswith("[")), None
    if kind in ("nan", "1e400"):
        m = NUM_TOML.search(text)
        return text[: m.start(4)] + ("nan" if kind == "nan" else "1e400") + text[m.end(4):], m.group(2)
    if kind == "misspelt_key":
        m = KEY_TOML.search(text)
        return text[: m.start(2)] + misspell(m.group(2)) + text[m.end(2):], m.group(2)
    raise ValueError(kind)


def csv_variant(text: str, kind: str) -> tuple[str, str | None]:
    lines = text.splitlines()
    header = lines[0].split(",")
    if kind == "header_only":
        return lines[0] + "\n", None
    if kind in ("nan", "1e400"):
        row = lines[3].split(",")
        row[0] = "nan" if kind == "nan" else "1e400"
        return "\n".join([*lines[:3], ",".join(row), *lines[4:]]) + "\n", header[0]
    if kind == "misspelt_key":
        return ",".join([misspell(header[0]), *header[1:]]) + "\n" + "\n".join(lines[1:]) + "\n", header[0]
    raise ValueError(kind)


def json_variant(d: dict, kind: str) -> tuple[str, str | None]:
    if kind == "header_only":
        return "{}", None
    if kind in ("nan", "1e400"):
        def first_number(o: dict, parent: str = "") -> tuple[dict, str, str] | None:
            for k, v in o.items():
                if isinstance(v, (int, float)) and not isinstance(v, bool):
                    return o, k, parent if k == "value" else k  # {"m": {"value": 3}}: the field is `m`
                if isinstance(v, dict) and (found := first_number(v, k)):
                    return found
            return None
        d = json.loads(json.dumps(d))
        holder, key, field = first_number(d)
        holder[key] = float("nan") if kind == "nan" else 1.5e300
        text = json.dumps(d)
        return (text.replace("1.5e+300", "1e400") if kind == "1e400" else text), field
    if kind == "misspelt_key":
        first = next(iter(d))
        return json.dumps({(misspell(first) if k == first else k): v for k, v in d.items()}), first
    raise ValueError(kind)


@dataclass
class Case:
    command: str
    argv: Callable[[Path], list[str]]  # the command line, given the folder of its files
    bad: Path  # the file of the variant (relative to the folder)
    field: str | None  # the field the line must name


def write(folder: Path, rel: str, content: str | bytes) -> Path:
    p = folder / rel
    p.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(content, bytes):
        p.write_bytes(content)
    else:
        p.write_text(content)
    return p


def variant_content(fmt: str, valid: str | dict, kind: str, other: str | bytes) -> tuple[str | bytes, str | None]:
    if kind == "binary":
        return BINARY, None
    if kind == "latin1":
        return LATIN1, None
    if kind == "empty":
        return b"", None
    if kind == "wrong_kind":
        return other, None
    if fmt == "toml":
        return toml_variant(str(valid), kind)
    if fmt == "csv":
        return csv_variant(str(valid), kind)
    return json_variant(valid, kind)  # type: ignore[arg-type]


# every command that reads a file a person hands it: (name, format, valid content, a file of
# another kind, file name, argv given the folder)
AN_ARGS = ["--geometry", "ct", "--width-m", "0.0508", "--thickness-m", "0.00635", "--delta-p-n", "4450", "--r-ratio", "0.1"]


def commands(tmp: Path) -> list[tuple[str, str, str | dict, str | bytes, str, Callable[[Path], list[str]]]]:
    spec, an = spec_text(), a_n_text()
    campaign = (EXAMPLES / "campaign_ct.toml").read_text()
    rig = (EXAMPLES / "rig_virtual.toml").read_text()
    profile = "u\n" + "".join(f"{0.5 * np.sin(i / 10):.4f}\n" for i in range(200))
    table, meta = record_files(tmp / "valid")
    rec_csv, rec_meta = table.read_text(), json.loads(meta.read_text())
    store = str(tmp / "store")
    return [
        ("run", "toml", spec, campaign, "t.toml", lambda d: ["run", str(d / "t.toml"), "--out", str(d / "o"), "--store", store, "--no-recording", "--quiet"]),
        ("run --check", "toml", spec, json.dumps(crack_model()), "t.toml", lambda d: ["run", "--check", str(d / "t.toml")]),
        ("campaign", "toml", campaign, spec, "c.toml", lambda d: ["campaign", str(d / "c.toml"), "--store", store, "--out", str(d / "o"), "--quiet"]),
        ("life-band", "csv", an, rec_csv, "an.csv", lambda d: ["life-band", str(EXAMPLES / "ct_constant_force.toml"), "--data", str(d / "an.csv"),
                                                                 "--store", store, "--out", str(d / "o"), "--quiet", "--samples", "8"]),
        ("life-band spec", "toml", spec, campaign, "t.toml", lambda d: ["life-band", str(d / "t.toml"), "--data", str(d / "an.csv"),
                                                                          "--store", store, "--out", str(d / "o"), "--quiet", "--samples", "8"]),
        ("e647", "csv", an, rec_csv, "an.csv", lambda d: ["e647", str(d / "an.csv"), *AN_ARGS, "--out", str(d / "o")]),
        ("crack fit", "csv", an, rec_csv, "an.csv", lambda d: ["crack", "fit", str(d / "an.csv"), *AN_ARGS, "--out", str(d / "o")]),
        ("crack predict", "json", crack_model(), json.dumps(rig_model()), "m.json",
         lambda d: ["crack", "predict", str(d / "m.json"), *AN_ARGS, "--a0-m", "0.0152", "--af-m", "0.03"]),
        ("identify", "csv", rec_csv, an, "r.csv", lambda d: ["identify", str(d / "r.csv"), "--out", str(d / "o")]),
        ("identify meta", "json", rec_meta, json.dumps(crack_model()), "r.json", lambda d: ["identify", str(d / "r.csv"), "--out", str(d / "o")]),
        ("diagnose", "csv", rec_csv, an, "r.csv", lambda d: ["diagnose", str(d / "r.csv"), "--out", str(d / "o")]),
        ("diagnose meta", "json", rec_meta, json.dumps(rig_model()), "r.json", lambda d: ["diagnose", str(d / "r.csv"), "--out", str(d / "o")]),
        ("predict", "json", rig_model(), json.dumps(crack_model()), "m.json",
         lambda d: ["predict", str(d / "m.json"), str(d / "r.csv"), "--out", str(d / "o")]),
        ("predict record", "csv", rec_csv, an, "r.csv", lambda d: ["predict", str(d / "m.json"), str(d / "r.csv"), "--out", str(d / "o")]),
        ("fleet add", "csv", rec_csv, an, "r.csv", lambda d: ["fleet", "add", str(d / "r.csv"), "--machine", "m1", "--date", "2026-01-02", "--store", store]),
        ("rig serve", "toml", rig, spec, "rig.toml", lambda d: ["rig", "serve", str(d / "rig.toml"), "--seconds", "0.1"]),
        ("simulate", "csv", profile, an, "p.csv", lambda d: ["simulate", "--profile", f"csv:path={d / 'p.csv'}", "--out", str(d / "o" / "sim")]),
    ]


def build_corpus(tmp: Path) -> list[Case]:
    cases = []
    for name, fmt, valid, other, fname, argv in commands(tmp):
        for kind in VARIANTS:
            d = tmp / f"{name.replace(' ', '_')}-{kind}"
            # the files beside it stay valid: the record's other half, a model for `predict`
            table, meta = record_files(d, "r")
            write(d, "m.json", json.dumps(rig_model()))
            write(d, "an.csv", a_n_text())
            write(d, "c.toml", (EXAMPLES / "campaign_ct.toml").read_text())
            shutil.copy(EXAMPLES / "ct_constant_force.toml", d / "ct_constant_force.toml")
            content, field = variant_content(fmt, valid, kind, other)
            write(d, fname, content)
            cases.append(Case(f"{name} × {kind}", argv, d / fname, field))
    return cases


def run_main(argv: list[str], capsys: pytest.CaptureFixture) -> tuple[int, str, str]:
    try:
        code = cli.main(argv)
    except SystemExit as e:  # argparse
        code = int(e.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def test_the_valid_inputs_are_accepted(tmp_path, capsys):
    """The corpus's starting points are good input: a refusal below is the variant's doing."""
    cmds = {c[0]: c for c in commands(tmp_path)}
    d = tmp_path / "ok"
    record_files(d, "r")
    write(d, "m.json", json.dumps(rig_model()))
    write(d, "an.csv", a_n_text())
    write(d, "t.toml", spec_text())
    write(d, "p.csv", cmds["simulate"][2])
    write(d, "cm.json", json.dumps(crack_model()))
    for argv in (["run", "--check", str(d / "t.toml")], ["e647", str(d / "an.csv"), *AN_ARGS, "--out", str(d / "o1")],
                 ["crack", "predict", str(d / "cm.json"), *AN_ARGS, "--a0-m", "0.0152", "--af-m", "0.03"],
                 ["identify", str(d / "r.csv"), "--out", str(d / "o2")],
                 ["simulate", "--profile", f"csv:path={d / 'p.csv'}", "--out", str(d / "o3" / "sim")]):
        code, out, err = run_main(argv, capsys)
        assert code == 0, (argv, err)
    from htm.ident.predict import read_model
    from htm.ident.records import read_record
    from htm.spec import load

    assert read_model(d / "m.json").family == "valve"
    assert len(read_record(d / "r.csv").columns["t"]) == 8600
    assert load(d / "t.toml").name == "t"


def test_every_command_refuses_every_bad_file_in_one_line(tmp_path, capsys):
    cases = build_corpus(tmp_path)
    assert len(cases) == 17 * len(VARIANTS)
    failures = []
    for case in cases:
        argv = case.argv(case.bad.parent)
        code, out, err = run_main(argv, capsys)
        lines = [x for x in err.splitlines() if x.strip()]
        problems = []
        if code != 2:
            problems.append(f"exit {code}")
        if len(lines) != 1:
            problems.append(f"{len(lines)} lines on stderr")
        if "Traceback" in err:
            problems.append("traceback")
        if lines and case.bad.name not in lines[0]:
            problems.append("the file is not named")
        if lines and case.field and case.field not in lines[0]:
            problems.append(f"the field `{case.field}` is not named")
        if problems:
            failures.append(f"{case.command}: {', '.join(problems)}: {err.strip()[:300]!r}")
    assert not failures, "\n".join(failures)


def test_the_entry_point_prints_no_traceback(tmp_path):
    """The installed `htm` script, as a person runs it, for one bad file of each format."""
    htm = Path(sys.executable).with_name("htm")
    an = write(tmp_path, "an.csv", "cycles,a_m\n0,0.0152\n1000,nan\n2000,0.016\n")
    rec, meta = record_files(tmp_path, "bin")
    rec.write_bytes(BINARY)
    spec = write(tmp_path, "s.toml", spec_text().replace("geometry", misspell("geometry"), 1))
    crack = write(tmp_path, "cm.json", json.dumps(crack_model()))
    runs = {
        "e647": ([str(htm), "e647", str(an), *AN_ARGS, "--out", str(tmp_path / "o")], "line 3", "a_m"),
        "diagnose": ([str(htm), "diagnose", str(rec), "--out", str(tmp_path / "o")], "bin.csv", "binary"),
        "run": ([str(htm), "run", str(spec), "--out", str(tmp_path / "o2")], "s.toml", "geometry"),
        "predict": ([str(htm), "predict", str(crack), str(rec), "--out", str(tmp_path / "o")], "cm.json", "crack-growth model"),
    }
    for name, (argv, *must) in runs.items():
        p = subprocess.run(argv, capture_output=True, text=True, timeout=120)
        assert p.returncode == 2, (name, p.stderr)
        assert "Traceback" not in p.stderr and len(p.stderr.strip().splitlines()) == 1, (name, p.stderr)
        for m in must:
            assert m in p.stderr, (name, m, p.stderr)


def test_a_misspelt_key_names_its_close_match(tmp_path, capsys):
    d = tmp_path
    write(d, "an.csv", a_n_text().replace("cycles", "cycels", 1))
    code, _, err = run_main(["e647", str(d / "an.csv"), *AN_ARGS, "--out", str(d / "o")], capsys)
    assert code == 2 and "`cycles` is missing (found `cycels`" in err
    write(d, "t.toml", spec_text().replace("delta_f_n", "delta_fn", 1))
    code, _, err = run_main(["run", "--check", str(d / "t.toml")], capsys)
    assert code == 2 and "delta_fn" in err and "perhaps `delta_f_n`" in err


def test_a_dropped_sample_is_said_on_the_terminal_with_its_row(tmp_path, capsys):
    """DATA_FORMAT.md: a NaN in a channel is a dropped sample, tolerated; the command says so on
    stderr (not only in report.md). A NaN in `t` or any 1e400 is refused (the corpus above)."""
    table, _ = record_files(tmp_path, "r")
    lines = table.read_text().splitlines()
    head = lines[0].split(",")
    row = lines[10].split(",")
    row[head.index("y")] = "nan"
    lines[10] = ",".join(row)
    table.write_text("\n".join(lines) + "\n")
    code, out, err = run_main(["identify", str(table), "--out", str(tmp_path / "o")], capsys)
    assert code == 0, err
    assert "htm identify: warning:" in err and "`y`" in err and "1 dropped" in err


def test_identify_refuses_a_machine_position_record_by_name(tmp_path, capsys):
    t = np.arange(400) / 500.0
    y = 0.1 + 0.01 * np.sin(2 * np.pi * t)
    write_record(Record({"t": t, "y": y, "y_ref": y}, {"sample_rate_hz": 500.0, "controller": {"type": "machine_position"}}, "mp"),
                 tmp_path / "mp")
    code, _, err = run_main(["identify", str(tmp_path / "mp.csv"), "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "KeyError" not in err and "closes its own loop" in err and "`u`" in err


def test_an_af_beyond_the_specimen_is_said_in_metres_and_millimetres(tmp_path, capsys):
    write(tmp_path, "cm.json", json.dumps(crack_model()))
    base = ["crack", "predict", str(tmp_path / "cm.json"), *AN_ARGS, "--a0-m", "0.0152"]
    code, _, err = run_main([*base, "--af-m", "0.06"], capsys)
    assert code == 2 and "0.06 m (60 mm)" in err and "50.8 mm" in err and "millimetres" not in err
    code, _, err = run_main([*base, "--af-m", "30"], capsys)  # 30 mm given as metres
    assert code == 2 and "give 0.03" in err
