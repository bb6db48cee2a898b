"""Snapshot tests of every console screen (pytest-textual-snapshot; SVGs in tests/__snapshots__).

Screens with live data are rendered from a deterministic lock-step session stepped on the test's
thread (the virtual rig's bus and DAQ get fixed names), so the picture is the same on every run.
Update after an intended change with `pytest tests/test_tui_snapshots.py --snapshot-update`.
"""
import tomllib
from pathlib import Path

from textual.widgets import Input

from htm import spec as specmod
from htm.tui.app import HtmApp

ROOT = Path(__file__).resolve().parents[1]
SIZE = (150, 50)


def lockstep_session():
    from htm.control.session import Session, specimen_of
    from htm.devices.config import virtual_config

    spec = specmod.parse(tomllib.loads((ROOT / "examples" / "ct_constant_force.toml").read_text()), "snapshot")
    cfg = virtual_config("lockstep", bus={"channel": "htm-snapshot"}, analog={"device": "htm-snapshot"},
                         position={"protect_force_n": 2000.0})
    s = Session().open(cfg, virtual=True, specimen=specimen_of(spec), thread=False)
    return s, spec


def app_without_rig(store) -> HtmApp:
    return HtmApp(session_factory=lambda: None, poll=False, store=store)


def test_setup_screen(snap_compare, store):
    assert snap_compare(app_without_rig(store), terminal_size=SIZE)


def test_setup_screen_with_a_bad_field(snap_compare, store):
    async def bad(pilot):
        pilot.app.query_one("#loading-r_ratio").value = "1.5"
        await pilot.pause()

    assert snap_compare(app_without_rig(store), terminal_size=SIZE, run_before=bad)


def test_help_screen(snap_compare, store):
    assert snap_compare(app_without_rig(store), terminal_size=SIZE, press=["f1"])


def test_results_screen_empty_store(snap_compare, store):
    assert snap_compare(app_without_rig(store), terminal_size=SIZE, press=["f5"])


def test_diagnose_screen(snap_compare, store):
    async def go(pilot):
        # F6 puts the cursor in the record field; a blinking cursor would make the picture depend on
        # the moment it is taken
        await pilot.press("f6")
        await pilot.pause()
        for field in pilot.app.query(Input):
            field.cursor_blink = False
        await pilot.pause()

    assert snap_compare(app_without_rig(store), terminal_size=SIZE, run_before=go)


def _with_session(periods: int, start: bool):
    holder = {}

    def factory():
        s, spec = lockstep_session()
        holder["s"], holder["spec"] = s, spec
        return s

    async def drive(pilot):
        s = holder["s"]
        if start:
            s.start(holder["spec"], record=False)
        else:
            s.position()
        s.step(periods)
        pilot.app.poll()
        await pilot.pause()

    return factory, drive


def test_install_screen(snap_compare, store):
    factory, drive = _with_session(500, start=False)
    app = HtmApp(session_factory=factory, poll=False, store=store)

    async def go(pilot):
        await pilot.press("f3")
        await drive(pilot)

    assert snap_compare(app, terminal_size=SIZE, run_before=go)


def test_run_screen_cycling(snap_compare, store):
    factory, drive = _with_session(5000, start=True)
    app = HtmApp(session_factory=factory, poll=False, store=store)

    async def go(pilot):
        await pilot.press("f4")
        await drive(pilot)

    assert snap_compare(app, terminal_size=SIZE, run_before=go)


def test_run_screen_life_test(snap_compare, store):
    """A strain_life test on the lock-step virtual rig (a round bar, an extensometer on ai7): the
    life numbers, the live stress–strain loop and the tensile peak's trend with its threshold."""
    from test_tui_life import SHORT_LIFE

    from htm.control.session import Session, specimen_of
    from htm.devices.config import virtual_config
    from htm.fatigue import lifetest

    spec = lifetest.parse(SHORT_LIFE, "snapshot_life")
    holder = {}

    def factory():
        cfg = virtual_config("lockstep", bus={"channel": "htm-snapshot-life"}, analog={"device": "htm-snapshot-life",
                             "channels": {"extensometer": "ai7"}}, position={"protect_force_n": 2000.0})
        holder["s"] = Session().open(cfg, virtual=True, specimen=specimen_of(spec), thread=False)
        return holder["s"]

    app = HtmApp(session_factory=factory, poll=False, store=store)

    async def go(pilot):
        await pilot.press("f4")
        s = holder["s"]
        s.start(spec, record=False)
        s.step(100 * 40)
        pilot.app.poll()
        await pilot.pause()

    assert snap_compare(app, terminal_size=SIZE, run_before=go)
