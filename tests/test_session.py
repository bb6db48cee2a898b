"""The operator-console facade: commands, specimen protect, interlocks and e-stop, the decimated
feed, a real-time threaded run, and the rig served by another process over udp_multicast."""
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from htm.control import Session
from htm.control.session import specimen_of
from htm.devices.config import virtual_config
from htm.errors import DeviceError, InterlockTripped, ParameterError
from htm.spec import load

ROOT = Path(__file__).resolve().parents[1]


def test_install_with_specimen_protect_then_jog_limits():
    spec = load(ROOT / "examples" / "ct_constant_force.toml")
    s = Session().open(virtual_config("lockstep", position={"protect_force_n": 2000.0}), virtual=True,
                       specimen=specimen_of(spec), thread=False)
    try:
        s.step(5)
        assert not s.rig.daq.relay(0), "amplifier off until motion is commanded"
        s.tare()
        s.move_to(s.snapshot()["y"] + 1e-3)  # 1 mm into a stiff specimen would be ~10 kN
        s.step(1500)
        snap = s.snapshot()
        assert snap["protecting"] and snap["amplifier"]
        assert max(abs(x["f"]) for x in s.feed_since(0)) < 3000.0 and snap["f"] > 1000.0
        with pytest.raises(ParameterError, match="jog rate_m_s"):
            s.jog(1.0)
    finally:
        s.close()


def test_estop_latches_until_reset_and_refuses_motion():
    s = Session().open(virtual_config("lockstep"), virtual=True, thread=False)
    try:
        s.step(5)
        s.jog(0.005)
        s.step(50)
        s.estop()
        s.step(3)
        assert not s.rig.daq.relay(0) and s.rig.daq.output(1) == 0.0
        with pytest.raises(InterlockTripped, match="estop"):
            s.jog(0.001)
        assert s.reset() == [] or True
        s.step(200)  # the supply pressure comes back
        s.reset()
        s.step(1)
        s.jog_step(1e-4)
        s.step(100)
        assert s.snapshot()["interlock"] is None and s.snapshot()["amplifier"]
        kinds = [e["kind"] for e in s.events_since(0)]
        assert "estop" in kinds and "reset" in kinds
        assert {d["name"] for d in s.detectors()} >= {"position", "force", "transducer_silent", "heartbeat", "supply_pressure"}
        assert all({"name", "lo", "hi", "state", "action", "latched"} <= set(d) for d in s.detectors())
    finally:
        s.close()


def test_realtime_thread_runs_a_test_with_a_decimated_feed():
    spec = load(ROOT / "examples" / "ct_constant_force.toml")
    s = Session().open(virtual_config("realtime"), virtual=True, specimen=specimen_of(spec))
    try:
        s.start(spec)
        t0 = time.monotonic()  # the loop's own pace: a loaded machine may take longer than 2 s
        while time.monotonic() - t0 < 60.0:
            time.sleep(0.2)
            now = s.snapshot()
            if now["cycles"] >= 12 and now["timing"]["periods"] > 950:
                break
        s.hold()
        time.sleep(0.3)
        snap = s.snapshot()
        assert snap["state"] == "holding" and snap["cycles"] >= 10, [e["message"] for e in s.events_since(0)]
        feed = s.feed_since(0)
        rate = len(feed) / (feed[-1]["t_s"] - feed[0]["t_s"])
        assert 15.0 <= rate <= 21.0, f"feed at {rate:.1f} Hz"
        assert snap["timing"]["periods"] > 900 and math.isfinite(snap["timing"]["p99_ms"])
        s.resume()
        s.stop()
        time.sleep(1.0)
        assert s.snapshot()["state"] == "idle" and not s.rig.daq.relay(0), "amplifier off once the test stopped"
    finally:
        s.close()


