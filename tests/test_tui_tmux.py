"""`htm-tui` in a real terminal: tmux runs it, keys go in with send-keys, the screen is read back
with capture-pane. Start, hold, resume, stop, a second test, e-stop and quit, on the built-in
virtual rig; both tests end up in the store with their end reasons. `.ci/run` installs tmux."""
from __future__ import annotations

import os
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

    def wait_for(self, text: str, timeout: float = 60.0) -> str:
        t0 = time.monotonic()
        while True:
            screen = self.screen()
            if text in screen:
                return screen
            if time.monotonic() - t0 > timeout:
                raise AssertionError(f"`{text}` not on the screen after {timeout:g} s:\n{screen}")
            time.sleep(0.2)


def test_console_in_tmux_runs_two_tests_by_keys_and_records_both(tmp_path):
    store = tmp_path / "store"
    t = Tmux(f"htm-test-{os.getpid()}")
    cmd = f"env HTM_STORE={store} {HTM_TUI} --store {store}"
    t("new-session", "-d", "-s", "tui", "-x", "170", "-y", "50", cmd)
    try:
        t.wait_for("connected to the virtual rig")
        t.keys("F4")
        t.wait_for("state idle")
        t.keys("s")
        t.wait_for("state running")
        t.keys("h")
        t.wait_for("state holding")
        t.keys("r")
        t.wait_for("state running")
        t.keys("x")
        t.wait_for("state idle")
        t.keys("s")  # a second test in the same session, its supply unloaded by the stop
        t.wait_for("state running")
        t.keys("F12")
        screen = t.wait_for("estop: E-STOP", timeout=10)
        screen = t.wait_for("amplifier off", timeout=5)
        assert "interlock power_off" in screen and "error:" not in screen, screen
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
