"""Every command in the README runs as written: each fenced `sh` and `python` block is executed in a
temporary folder (the checkout's examples, benchmarks, data and environment linked in) with a
temporary test store. A block that cannot run here (an interactive console, a
server that runs until interrupted, the test suite itself) says so in the line right above it
("not run by the README test: why"); its command lines are then checked to parse."""
from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
MARKER = "not run by the README test"
BLOCK_TIMEOUT_S = 300
FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M)


def blocks() -> list[tuple[int, str, str, str | None]]:
    """(line, language, code, reason it is not run or None) of every sh/python block."""
    text = README.read_text()
    out = []
    for m in FENCE.finditer(text):
        lang = m.group(1)
        if lang not in ("sh", "python"):
            continue
        line = text.count("\n", 0, m.start()) + 1
        before = [ln for ln in text[: m.start()].splitlines() if ln.strip()]
        reason = before[-1] if before and MARKER in before[-1] else None
        out.append((line, lang, m.group(2), reason))
    return out


def commands(code: str) -> list[str]:
    """The block's command lines (continuations joined, comments and blank lines dropped)."""
    joined = code.replace("\\\n", " ")
    return [ln.split("  #")[0].strip() for ln in joined.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]


def layout(base: Path) -> Path:
    """A folder laid out like the checkout (.venv, examples, benchmarks, data, Makefile linked in);
    returns the checkout folder."""
    work = base / "checkout"
    work.mkdir(parents=True)
    (work / ".venv").symlink_to(Path(sys.prefix))
    for name in ("examples", "benchmarks", "data", "Makefile", "python", "crates", "Cargo.toml", "pyproject.toml"):
        (work / name).symlink_to(ROOT / name)
    return work


def env_for(work: Path) -> dict[str, str]:
    env = dict(os.environ, HTM_STORE=str(work / "store"))
    env["MAKEFLAGS"] = "-o .venv/.installed"  # `make run` uses the environment as set up, never rebuilds it
    return env


README_BLOCKS = blocks()


def run_block(work: Path, lang: str, code: str) -> subprocess.CompletedProcess:
    cmd = ["bash", "-e", "-o", "pipefail", "-c", code] if lang == "sh" else [sys.executable, "-c", code]
    return subprocess.run(cmd, cwd=work, env=env_for(work), capture_output=True, text=True, timeout=BLOCK_TIMEOUT_S)


HEAVY = ("benchmarks/", "examples/", " diagnose ", " resume ", " run ")  # a script or a whole test: seconds


def cost(code: str) -> int:
    """A block's expected run time in "commands": a script or a whole test counts as five."""
    return sum(5 if any(h in f" {c} " for h in HEAVY) else 1 for c in commands(code))


@pytest.fixture(scope="module")
def ran(tmp_path_factory):
    """Every runnable block, each in its own checkout-like folder and store, two at a time (the
    machine's cores), the longest first."""
    todo = [(b[0], b[1], b[2]) for b in README_BLOCKS if b[3] is None]
    todo.sort(key=lambda b: -cost(b[2]))
    base = tmp_path_factory.mktemp("readme")
    with ThreadPoolExecutor(2) as pool:
        futs = {line: pool.submit(run_block, layout(base / f"line{line}"), lang, code) for line, lang, code in todo}
        return {line: f.result() for line, f in futs.items()}


def test_the_readme_has_blocks_and_every_skip_says_why():
    assert len(README_BLOCKS) >= 6
    for line, _, _, reason in README_BLOCKS:
        if reason is not None:
            assert len(reason.split(MARKER, 1)[1].strip(" :—-_*.()")) > 10, f"README line {line}: say why it is not run"


@pytest.mark.parametrize("line,lang,code,reason", README_BLOCKS, ids=[f"line{b[0]}-{b[1]}" for b in README_BLOCKS])
def test_readme_block_runs_as_written(tmp_path, request, line, lang, code, reason):
    if reason is not None:
        work = layout(tmp_path)
        for cmd in commands(code):
            check_parses(cmd, work)
        return
    p = request.getfixturevalue("ran")[line]
    assert p.returncode == 0, f"README block at line {line} failed ({p.returncode}):\n{p.stdout[-3000:]}\n{p.stderr[-3000:]}"
    assert "Traceback" not in p.stderr, p.stderr[-3000:]


def check_parses(cmd: str, work: Path) -> None:
    """A command line of a block that is not run: its arguments parse (and its file arguments exist)."""
    argv = shlex.split(cmd)
    prog = argv[0]
    if prog == "make":
        p = subprocess.run(["make", "-n", *argv[1:]], cwd=work, env=env_for(work), capture_output=True, text=True, timeout=60)
        assert p.returncode == 0, p.stderr
    elif prog.endswith("/htm"):
        from htm.cli import build_parser

        build_parser().parse_args(argv[1:])  # argparse exits on a bad line (pytest reports it)
    elif prog.endswith("/htm-tui"):
        from htm.tui.app import build_parser as tui_parser

        tui_parser().parse_args(argv[1:])
    elif prog.endswith("/python") and len(argv) > 1 and argv[1].endswith(".py"):
        # a script that is not run: it exists, compiles, and knows every option the line gives it
        script = work / argv[1]
        assert script.exists(), f"`{cmd}`: {argv[1]} does not exist"
        src = script.read_text()
        compile(src, str(script), "exec")
        for a in argv[2:]:
            if a.startswith("--"):
                assert f'"{a.split("=")[0]}"' in src, f"`{cmd}`: {argv[1]} has no option {a}"
    else:
        raise AssertionError(f"no parse check for `{cmd}`: run it, or teach check_parses")
    for a in argv[1:]:
        if a.endswith(".toml") and not a.startswith("-") and "/" in a and not a.startswith("rig."):
            assert (work / a).exists(), f"`{cmd}`: {a} does not exist"
