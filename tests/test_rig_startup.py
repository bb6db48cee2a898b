"""Start-up that protects the specimen (issue 30, item 1), on the virtual rig over its real
virtual CAN bus and simulated DAQ: from power-on (hydraulics off, amplifier off) through position
control's low-pressure start-up to the working pressure, then jogs and moves into and out of the
gripped specimen, the force of every control period stays inside specimen protect + 5 %, for the
C(T) and the M(T) specimens of `examples/`. Before the fix, entering position control put about
−12.9 kN on the C(T) and held it there."""
from pathlib import Path

import pytest

from htm.control import Session
from htm.control.session import specimen_of
from htm.devices.config import virtual_config
from htm.spec import load

ROOT = Path(__file__).resolve().parents[1]
PROTECT_N = 2000.0


def _recording(s: Session) -> list[dict]:
    """Every control period's measured force, supply pressure and controller state."""
    lp = s.loop
    rows: list[dict] = []
    period = lp.period

    def recorded() -> float:
        u = period()
        m = lp.meas
        rows.append({"k": lp.k, "f": m["f"], "p_s": m["p_s"], "state": lp.ctrl.state, "starting": lp.ctrl.starting_up,
                     "amplifier": lp.powered})
        return u
    lp.period = recorded
    return rows


@pytest.mark.parametrize("example", ["ct_constant_force.toml", "virkler_mt.toml"])
def test_power_on_to_high_pressure_and_install_moves_stay_inside_protect(example):
    spec = load(ROOT / "examples" / example)
    cfg = virtual_config("lockstep", position={"protect_force_n": PROTECT_N})
    s = Session().open(cfg, virtual=True, specimen=specimen_of(spec), thread=False)
    try:
        rows = _recording(s)
        s.step(250)  # powered on, hydraulics off: the specimen takes the piston's weight
        assert not s.snapshot()["amplifier"]
        s.position()  # returns at the working pressure
        start = [r for r in rows if r["starting"]]
        low = min(r["p_s"] for r in start)
        assert start and low < 0.1 * s.loop.supply_pa, f"the supply came up low: {low / 1e5:.1f} bar"
        snap = s.snapshot()
        assert snap["amplifier"] and not s.loop.ctrl.starting_up
        assert snap["p_s"] == pytest.approx(s.loop.supply_pa, rel=0.03), "at the working pressure"
        assert abs(snap["f"]) < 0.1 * PROTECT_N, f"the start-up leaves the specimen unloaded: {snap['f']:.0f} N"
        s.tare()
        y0 = snap["y"]
        s.jog(0.01)  # far faster than a gripped specimen allows
        s.step(1000)
        assert s.snapshot()["protecting"] and s.snapshot()["f"] > 0.8 * PROTECT_N
        s.jog(-0.01)
        s.step(1500)
        assert s.snapshot()["f"] < -0.8 * PROTECT_N
        s.jog(0.0)
        s.move_to(y0 + 1e-3)  # 1 mm into the specimen: ~100 kN on the C(T) unprotected
        s.step(1000)
        s.move_to(y0)
        s.step(1000)
        s.jog_step(-2e-4)
        s.step(500)
        worst = max(abs(r["f"]) for r in rows)
        assert worst <= 1.05 * PROTECT_N, f"peak |f| {worst:.0f} N past protect + 5 %"
        assert not [e for e in s.events_since(0) if e["kind"] == "trip"], "no detector tripped"
        assert len(rows) > 5000
    finally:
        s.close()


def test_protect_holds_when_position_control_is_entered_again_while_powered():
    """Install pressed again (or after a hold trip): bumpless from the present command, no
    second start-up, the learned null kept — the integrator is never reset to zero."""
    spec = load(ROOT / "examples" / "ct_constant_force.toml")
    s = Session().open(virtual_config("lockstep", position={"protect_force_n": PROTECT_N}), virtual=True,
                       specimen=specimen_of(spec), thread=False)
    try:
        s.position()
        rows = _recording(s)
        s.step(100)
        s.position()
        s.step(500)
        assert not any(r["starting"] for r in rows)
        assert max(abs(r["f"]) for r in rows) < 0.25 * PROTECT_N
    finally:
        s.close()


def test_a_test_started_during_the_start_up_waits_for_the_working_pressure():
    """The console sends `start` while position control's start-up is still at its low pressure
    (its Install key runs `position()` on a worker thread): the test waits for the working
    pressure and runs, instead of tripping the supply limit at the start-up's few bar."""
    import threading
    import time

    spec = load(ROOT / "examples" / "ct_constant_force.toml")
    cfg = virtual_config("lockstep", position={"protect_force_n": PROTECT_N})
    s = Session().open(cfg, virtual=True, specimen=specimen_of(spec), paced=True)
    try:
        t = threading.Thread(target=s.position)
        t.start()
        deadline = time.monotonic() + 5.0
        while not s.loop.ctrl.starting_up and time.monotonic() < deadline:
            time.sleep(0.005)
        assert s.loop.ctrl.starting_up and s.loop.meas["p_s"] < 0.1 * s.loop.supply_pa, "caught inside the start-up"
        s.start(spec, record=False)
        t.join(10.0)
        time.sleep(0.5)
        snap = s.snapshot()
        assert snap["interlock"] is None and snap["amplifier"], [e["message"] for e in s.log.since(0)][-4:]
        assert snap["test"] == 1 and snap["cycles"] > 0
        assert not any(e["kind"] == "trip" for e in s.log.since(0))
    finally:
        s.close()


def test_a_test_started_cold_energises_at_the_working_pressure_and_holds_its_band():
    """`Session.start` straight from power-on (no position control before it): the start-up
    protection must not keep a test at the start-up's low pressure, nor trip it."""
    spec = load(ROOT / "examples" / "ct_constant_force.toml")
    s = Session().open(virtual_config("lockstep", position={"protect_force_n": PROTECT_N}), virtual=True,
                       specimen=specimen_of(spec), thread=False)
    try:
        rows = _recording(s)
        assert not s.loop.powered
        s.start(spec, record=False)
        cycles = []
        while len(cycles) < 60:
            s.step(200)
            cycles += s.cycles_since(len(cycles))
        powered = [r for r in rows if r["amplifier"]]
        assert powered and {r["state"] for r in powered} <= {"starting", "running"} and not any(r["starting"] for r in powered), \
            "energised for the test (its smooth start), not for position control's low-pressure start-up"
        assert min(r["p_s"] for r in powered) >= 0.9 * s.loop.supply_pa, "at the working pressure from the first powered period"
        assert not [e for e in s.log.since(0) if e["kind"] == "trip"]
        judged = [c["df_err_pct"] for c in cycles if c["judged"]]
        assert judged and max(abs(x) for x in judged) < 2.0
    finally:
        s.close()
