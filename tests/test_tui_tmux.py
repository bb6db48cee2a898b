"""`htm-tui` in a real terminal: tmux runs it, keys go in with send-keys, the screen is read back
with capture-pane. Start, hold, resume, stop, a second test, e-stop and quit, on the built-in
virtual rig; both tests end up in the store with their end reasons. `.ci/run` installs tmux."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from htm.record import Store

HTM_TUI = str(Path(sys.executable).with_name("htm-tui"))


class Tmux:
    def __init__(self, tag: str) -> None:
        assert shutil.which("tmux"), "tmux is needed for the real-terminal test (.ci/run installs it)"
        self.base = ["tmux", "-L", tag]

    def __call__(self, *args: str) -> str:
        return subprocess.run(self.base + list(args), capture_output=True, text=True, timeout=30, check=True).stdout

    def screen(self) -> str:
        return self("capture-pane", "-p", "-t", "tui")

    def keys(self, *keys: str) -> None:
        self("send-keys", "-t", "tui", *keys)

    def wait_for(self, text: str, timeout: float = 60.0, *, line: bool = False) -> str:
        """Wait until `text` is on the screen (`line=True`: until a line starts with it, so a panel
        drawn in parts is read only once the row itself is there)."""
        t0 = time.monotonic()
        while True:
            screen = self.screen()
            if (any(ln.lstrip().startswith(text) for ln in screen.splitlines()) if line else text in screen):
                return screen
            if time.monotonic() - t0 > timeout:
                raise AssertionError(f"`{text}` not on the screen after {timeout:g} s:\n{screen}")
            time.sleep(0.2)

    def wait_gone(self, text: str, timeout: float = 20.0) -> str:
        """Wait until `text` is no longer on the screen."""
        t0 = time.monotonic()
        while True:
            screen = self.screen()
            if text not in screen:
                return screen
            if time.monotonic() - t0 > timeout:
                raise AssertionError(f"`{text}` still on the screen after {timeout:g} s:\n{screen}")
            time.sleep(0.2)


def test_console_in_tmux_runs_two_tests_by_keys_and_records_both(tmp_path):
    store = tmp_path / "store"
    t = Tmux(f"htm-test-{os.getpid()}")
    cmd = f"env -u COLUMNS -u LINES HTM_STORE={store} {HTM_TUI} --store {store}"  # pytest's COLUMNS would size the app
    t("new-session", "-d", "-s", "tui", "-x", "170", "-y", "50", cmd)
    try:
        t.wait_for("connected to the virtual rig")
        t.keys("F4")
        t.wait_for("state idle")
        t.keys("s")
        t.wait_for("state running")
        # the crack the test runs on beside the law's, the opening force and ΔK_eff (issue 29)
        screen = t.wait_for("crack model")
        assert "a law" in screen and "F_op" in screen and "ΔK_eff" in screen, screen
        t.keys("h")
        t.wait_for("state holding")
        t.keys("r")
        t.wait_for("state running")
        t.keys("x")
        t.wait_for("state idle")
        t.keys("s")  # a second test in the same session, its supply unloaded by the stop
        t.wait_for("state running")
        t.keys("F12")
        screen = t.wait_for("estop      E-STOP", timeout=10)  # the event log: time [s], event, detail
        screen = t.wait_for("amplifier off", timeout=5)
        assert "interlock power_off" in screen and not any(ln.split()[1:2] == ["error"] for ln in screen.splitlines()), screen
        t.keys("q")
        t0 = time.monotonic()
        while _alive(t):
            assert time.monotonic() - t0 < 15, "the console did not quit on q"
            time.sleep(0.2)
    finally:
        subprocess.run(t.base + ["kill-server"], capture_output=True)
    with Store(store) as s:
        tests = s.list_tests()
        tables = [s.cycles(x["id"])["cycle"] for x in tests]
    assert [(x["kind"], x["status"], x["end_reason"]) for x in tests] == [
        ("device", "stopped", "operator stop"), ("device", "stopped", "estop")], tests
    for c in tables:
        assert len(c) >= 20 and np.array_equal(c, np.arange(1, len(c) + 1)), "each test from cycle 1, no gap"


def _alive(t: Tmux) -> bool:
    return subprocess.run(t.base + ["has-session", "-t", "tui"], capture_output=True).returncode == 0


def test_every_tab_by_keyboard_alone_in_tmux(tmp_path):
    """Every tab driven by keys alone in a real terminal, and what the screen shows: Setup
    (simulate), Install (position control), Run (the limits panel in engineering units, start,
    stop), Results (↑/↓ in the list at once, the selection kept across tabs), Diagnose (its
    record and output fields typed into, Tab between them, Enter on the button), help."""
    from htm.cli import main as htm_main
    from htm.ident.proving import make_record
    from htm.ident.records import write_record

    store = tmp_path / "store"
    for i in (1, 2):
        assert htm_main(["run", "examples/ct_constant_force.toml", "--out", str(tmp_path / f"run{i}"), "--quiet",
                         "--no-recording", "--store", str(store)]) == 0
    with Store(store) as s:
        older, newer = [x["id"] for x in s.list_tests()]
    rec, _ = make_record({"sensor_offset": {"channel": "p_a", "offset_pa": 4e5}}, seed=3, duration_s=10.0)
    record, _ = write_record(rec, tmp_path / "rec")
    t = Tmux(f"htm-keys-{os.getpid()}")
    t("new-session", "-d", "-s", "tui", "-x", "170", "-y", "50", f"env -u COLUMNS -u LINES HTM_STORE={store} {HTM_TUI} --store {store}")
    try:
        t.wait_for("connected to the virtual rig")
        assert max(map(len, t.screen().splitlines())) > 150, "the console fills the 170-column terminal"
        # Setup: simulate the spec on the fast engine
        t.keys("C-s")
        t.wait_for("predicted life", timeout=60)
        # Install: position control on; the numbers in mm and kN
        t.keys("F3")
        t.wait_for("jog rate")
        t.keys("o")
        screen = t.wait_for("state position")
        assert "position" in screen and " mm" in screen and " kN" in screen, screen
        # Run: the limits panel in engineering units, each with its unit; start and stop
        t.keys("F4")
        t.wait_for("low limit")
        t.wait_for("supply_pressure", line=True)
        screen = t.wait_for("force_band", line=True)
        row = next(ln for ln in screen.splitlines() if ln.split()[:1] == ["supply_pressure"])
        assert row.split()[1:6] == ["supply", "pressure", "120.0", "250.0"] or "120.0" in row and "bar" in row, row
        band = next(ln for ln in screen.splitlines() if ln.split()[:1] == ["force_band"])
        assert "none" in band and "25.0" in band and "% of ΔF" in band, band
        assert "e+0" not in screen, "no e-notation on the Run tab"
        t.keys("s")
        t.wait_for("state running")
        t.keys("x")
        t.wait_for("state idle")
        # Results: ↑/↓ act at once (no Tab first), the selection stays across tabs
        t.keys("F5")
        screen = t.wait_for("a end [mm]")
        t.keys("Down")
        t.wait_for(f"{older} ct_constant_force")  # the summary's first line names the test selected
        t.keys("F2")
        t.wait_for("can the rig run it?")
        t.keys("F5")
        time.sleep(1.0)
        screen = t.wait_for(f"{older} ct_constant_force")
        assert f"{newer} ct_constant_force (" not in screen, "the selection stayed on the test chosen"
        assert "final a/W" in screen and "mm" in screen, screen
        # Diagnose: both fields and the button by keyboard
        t.keys("F6")
        t.wait_for("record table (.csv")
        # (at a person's pace: a burst of characters arrives as one paste, and a Tab inside a
        # paste is text, not a key)
        t("send-keys", "-t", "tui", "-l", str(record))
        time.sleep(0.5)
        t.keys("Tab")
        time.sleep(0.5)
        t("send-keys", "-t", "tui", "-l", str(tmp_path / "diag"))
        time.sleep(0.5)
        t.keys("Tab")
        time.sleep(0.5)
        t.keys("Enter")
        screen = t.wait_for("report:", timeout=300)
        assert "sensor_offset" in screen and "bar" in screen, screen
        assert (tmp_path / "diag" / "report.md").exists()
        # help, then quit
        t.keys("F1")
        t.wait_for("htm-tui keys")
        t.keys("Escape")
        time.sleep(0.5)  # ESC then q at once would read as alt+q
        t.wait_gone("htm-tui keys", timeout=20)  # the help closed (a loaded machine draws late)
        t.keys("q")
        t0 = time.monotonic()
        while _alive(t):
            assert time.monotonic() - t0 < 15, "the console did not quit on q"
            time.sleep(0.2)
    finally:
        subprocess.run(t.base + ["kill-server"], capture_output=True)


def test_a_strain_life_test_in_tmux_shows_its_loop_and_threshold_and_is_recorded(tmp_path):
    """`htm-tui --spec` with a strain_life spec: Run starts it on the built-in virtual rig (gripping
    a round bar for it, an extensometer on its channel), the screen shows the life numbers (the
    tensile peak, its trend, the failure threshold), the live stress–strain loop and the trend
    plot; stopped by key, the test is in the store with its per-cycle table from cycle 1."""
    import pyarrow.parquet as pq
    from test_tui_life import SHORT_LIFE

    from htm import spec as specmod

    store = tmp_path / "store"
    spec = tmp_path / "en_short.toml"
    spec.write_text(specmod.dumps(SHORT_LIFE))
    t = Tmux(f"htm-life-{os.getpid()}")
    t("new-session", "-d", "-s", "tui", "-x", "170", "-y", "50",
      f"env -u COLUMNS -u LINES HTM_STORE={store} {HTM_TUI} --store {store} --spec {spec}")
    try:
        t.wait_for("connected to the virtual rig")
        t.wait_for("strain_life, ε_a 0.6 %")  # the Setup status of the spec given
        t.keys("F4")
        t.wait_for("state idle")
        t.keys("s")
        screen = t.wait_for("mode strain_life", timeout=30)
        screen = t.wait_for("(50 % drop)", timeout=30)
        assert "tensile peak" in screen and "failure at" in screen and "σ_a" in screen, screen
        assert "stress–strain loop" in screen and "failure threshold" in screen, screen
        t0 = time.monotonic()
        while not re.search(r"cycles (\d{2,}|[\d,]{4,})", t.screen()):  # ten cycles and more: the trend is judged
            assert time.monotonic() - t0 < 60, t.screen()
            time.sleep(0.3)
        screen = t.screen()
        assert re.search(r"trend \d+\.\d{3} kN", screen) and re.search(r"failure at \d+\.\d{3} kN", screen), screen
        t.keys("x")
        t.wait_for("state idle", timeout=20)
        t.keys("q")
        t0 = time.monotonic()
        while _alive(t):
            assert time.monotonic() - t0 < 15, "the console did not quit on q"
            time.sleep(0.2)
    finally:
        subprocess.run(t.base + ["kill-server"], capture_output=True)
    with Store(store) as s:
        (x,) = s.list_tests()
        d = s.test_dir(x["id"])
    assert (x["kind"], x["mode"], x["status"], x["end_reason"]) == ("strain_life", "device", "stopped", "operator stop"), x
    c = pq.read_table(d / "cycles.parquet").column("cycle").to_numpy()
    assert len(c) >= 5 and np.array_equal(c, np.arange(1, len(c) + 1))
