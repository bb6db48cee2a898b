"""Every command in the README and the documentation site (`docs/`) runs as written: each fenced
`sh` and `python` block is executed in a temporary folder (the checkout's examples, benchmarks, data
and environment linked in) with a temporary test store. A block that cannot run here (an
interactive console, a server that runs until interrupted, the test suite itself, a benchmark of
minutes) says so in the line right above it, as a comment on the site (`<!-- not run by the docs
test: why -->`) or as text ("not run by the README test: why"); its command lines are then checked
to parse. A block that appears twice runs once. Besides: the README stays a five-minute read
(≤ 8 KB) and every page of `docs/` is in the site's navigation (`mkdocs.yml`)."""
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
PAGES = [README, *sorted((ROOT / "docs").rglob("*.md"))]
MARKER = re.compile(r"not run by the (README|docs) test")
BLOCK_TIMEOUT_S = 300
FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M)
README_MAX_BYTES = 8 * 1024


def blocks() -> list[tuple[str, int, str, str, str | None]]:
    """(page, line, language, code, reason it is not run or None) of every sh/python block."""
    out = []
    for page in PAGES:
        text = page.read_text()
        name = page.relative_to(ROOT).as_posix()
        for m in FENCE.finditer(text):
            lang = m.group(1)
            if lang not in ("sh", "python"):
                continue
            line = text.count("\n", 0, m.start()) + 1
            before = [ln for ln in text[: m.start()].splitlines() if ln.strip()]
            reason = before[-1] if before and MARKER.search(before[-1]) else None
            out.append((name, line, lang, m.group(2), reason))
    return out


def commands(code: str) -> list[str]:
    """The block's command lines (continuations joined, comments and blank lines dropped)."""
    joined = code.replace("\\\n", " ")
    return [ln.split("  #")[0].strip() for ln in joined.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]


def shared_folder() -> Path | None:
    """The project's `shared/` folder beside the checkout (CI keeps a copy there; a git worktree's
    is beside its main checkout), which blocks reach as `../shared/...`; None when there is none."""
    found = [ROOT.parent / "shared"]
    try:
        common = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--path-format=absolute", "--git-common-dir"],
                                capture_output=True, text=True, timeout=30).stdout.strip()
        if common:
            found.append(Path(common).parent.parent / "shared")
    except OSError:
        pass
    return next((p for p in found if p.is_dir()), None)


SHARED = shared_folder()


def layout(base: Path) -> Path:
    """A folder laid out like the checkout (.venv, examples, benchmarks, data, Makefile linked in,
    `shared/` beside it); returns the checkout folder."""
    work = base / "checkout"
    work.mkdir(parents=True)
    if SHARED is not None:
        (base / "shared").symlink_to(SHARED)
    (work / ".venv").symlink_to(Path(sys.prefix))
    for name in ("examples", "benchmarks", "data", "Makefile", "python", "crates", "Cargo.toml", "pyproject.toml"):
        (work / name).symlink_to(ROOT / name)
    return work


def env_for(work: Path) -> dict[str, str]:
    env = dict(os.environ, HTM_STORE=str(work / "store"))
    env["MAKEFLAGS"] = "-o .venv/.installed"  # `make run` uses the environment as set up, never rebuilds it
    return env


DOC_BLOCKS = blocks()
BLOCK_IDS = [f"{b[0]}:{b[1]}-{b[2]}" for b in DOC_BLOCKS]


def run_block(work: Path, lang: str, code: str) -> subprocess.CompletedProcess:
    cmd = ["bash", "-e", "-o", "pipefail", "-c", code] if lang == "sh" else [sys.executable, "-c", code]
    try:
        return subprocess.run(cmd, cwd=work, env=env_for(work), capture_output=True, text=True, timeout=BLOCK_TIMEOUT_S)
    except subprocess.TimeoutExpired as e:  # this block fails; the others still run and report
        out = e.stdout.decode(errors="replace") if isinstance(e.stdout, bytes) else e.stdout or ""
        err = e.stderr.decode(errors="replace") if isinstance(e.stderr, bytes) else e.stderr or ""
        return subprocess.CompletedProcess(cmd, -9, out, f"{err}\ntimed out after {BLOCK_TIMEOUT_S} s")


HEAVY = ("benchmarks/", "examples/", " diagnose ", " resume ", " run ")  # a script or a whole test: seconds


def cost(code: str) -> int:
    """A block's expected run time in "commands": a script or a whole test counts as five."""
    return sum(5 if any(h in f" {c} " for h in HEAVY) else 1 for c in commands(code))


@pytest.fixture(scope="module")
def ran(request, tmp_path_factory):
    """Every runnable block this session selected (a block repeated on two pages once), each in its
    own checkout-like folder and store, two at a time (the machine's cores), the longest first;
    keyed by the code."""
    chosen = {item.callspec.params["code"] for item in request.session.items
              if getattr(item, "originalname", "") == "test_doc_block_runs_as_written"}
    todo = {(b[2], b[3]) for b in DOC_BLOCKS if b[4] is None and b[3] in chosen}
    order = sorted(todo, key=lambda b: -cost(b[1]))
    base = tmp_path_factory.mktemp("docs")
    with ThreadPoolExecutor(2) as pool:
        futs = {code: pool.submit(run_block, layout(base / f"block{i}"), lang, code) for i, (lang, code) in enumerate(order)}
        return {code: f.result() for code, f in futs.items()}


def test_the_docs_have_blocks_and_every_skip_says_why():
    assert len(DOC_BLOCKS) >= 20
    assert sum(1 for b in DOC_BLOCKS if b[0] == "README.md" and b[4] is None) >= 2, "the README's tour runs"
    for page, line, _, _, reason in DOC_BLOCKS:
        if reason is not None:
            why = MARKER.split(reason, 1)[-1]
            assert len(why.strip(" :—-_*.()>")) > 10, f"{page} line {line}: say why it is not run"


def test_the_readme_is_a_five_minute_read():
    size = len(README.read_bytes())
    assert size <= README_MAX_BYTES, f"README.md is {size} bytes; move the detail into docs/ (≤ {README_MAX_BYTES})"


def test_every_page_is_in_the_site_navigation():
    nav = (ROOT / "mkdocs.yml").read_text()
    pages = {p.relative_to(ROOT / "docs").as_posix() for p in PAGES if p != README}
    missing = sorted(p for p in pages if not re.search(rf":\s*{re.escape(p)}\s*$", nav, re.M))
    assert not missing, f"pages not in mkdocs.yml's nav: {missing}"


@pytest.mark.parametrize("page,line,lang,code,reason", DOC_BLOCKS, ids=BLOCK_IDS)
def test_doc_block_runs_as_written(tmp_path, request, page, line, lang, code, reason):
    if reason is not None:
        work = layout(tmp_path)
        for cmd in commands(code):
            check_parses(cmd, work)
        return
    p = request.getfixturevalue("ran")[code]
    assert p.returncode == 0, f"{page}: block at line {line} failed ({p.returncode}):\n{p.stdout[-3000:]}\n{p.stderr[-3000:]}"
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
