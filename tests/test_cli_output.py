"""What `htm` prints: for a person, labelled values in engineering units (mm, kN, MPa·√m, bar),
aligned, no Python reprs, no `..` paths; with `--json`, the same results as JSON in SI for
scripts, on every command that prints results."""
import argparse
import json
import re
from pathlib import Path

import pytest

from htm import cli

SPEC = Path(__file__).resolve().parents[1] / "examples" / "ct_constant_force.toml"
# commands that print results (every one takes --json); the others print an id or a status
RESULT_COMMANDS = {"simulate", "params", "run", "resume", "e647", "crack fit", "crack predict", "identify", "diagnose",
                   "predict", "campaign", "life-band", "db list", "db show", "db export", "fleet add", "fleet diagnose",
                   "fleet trend"}
REPR = re.compile(r"\{'|\[\{|\d\.\d{8,}|/\.\./")  # a dict/list repr, a float printed to 16 digits, a/../b


def leaves(parser: argparse.ArgumentParser, prefix: str = "") -> dict[str, argparse.ArgumentParser]:
    out = {}
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            for name, p in a.choices.items():
                out.update(leaves(p, f"{prefix} {name}".strip()))
    return out or {prefix: parser}


def test_every_command_that_prints_results_takes_json():
    cmds = leaves(cli.build_parser())
    with_json = {name for name, p in cmds.items() if any("--json" in a.option_strings for a in p._actions)}
    assert RESULT_COMMANDS <= set(cmds)
    assert with_json >= RESULT_COMMANDS, RESULT_COMMANDS - with_json


@pytest.fixture(scope="module")
def stored(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("out")
    store = tmp / "store"
    # the outputs outside the store: the catalogue keeps them as store/../out (the path)
    assert cli.main(["run", str(SPEC), "--out", str(tmp / "out" / "ct"), "--store", str(store), "--no-recording", "--quiet"]) == 0
    return tmp, store


def test_db_show_is_labelled_engineering_units_without_reprs(stored, capsys, monkeypatch):
    tmp, store = stored
    monkeypatch.chdir(tmp)
    capsys.readouterr()
    assert cli.main(["db", "last", "--store", str(store)]) == 0
    tid = capsys.readouterr().out.strip()
    assert cli.main(["db", "show", tid, "--store", str(store)]) == 0
    text = capsys.readouterr().out
    assert not REPR.search(text), REPR.search(text)
    rows = {ln.split("  ")[0].strip(): ln for ln in text.splitlines() if ln.startswith("  ")}
    assert re.search(r"final a\s+30\.48 mm", text)
    assert re.search(r"velocity gain\s+-?\d+\.\d+ mm/s per V", text)
    assert re.search(r"max abs df err\s+0\.\d+ %", text)
    assert re.search(r"convergence\s+cause start, first cycle \d+", text)
    assert "out/ct/report.md" in text and "store/tests/" in text  # paths relative to here, no ..
    assert rows  # the indented result rows
    # labels aligned: every result value starts in the same column
    res = text.split("results:\n")[1].split("events")[0].splitlines()
    starts = {len(re.match(r"  (\S+(?: \S+)*)\s+", ln).group(0)) for ln in res}
    assert len(starts) == 1, res
    assert cli.main(["db", "show", tid, "--store", str(store), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["id"] == tid and d["results"]["final_a_m"] == pytest.approx(0.03048, rel=1e-3)
    assert isinstance(d["results"]["convergence"], list) and d["results"]["convergence"][0]["cause"] == "start"


def test_run_json_is_the_summary_in_si(stored, capsys):
    tmp, store = stored
    capsys.readouterr()
    assert cli.main(["run", str(SPEC), "--out", str(tmp / "o2"), "--store", str(store), "--no-recording", "--quiet", "--json"]) == 0
    out = capsys.readouterr().out
    s = json.loads(out)  # stdout is the JSON and nothing else
    assert s["end_reason"] == "target_crack_length" and s["final_a_over_w"] == pytest.approx(0.6, abs=1e-3)
    assert s["test_id"] and s["force_in_band"] is True
    assert cli.main(["run", "--check", str(SPEC), "--json"]) == 0
    chk = json.loads(capsys.readouterr().out)
    assert chk["feasible"] is True and {c["name"] for c in chk["checks"]} >= {"force_tension", "valve_flow", "stroke"}


def test_db_list_is_a_table_with_units(stored, capsys):
    tmp, store = stored
    capsys.readouterr()
    assert cli.main(["db", "list", "--store", str(store)]) == 0
    head, *rows = capsys.readouterr().out.splitlines()
    assert "a end [mm]" in head and rows
    assert all(re.search(r"\s30\.4\d\d\s", r) for r in rows), rows
    assert cli.main(["db", "list", "--store", str(store), "--json"]) == 0
    assert all(r["status"] == "finished" for r in json.loads(capsys.readouterr().out))


def test_an_mt_tests_a_over_w_is_the_specs_2a_over_w(tmp_path, capsys):
    """M(T): a is the half crack and the spec's a/W is 2a/W; the summary and the progress line say
    the same a/W the spec ends at (it said half of it)."""
    mt = SPEC.with_name("virkler_mt.toml")
    assert cli.main(["run", str(mt), "--out", str(tmp_path / "mt"), "--no-store", "--json"]) == 0
    cap = capsys.readouterr()
    s = json.loads(cap.out)
    assert s["final_a_over_w"] == pytest.approx(0.6535, abs=1e-3)
    assert "until a/W 0.654" in cap.err or "of 0.654" in cap.err


def test_each_command_loads_only_its_own_group():
    """`htm diagnose` builds a parser with the identification group only (the campaign, fleet and
    fatigue packages and their scipy are not imported: about a second on every call), and the table
    that says which group registers which subcommand is what each group's `register` adds."""
    for group, (_, names, _) in cli.GROUPS.items():
        ap = argparse.ArgumentParser()
        sub = ap.add_subparsers()
        cli._group(group)(sub)
        assert tuple(sub.choices) == names, group
    every = set(leaves(cli.build_parser()))
    assert {name.split()[0] for name in every} == set(cli.BUILT_IN) | {n for _, ns, _ in cli.GROUPS.values() for n in ns}
    probe = ("import sys, htm.cli as c; p = c.build_parser(['diagnose', 'r.csv']); "
             "print(sorted(leaves for leaves in p._subparsers._group_actions[0].choices)); "
             "print(any(m.startswith(('htm.campaign', 'htm.fleet', 'htm.fatigue', 'htm.control')) for m in sys.modules))")
    import subprocess
    import sys
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout.splitlines()
    assert out == [str(sorted(["simulate", "params", "identify", "diagnose", "predict"])), "False"]