def test_rig_in_another_process_over_udp_multicast(tmp_path):
    """`htm rig serve` in a subprocess; the loop in this one, lock-step over udp_multicast with
    hop limit 0 (IPv4 TTL 0: looped back on this host, never sent on a wire)."""
    tag = f"htm-udp-{os.getpid()}"
    cfg = tmp_path / "rig.toml"
    cfg.write_text(f'[bus]\ninterface = "udp_multicast"\nchannel = "239.74.163.2"\noptions = {{ hop_limit = 0 }}\n'
                   f'[analog]\ndevice = "{tag}"\n[loop]\nmode = "lockstep"\n')
    proc = subprocess.Popen([sys.executable, "-c", "import sys; from htm.cli import main; sys.exit(main())", "rig", "serve", str(cfg), "--seconds", "60"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        assert "virtual rig ready" in proc.stdout.readline()
        s = Session().open(cfg, thread=False)
        try:
            s.step(20)
            y0 = s.snapshot()["y"]
            s.move_to(y0 + 2e-3)
            s.step(1000)
            snap = s.snapshot()
            assert snap["y"] == pytest.approx(y0 + 2e-3, abs=2e-5), "the other process's plant moved"
            assert s.loop.master.age_periods == 0 and snap["interlock"] is None
        finally:
            s.close()
    finally:
        proc.terminate()
        out, err = proc.communicate(10)
    assert "virtual rig stopping after" in out, err


def _wait(cond, timeout: float = 10.0) -> None:
    t0 = time.monotonic()
    while not cond():
        assert time.monotonic() - t0 < timeout, "condition not reached in time"
        time.sleep(0.05)


def test_every_test_of_a_session_is_recorded_with_its_own_rows_report_and_end_reason(tmp_path):
    """Two tests in one session, the second started right after the first stopped (its supply
    still unloaded): both recorded from cycle 1, no trip, no recording error; an indicate-only
    trip does not become the end reason of the operator's stop; each test gets a report."""
    from htm.record import Store

    spec = load(ROOT / "examples" / "ct_constant_force.toml")
    tight = {"amplitude_error": {"lo": -1e-6, "hi": 1e-6}}  # indicate-only: trips on every test
    s = Session().open(virtual_config("lockstep", limits=tight), virtual=True, specimen=specimen_of(spec), thread=False)
    ids = []
    try:
        for _ in range(2):
            s.start(spec, store=tmp_path)
            s.step(50 * 30)  # 30 cycles at 10 Hz, 500 Hz
            s.stop()
            s.step(50 * 5)
            rec = s.recorder
            _wait(lambda rec=rec: rec.status is not None)
            ids.append(rec.test_id)
        events = s.events_since(0)
    finally:
        s.close()
    assert [e for e in events if e["kind"] == "error"] == []
    trips = [e for e in events if e["kind"] == "trip"]
    assert trips and all(e["action"] == "indicate" for e in trips), [e["message"] for e in trips]
    with Store(tmp_path) as st:
        for tid in ids:
            t = st.get(tid)
            c = st.cycles(tid)["cycle"]
            assert len(c) >= 25 and np.array_equal(c, np.arange(1, len(c) + 1)), f"{tid}: {c[:5]}…"
            assert (t["status"], t["end_reason"]) == ("stopped", "operator stop")
            report = Path(t["files"]["report"]["path"]).read_text()
            assert f"cycles recorded: {len(c)}" in report and "operator stop" in report
            # the live test's convergence, as a simulated test's: results and an event
            assert t["results"]["convergence"][0]["cause"] == "start" and t["results"]["cycles_to_2pct"] == 0
            assert any(e["kind"] == "convergence" for e in t["events"])


def test_a_start_after_a_stop_loads_the_supply_and_times_out_clearly_without_it():
    spec = load(ROOT / "examples" / "ct_constant_force.toml")
    s = Session().open(virtual_config("lockstep"), virtual=True, specimen=specimen_of(spec), thread=False)
    try:
        s.jog(0.0)
        s.step(10)
        s.stop()
        s.step(200)
        assert not s.snapshot()["amplifier"] and s.snapshot()["p_s"] < 1e6, "the supply is unloaded"
        s.start(spec, record=False)
        s.step(200)
        assert s.snapshot()["interlock"] is None and s.snapshot()["state"] in ("starting", "running")
        s.stop()
        s.step(50 * 5)
        s.rig.inject("supply_loss")  # the pump is off: the supply never comes up
        with pytest.raises(DeviceError, match="supply pressure did not come up.*nothing was energised"):
            s.start(spec, record=False)
        assert not s.snapshot()["amplifier"] and s.snapshot()["interlock"] is None
    finally:
        s.close()


def test_commands_right_after_open_act_on_a_valid_reading():
    s = Session().open(virtual_config("lockstep"), virtual=True, thread=False)
    try:
        y = s.snapshot()["y"]
        off = s.tare()  # before any step: open() waited for the first reading
        assert math.isfinite(y) and math.isfinite(off)
        s.move_to(y + 1e-3)
        s.step(1000)
        snap = s.snapshot()
        assert snap["interlock"] is None and snap["y"] == pytest.approx(y + 1e-3, abs=2e-5)
        assert math.isfinite(snap["f"])
        s.loop.meas["f"] = math.nan  # a load cell that reads nothing: tare refuses, nothing changes
        with pytest.raises(DeviceError, match="tare: no valid reading"):
            s.tare()
        assert s.loop.load_offset_n == off
    finally:
        s.close()


def _until(cond, seconds: float) -> bool:
    t0 = time.monotonic()
    while not cond():
        if time.monotonic() - t0 > seconds:
            return False
        time.sleep(0.02)
    return True


def test_an_in_process_rig_late_on_a_loaded_host_is_no_silent_transducer_but_a_silent_one_trips(monkeypatch):
    """In real time the loop pumps the in-process rig, as in lock-step: the rig's answer to a SYNC
    comes within the period however late the host runs its code. A host that does not run the rig
    for 5 ms (every 50th SYNC here; measured under load: 14 ms with the rig on its own thread)
    makes late periods, counted in the loop's timing, and no transducer_silent trip — on a thread
    of its own the rig answered two SYNCs late and the loop powered off. A transducer that stops
    answering (the rig's `transducer_silent` fault) still trips it and powers off."""
    from htm.devices.rig import VirtualRig

    on_sync = VirtualRig._on_sync
    delayed = []

    def late(self):
        if self.periods % 50 == 25:
            delayed.append(self.periods)
            time.sleep(0.005)
        return on_sync(self)

    monkeypatch.setattr(VirtualRig, "_on_sync", late)
    spec = load(ROOT / "examples" / "ct_constant_force.toml")
    s = Session().open(virtual_config("realtime"), virtual=True, specimen=specimen_of(spec))
    try:
        s.start(spec, record=False)
        assert _until(lambda: s.snapshot()["timing"]["periods"] > 500, 30.0)
        snap = s.snapshot()
        trips = [e["message"] for e in s.events_since(0) if e["kind"] == "trip"]
        assert len(delayed) >= 9 and snap["timing"]["overruns"] >= 9, (len(delayed), snap["timing"])
        assert snap["interlock"] is None and not trips, trips
        assert snap["state"] in ("starting", "running") and snap["amplifier"] and s.rig.daq.relay(0)
        s.rig.inject("transducer_silent")
        assert _until(lambda: s.snapshot()["interlock"] == "power_off", 5.0), [e["message"] for e in s.events_since(0)]
        trips = [e["detector"] for e in s.events_since(0) if e["kind"] == "trip"]
        assert "transducer_silent" in trips
        assert _until(lambda: not s.rig.daq.relay(0), 1.0), "amplifier off after the silent transducer"
        with pytest.raises(InterlockTripped, match="transducer_silent"):
            s.start(spec, record=False)
    finally:
        s.close()


def _latched(s: Session) -> Session:
    """`s` with its transducer silenced until transducer_silent has latched (power off)."""
    s.rig.inject("transducer_silent")
    if s._thread is None:
        s.step(5)
    else:
        assert _until(lambda: s.snapshot()["interlock"] == "power_off", 5.0)
    assert s.snapshot()["interlock"] == "power_off"
    return s


def test_the_loop_benchmark_reports_a_latched_session_as_refused_instead_of_raising(tmp_path):
    """benchmarks/realtime_loop.py: a session whose interlock latched before the start (as the
    transducer_silent one on a loaded host did) is a result with its one-line reason, and a
    figure it could not measure is null — not an InterlockTripped traceback."""
    import realtime_loop

    spec = load(ROOT / "examples" / "ct_constant_force.toml")
    s = _latched(Session().open(virtual_config("lockstep"), virtual=True, specimen=specimen_of(spec), thread=False))
    ls = realtime_loop.lockstep(100, tmp_path, session=s)
    assert ls["periods_per_s"] is None and ls["interlock"] == "power_off"
    assert ls["refused"] == "interlock latched (transducer_silent): reset() first"
    assert any(t.startswith("transducer_silent:") for t in ls["trips"])
    assert s.loop is None, "the benchmark closed the session"
    s = _latched(Session().open(virtual_config("realtime"), virtual=True, specimen=specimen_of(spec)))
    rt = realtime_loop.realtime(500.0, 0.2, 0, tmp_path, session=s)
    assert rt["refused"] == "interlock latched (transducer_silent): reset() first"
    assert rt["p99_ms"] is None and rt["overrun_pct"] is None and rt["cycles"] is None


@pytest.mark.parametrize("latch", ["realtime", "every"])
def test_the_loop_benchmark_goes_on_past_a_refused_session_and_fails_only_when_nothing_measured(latch, monkeypatch, capsys):
    """The whole benchmark with the real-time sessions (or every session) latched at open: the
    JSON keeps its keys, null where nothing was measured, the reason beside it; exit 0 while
    something was measured (the lock-step figure), else 1 with one line on stderr."""
    import realtime_loop

    class Latched(Session):
        def open(self, config, **kw):
            super().open(config, **kw)
            return _latched(self) if latch == "every" or config.loop.mode == "realtime" else self

    monkeypatch.setattr(realtime_loop, "Session", Latched)
    monkeypatch.setattr(sys, "argv", ["realtime_loop.py", "--seconds", "0.2", "--lockstep-periods", "200", "--priority", "0"])
    rc = realtime_loop.main()
    out, err = capsys.readouterr()
    j = json.loads(out)
    refused = "interlock latched (transducer_silent): reset() first"
    assert j["rt500_p99_ms"] is None and j["rt1000_p99_ms"] is None and j["rt500_overrun_pct"] is None
    assert j["rt500"]["refused"] == j["rt1000"]["refused"] == refused
    if latch == "realtime":
        assert rc == 0 and err == ""
        assert j["lockstep_periods_per_s"] > 0.0 and j["lockstep"]["refused"] is None and j["lockstep"]["trips"] == []
    else:
        assert rc == 1 and j["lockstep_periods_per_s"] is None and j["lockstep"]["refused"] == refused
        assert err.count("\n") == 1 and err.startswith("realtime_loop: nothing measured: lock-step interlock latched")
