"""`Session`: the operator console's handle on the rig — it owns the devices and the control loop
on a background thread and never lets a caller block the loop.

    s = Session()
    s.open(None)                  # None → in-process virtual rig (real time); or a RigConfig / path
    s.position()                  # position control (install): specimen protect limits the force
    s.jog(0.002) / s.jog_step(1e-4) / s.move_to(0.1)   # [m/s], [m], [m]
    s.tare()                      # zero the load cell at the current reading
    s.start(spec)                 # htm.spec.TestSpec: smooth ramp-in, then cycling
    s.hold(); s.resume(); s.stop(); s.estop(); s.reset()
    s.snapshot()                  # live numbers (dict): state, cycles, frequency, a, ΔK, K_sp, errors,
                                  # last peak/valley, jitter stats, interlock state
    s.detectors()                 # every detector: name, channel, limit, state, action, latched
    s.feed_since(n)               # decimated samples (≤ 20 Hz; a bounded queue: old ones drop)
    s.cycles_since(n)             # per-cycle results (peaks, valleys, a, ΔK, K_sp, ...)
    s.events_since(n)             # event log: trips, actions, amplifier, commands
    s.close()

Commands are queued and run by the loop at the start of its next period; the caller waits for
the result (a clear error if refused, e.g. InterlockTripped while a latch holds), the loop never
waits for the caller. Snapshots read numbers the loop writes; nothing takes a lock in the loop.
With `thread=False` (tests, benchmarks) the caller drives the loop: `s.step(n)` runs n periods."""
from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from pathlib import Path
from typing import Any

from htm import core
from htm.control.loop import ControlLoop
from htm.control.safety import EventLog
from htm.devices.analog import AnalogIO
from htm.devices.config import RigConfig, load_config, virtual_config
from htm.devices.rig import VirtualRig
from htm.devices.transducer import TransducerMaster, network_on, open_bus, stop_notifier
from htm.errors import DeviceError, HtmError, InterlockTripped
from htm.params import with_overrides

COMMAND_TIMEOUT_S = 5.0
# how long a motion command waits for the unloaded supply to come up to its detector's range [s]
SUPPLY_TIMEOUT_S = 3.0
# how long open() waits for the loop's first valid position and force reading [s]
FIRST_READING_S = 2.0


def is_life(spec: Any) -> bool:
    """The spec is a life test (`htm.fatigue.lifetest.LifeSpec`: force_life or strain_life)."""
    from htm.fatigue.lifetest import LifeSpec

    return isinstance(spec, LifeSpec)


def specimen_of(spec) -> dict[str, Any]:
    """The virtual rig's specimen dict for a `TestSpec` (a cracking specimen), or for a life
    test's `LifeSpec` its round bar (``{"life": its core dict}``: the virtual rig grips a bar of
    that geometry and nominal material, with its own truth, `htm.devices.rig.true_bar`)."""
    if is_life(spec):
        return {"life": dict(spec.config)}
    return {"geometry": spec.geometry, "width_m": spec.width_m, "thickness_m": spec.thickness_m, "a0_m": spec.a0_m,
            **spec.material, "law": dict(spec.law)}


class Session:
    """The operator's handle on a rig (real or virtual): devices and control loop on a thread.

    ``Session().open(config, ...)`` opens the bus and DAQ and starts the loop; then position
    commands (``move_to(y_m)`` [m], ``jog(rate_m_s)`` [m/s]), ``tare()``, ``start(spec)`` for a
    `TestSpec`, ``hold()``/``resume()``/``stop()``/``estop()``/``reset()``, live numbers with
    ``snapshot()`` and ``close()``. See the module docstring for every call.

    Notes
    -----
    All numbers are SI: positions [m], forces [N], pressures [Pa], crack size [m], ΔK [Pa·√m].
    Commands wait for the loop (a clear error if refused, e.g. InterlockTripped while a latch
    holds); the loop never waits for the caller.
    """

    def __init__(self) -> None:
        self.cfg: RigConfig | None = None
        self.rig: VirtualRig | None = None
        self.loop: ControlLoop | None = None
        self.log = EventLog()
        self._thread: threading.Thread | None = None
        self.recorder = None  # htm.control.recorder.LiveRecorder of the running test
        self._paced = False
        self._net = None
        self._io = None

    # -- life cycle ---------------------------------------------------------------------------------
    def open(self, config: RigConfig | str | Path | None = None, *, virtual: bool | None = None,
             specimen: Any = None, thread: bool = True, mode: str | None = None,
             paced: bool = False) -> Session:
        """Validate the configuration, open the bus and the DAQ, check the transducer over SDO, start
        it (NMT) and the loop. `None` = an in-process virtual rig; `virtual=True` puts one behind
        any config; the loop pumps an in-process rig, which answers each SYNC within the period
        (a starved host delays the loop's periods, never the virtual transducer's answer).
        `paced=True` with a lock-step in-process rig keeps the deterministic device path but runs
        the periods on the wall clock, as the console does.
        Nothing is energised until a motion or a test is commanded. `specimen`, gripped in a
        virtual rig: a `TestSpec` (its specimen and material) or the rig's specimen dict."""
        if specimen is not None and not isinstance(specimen, dict):
            specimen = specimen_of(specimen)
        if isinstance(config, (str, Path)):
            config = load_config(config)
        cfg = config or virtual_config(mode or "realtime")
        if mode and mode != cfg.loop.mode:
            raise DeviceError(f"mode {mode!r} differs from the config's loop.mode {cfg.loop.mode!r}")
        virtual = config is None if virtual is None else virtual
        self.cfg = cfg
        self._paced = paced
        params = with_overrides(core.Params(cfg.rig_preset), cfg.rig_overrides)
        try:
            if virtual:
                self.rig = VirtualRig(cfg, specimen, threaded=True, handover=True)
            bus = open_bus(cfg.bus)
            self._net = network_on(bus, threaded=True, handover=True)
            self._io = AnalogIO(cfg.analog)
            master = TransducerMaster(self._net, cfg.transducer, 1.0 / cfg.loop.rate_hz)
            info = master.configure()
            master.start()
            stop_notifier(self._net)
            # the in-process rig: pumped by the loop from now on, in real time too (on a thread of
            # its own it answered when the host's scheduler let it: 14 ms late on a loaded host,
            # a silent transducer to the loop, which a transducer on the wire never is)
            pump = None
            if self.rig is not None:
                self.rig.hand_over()
                pump = self.rig.pump
            self.loop = ControlLoop(cfg, master, self._io, params, pump, self.log)
            self._first_contact(self.rig is not None)
        except BaseException:
            self.close()
            raise
        self.log.add(0, "open", f"transducer node {cfg.transducer.node_id} (0x{info['device_type']:08X}, "
                     f"{info['step_nm']} nm) on {cfg.bus.interface}:{cfg.bus.channel}; analog {cfg.analog.backend}; "
                     f"{cfg.loop.mode} at {cfg.loop.rate_hz:g} Hz")
        if thread:
            self._thread = threading.Thread(target=self._run, name="htm-control-loop", daemon=True)
            if cfg.loop.mode == "realtime" or paced:
                sys.setswitchinterval(5e-4)  # other threads must not hold the GIL for 5 ms
            self._thread.start()
        try:
            self._first_reading()
        except BaseException:
            self.close()
            raise
        return self

    def _first_reading(self) -> None:
        """Return once the loop has measured a finite position and force, so a command right
        after open() (move_to, tare) never acts on the NaN of "no reading yet"."""
        lp = self.loop
        t0 = time.monotonic()
        while not (math.isfinite(lp.meas["y"]) and math.isfinite(lp.meas["f"])):
            if time.monotonic() - t0 > FIRST_READING_S:
                raise DeviceError(f"no valid position and force reading {FIRST_READING_S:g} s after open "
                                  f"(y = {lp.meas['y']}, force = {lp.meas['f']}): check the transducer and the load cell")
            if self._thread is None:
                lp.period()
            else:
                time.sleep(0.005)

    def _first_contact(self, in_process: bool) -> None:
        """SYNC until the transducer answers (after NMT start), before the limits are armed."""
        lp = self.loop
        m = lp.master
        for _ in range(200):
            m.send_sync()
            if in_process:
                self.rig.pump()
            m.pump(0.0 if in_process else 0.02)
            if m.age_periods == 0:
                m.hb_seq = m.seq
                return
        raise DeviceError(f"transducer node {self.cfg.transducer.node_id} sends no TPDO1 after NMT start")

    def _run(self) -> None:
        lp = self.loop
        try:
            if self.cfg.loop.mode == "realtime" or self._paced:
                lp.run_realtime()
            else:
                while not lp.stop_requested:
                    lp.period()
        except BaseException as e:  # the loop died: make safe and say why
            lp.power_off(f"loop error: {e}")
            self.log.add(lp.k, "error", f"control loop stopped: {e!r}")

    def step(self, periods: int = 1) -> None:
        """Run `periods` control periods on the caller's thread (only when opened with thread=False)."""
        if self._thread is not None:
            raise HtmError("the loop runs on its own thread; step() is for thread=False sessions")
        self.loop.run_lockstep(periods)

    def close(self) -> None:
        """Stop the loop (valve null, amplifier off) and release the devices."""
        lp = self.loop
        if self.recorder is not None:
            self.recorder.stop()
            self.recorder = None
        if lp is not None:
            lp.stop_requested = True
            if self._thread is not None:
                self._thread.join(2.0)
                self._thread = None
            lp.power_off("session closed")
            try:
                lp.master.stop()
            except Exception:
                pass
        if self._io is not None:
            self._io.close()
            self._io = None
        if self._net is not None:
            stop_notifier(self._net)
            if self._net.bus is not None:
                self._net.bus.shutdown()
            self._net = None
        if self.rig is not None:
            self.rig.close()
            self.rig = None
        self.loop = None

    def __enter__(self) -> Session:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- commands (run by the loop at its next period) ------------------------------------------------
    def _do(self, fn: Callable[[], Any], what: str) -> Any:
        lp = self.loop
        if lp is None:
            raise HtmError("session is not open")
        fut: Future = Future()

        def run() -> None:
            try:
                fut.set_result(fn())
                self.log.add(lp.k, "command", what)
            except BaseException as e:
                fut.set_exception(e)

        if self._thread is None:
            run()
        else:
            lp.commands.append(run)
        return fut.result(COMMAND_TIMEOUT_S)

    def _motion_allowed(self) -> None:
        s = self.loop.safety
        if s.interlocked():
            latched = [d["name"] for d in s.describe() if d["latched"]] + (["estop"] if s.estop else [])
            raise InterlockTripped(f"interlock latched ({', '.join(latched)}): reset() first")

    def _supply_min_pa(self) -> float:
        """The lowest supply pressure the detectors accept [Pa] (0 without a supply limit)."""
        return max((lim.lo for lim in self.cfg.limits if lim.channel == "p_s_pa" and lim.action != "indicate"), default=0.0)

    def _wait(self, done: Callable[[], bool], seconds: float) -> bool:
        """Run (thread=False) or wait for the loop until `done()`, at most `seconds` of loop time
        (and ten times that on the wall clock: a loaded host runs late periods); returns whether it came."""
        lp = self.loop
        k0, t0 = lp.k, time.monotonic()
        while not done():
            if (lp.k - k0) * lp.dt > seconds or time.monotonic() - t0 > 10 * seconds + 1.0:
                return False
            if self._thread is None:
                lp.period()
            else:
                time.sleep(0.005)
        return True

    def _load_supply(self, low: bool = False) -> None:
        """Load the supply and wait until its pressure is within its detector's range, before
        anything is energised: after a stop, a trip or an e-stop the supply is unloaded, and
        energising at once would trip the supply detector. Waits at most SUPPLY_TIMEOUT_S.
        `low`: position control's start-up pressure instead (the controller's), reached from
        above or below."""
        lp = self.loop
        if lp.powered:
            return
        if low:
            target = self._low_supply_pa()

            def ok() -> bool:
                return abs(lp.meas["p_s"] - target) <= 0.2 * target + 0.5e5
            what, need = f"{target / 1e5:.1f} bar (start-up)", target
        else:
            need = self._supply_min_pa()
            target = lp.supply_pa

            def ok() -> bool:
                return lp.meas["p_s"] >= need
            what = f"≥ {need / 1e5:.1f} bar (the supply_pressure limit)"
        if ok() and lp._supply_written == target:
            return
        self._do(lambda: lp.write_supply(target), "load supply")
        if not self._wait(ok, SUPPLY_TIMEOUT_S):
            p = lp.meas["p_s"]
            self._do(lambda: lp.write_supply(0.0), "unload supply (it did not come up)")
            raise DeviceError(f"the supply pressure did not come up: p_s = {p / 1e5:.1f} bar after {SUPPLY_TIMEOUT_S:g} s, "
                              f"needed {what} — check the pump and the relief valve; nothing was energised")

    def _low_supply_pa(self) -> float:
        """Position control's start-up supply pressure [Pa] (the controller's choice)."""
        probe = core.CyclicController(self.loop.rate_hz, self.loop.position_settings)
        probe.position(0.1, 0.0)
        return probe.supply_demand_pa

    def _started_up(self) -> None:
        """Wait until position control's hydraulic start-up has reached the working pressure."""
        lp = self.loop
        g = lp.position_settings
        budget = g.get("startup_low_s", 1.0) + g.get("startup_ramp_s", 1.0) + 2.0  # + the unload (≤ 1 s)
        if not self._wait(lambda: not lp.ctrl.starting_up or not lp.powered, budget):
            raise DeviceError(f"position control's start-up did not finish in {budget:g} s (state {lp.ctrl.state})")
        if not lp.powered:
            raise InterlockTripped("position control's start-up was stopped: " +
                                   "; ".join(e["message"] for e in self.log.since(0)[-3:]))

    def _reading(self, key: str, what: str) -> float:
        v = self.loop.meas[key]
        if not math.isfinite(v):
            raise DeviceError(f"{what}: no valid reading ({key} = {v}); nothing was changed")
        return v

    def position(self) -> None:
        """Position control holding where the piston is (installation), amplifier on. From the
        amplifier off, the hydraulics start at low pressure: the controller learns the valve's
        null with the specimen carrying only the piston's weight, ramps to the working pressure
        and takes the weight off (the specimen is then at zero load); returns once done."""
        self._enter_position(None, "position control")

    def _enter_position(self, fn: Callable[[], None] | None, what: str) -> None:
        self._motion_allowed()
        lp = self.loop
        cold = not lp.powered
        self._load_supply(low=cold)

        def f() -> None:
            self._motion_allowed()
            if getattr(lp.ctrl, "is_life", False):  # after a life test: the position controller again
                lp.ctrl = core.CyclicController(lp.rate_hz, lp.position_settings)
            if lp.ctrl.state != "position" or fn is None:
                # bumpless from the present command when powered; from cold the controller's start-up
                lp.ctrl.position(self._reading("y", what), lp.ctrl.u_last_v if lp.powered else 0.0)
            lp.energise()
        if fn is None or lp.ctrl.state != "position" or not lp.powered:
            self._do(f, "position control")
        self._started_up()
        if fn is not None:
            def g() -> None:
                self._motion_allowed()
                fn()
            self._do(g, what)

    def _in_position(self, fn: Callable[[], None], what: str) -> None:
        self._enter_position(fn, what)

    def jog(self, rate_m_s: float) -> None:
        """Move at `rate_m_s` [m/s] (0 stops) in position control with specimen protect."""
        self._in_position(lambda: self.loop.ctrl.jog(rate_m_s), f"jog {rate_m_s * 1e3:+.3f} mm/s")

    def jog_step(self, dm: float) -> None:
        """Move by `dm` [m]."""
        self._in_position(lambda: self.loop.ctrl.jog_step(dm), f"jog step {dm * 1e3:+.4f} mm")

    def move_to(self, y_m: float) -> None:
        """Move to `y_m` [m]."""
        self._in_position(lambda: self.loop.ctrl.move_to(y_m), f"move to {y_m * 1e3:.3f} mm")

    def tare(self) -> float:
        """Zero the load cell at its present reading; returns the offset [N]."""
        def f() -> float:
            lp = self.loop
            lp.load_offset_n += self._reading("f", "tare")  # a NaN offset would poison every later force
            return lp.load_offset_n
        return self._do(f, "tare load cell")

    def start(self, spec, f0_n: float | None = None, *, record: bool = True, store: Any = None,
              recording: bool = True) -> None:
        """Start the test `spec` (htm.spec.TestSpec, or a life test's htm.fatigue.lifetest.LifeSpec:
        force_life / strain_life) with a smooth ramp-in from the present force.
        The controller is built here (its gain design takes milliseconds), then swapped in.
        With `record` the test goes into the test store (`store`: root folder, default
        $HTM_STORE) with a rerun recording (`recording`), see `htm.control.recorder`."""
        self._motion_allowed()
        if self.loop.powered and self.loop.ctrl.starting_up:
            # position control's hydraulic start-up is still at its low pressure: the test starts on
            # the working pressure, once the start-up is through (the supply limit would trip)
            self._started_up()
        self._load_supply()
        if is_life(spec):
            self._start_life(spec, f0_n, record=record, store=store, recording=recording)
            return
        crack = spec.measurement.get("crack", "model")
        if crack == "model" and self.cfg.analog.backend != "simulated":
            raise HtmError(f"test {spec.name}: [measurement] crack = \"model\" grows the crack by the law, which a real specimen "
                           "does not follow: name the rig's measurement (crack = \"compliance\" or \"potential_drop\")")
        channel = {"compliance": "cod", "potential_drop": "dcpd"}.get(crack)
        if channel is not None and channel not in self.cfg.crack_channels:
            raise HtmError(f"test {spec.name}: [measurement] crack = \"{crack}\" needs analog.channels.{channel} in the rig configuration")
        cfg = spec.config.with_params(with_overrides(core.Params(self.cfg.rig_preset), self.cfg.rig_overrides))
        lp = self.loop
        ctrl = core.CyclicController(lp.rate_hz, lp.position_settings)
        f0 = lp.meas["f"] if f0_n is None else f0_n
        ctrl.start_test(cfg, 0.0 if math.isnan(f0) else f0)

        def f() -> int:
            self._motion_allowed()
            lp.ctrl = ctrl
            lp.crack_channel = channel
            lp.test_no += 1  # this test's rows carry its number (cycles restart at 1)
            lp.energise()
            return lp.test_no
        if self.recorder is not None:  # the previous test's recorder: flushed and closed
            self.recorder.stop()
            self.recorder = None
        first_event = self.log.count
        test_no = self._do(f, f"start test {spec.name}")
        if record:  # one live recorder per test
            from htm.control.recorder import LiveRecorder

            self.recorder = LiveRecorder(self, store, spec, test_no, first_event, recording=recording)

    def _start_life(self, spec: Any, f0_n: float | None, *, record: bool, store: Any, recording: bool) -> None:
        """Start a life test (`LifeSpec`): the core's life controller (`engine::life::LifeMachine`,
        the simulator's code) on the loop's rate, fed the load cell, the extensometer's strain and
        the piston position; its rows and kept loops go to the store (`LifeRecorder`)."""
        from htm.control.lifectl import LifeTest
        from htm.devices.config import life_on_loop

        if spec.mode == "strain_life" and not self.cfg.has_extensometer:
            raise HtmError(f"test {spec.name}: strain_life controls the strain: it needs analog.channels.extensometer in the rig configuration")
        if self.rig is not None and self.rig.bar is None:
            raise HtmError(f"test {spec.name}: the virtual rig grips no round bar: open the session with the life spec as its specimen")
        lp = self.loop
        params = with_overrides(core.Params(self.cfg.rig_preset), self.cfg.rig_overrides)
        f0 = lp.meas["f"] if f0_n is None else f0_n
        ctrl = LifeTest(life_on_loop(spec.config, lp.rate_hz), params, 0.0 if math.isnan(f0) else f0, lp.meas["e"], lp.rate_hz)

        def f() -> int:
            self._motion_allowed()
            lp.ctrl = ctrl
            lp.crack_channel = "extensometer" if self.cfg.has_extensometer else None
            lp.test_no += 1
            lp.energise()
            return lp.test_no
        if self.recorder is not None:
            self.recorder.stop()
            self.recorder = None
        first_event = self.log.count
        test_no = self._do(f, f"start {spec.mode} test {spec.name}")
        if record:
            from htm.control.liferecorder import LifeRecorder

            self.recorder = LifeRecorder(self, store, spec, test_no, first_event, recording=recording)

    def hold(self) -> None:
        """Hold the running test: the amplitude ramps to zero over one cycle and the actuator
        stays at the mean force (or position); cycles stop counting. `resume` continues.
        Raises HtmError when no test is running."""
        self._do(self.loop.ctrl.hold, "hold")

    def resume(self) -> None:
        """Continue a held test: the amplitude ramps back in over the spec's start cycles
        (``[start] amplitude_cycles``). Raises HtmError when the test is not held, and
        InterlockTripped while an interlock is latched."""
        def f() -> None:
            self._motion_allowed()
            self.loop.ctrl.command_limit_v = math.inf
            self.loop.ctrl.resume()
        self._do(f, "resume")

    def stop(self) -> None:
        """End the test gently: the amplitude ramps to zero at the mean over the spec's
        ``[start] stop_cycles``, then the valve goes to null and the amplifier off (in position
        control: valve null now). Unlike `estop`, nothing latches."""
        self._do(self.loop.ctrl.stop, "stop")

    def estop(self) -> None:
        """E-stop: valve null, amplifier off, supply unloaded now; latched until reset()."""
        lp = self.loop
        if self._thread is None:
            lp.safety.estop = True
            lp.power_off("e-stop")
        else:  # do not wait for a command slot: set the latch the loop checks every period
            lp.safety.estop = True
            lp.commands.appendleft(lambda: lp.power_off("e-stop"))
        self.log.add(lp.k, "estop", "E-STOP")

    def reset(self) -> list[str]:
        """Reset the interlocks whose condition has gone; returns those still active."""
        def f() -> list[str]:
            lp = self.loop
            still = lp.safety.reset(lp.k)
            if not still:
                lp.ctrl.command_limit_v = math.inf
                lp.trip_period = None
                lp.write_supply(lp.supply_pa)
            return still
        return self._do(f, "reset interlocks")

    # -- live state ---------------------------------------------------------------------------------
    def detectors(self) -> list[dict[str, Any]]:
        """Every safety detector, as the loop sees it now.

        Returns
        -------
        list of dict
            ``name``, ``channel`` (the signal watched: position [m], force [N], pressures [Pa],
            ...), the band ``lo``/``hi`` in that channel's SI unit, ``action`` (what a trip does:
            indicate, hold, stop, power_off), ``state`` (ok, active, tripped), ``latched``, ``enabled``, the
            present ``value`` and the ``trip_value`` that latched it (SI, None if none).
        """
        return self.loop.safety.describe()

    def snapshot(self) -> dict[str, Any]:
        """Live numbers (SI): see the module docstring."""
        lp = self.loop
        c = lp.ctrl
        last = lp.cycles[-1] if lp.cycles and lp.cycles[-1]["test"] == lp.test_no else None
        info = c.info()

        def at(k: str) -> float:
            return last.get(k, math.nan) if last else math.nan
        life = None
        if getattr(c, "is_life", False):  # a life test: its mode, trend, threshold and live loop
            e, st = c.live_loop()
            life = {"mode": c.mode, "drop": c.drop, "area_m2": c.area_m2, "trend": at("trend"), "threshold": at("threshold"), "strain_max": at("strain_max"),
                    "strain_min": at("strain_min"), "stress_max_pa": at("stress_max_pa"), "stress_min_pa": at("stress_min_pa"),
                    "stiffness_n_m": at("stiffness_n_m"), "n_drop10": c.n_drop10, "n_drop50": c.n_drop50,
                    "loop_strain": list(map(float, e)), "loop_stress_pa": list(map(float, st))}
        return {
            "period": lp.k, "t_s": lp.k * lp.dt, "test": lp.test_no, "state": c.state, "mode": self.cfg.loop.mode, "rate_hz": lp.rate_hz,
            "amplifier": lp.powered, "interlock": lp.safety.latched(), "estop": lp.safety.estop,
            "cycles": c.cycle, "frequency_hz": info["frequency_hz"], "a_m": c.a_m, "end_reason": c.end_reason,
            # the crack the test runs on (`crack`: compliance, potential_drop or model) beside the law's,
            # and the last reading's opening force and ΔK_eff (NaN without a compliance reading)
            "crack": {"cod": "compliance", "dcpd": "potential_drop"}.get(lp.crack_channel or "", "model"), "a_law_m": c.a_law_m,
            "opening_force_n": at("opening_force_n"), "delta_k_eff_pa_sqrt_m": at("delta_k_eff_pa_sqrt_m"),
            "delta_k_pa_sqrt_m": at("delta_k_pa_sqrt_m"), "k_sp_n_m": at("k_sp_n_m"),
            "peak_err_pct": at("peak_err_pct"), "df_err_pct": at("df_err_pct"), "last_peak_n": at("fmax_n"), "last_valley_n": at("fmin_n"),
            "life": life,
            "targets": c.targets, "protecting": c.protecting, "reference_m": c.reference_m,
            **{f"{k}": v for k, v in lp.meas.items()}, "timing": lp.timing.stats(),
        }

    def feed_since(self, period: int = 0) -> list[dict[str, Any]]:
        """The decimated live samples (about 20 Hz; a bounded queue, the oldest drop) after loop
        period `period`.

        Returns
        -------
        list of dict
            Per sample: ``period`` (the loop period's number; pass the last one back to get only
            newer samples), time ``t_s`` [s], the controller ``state``, position ``y`` [m],
            velocity ``v`` [m/s], force ``f`` [N], pressures ``p_a``, ``p_b``, ``p_s`` [Pa] and
            the valve command ``u`` [V].
        """
        return [s for s in list(self.loop.feed) if s["period"] > period]

    def cycles_since(self, cycle: int = 0) -> list[dict[str, Any]]:
        """Per-cycle rows of the present (or last) test after `cycle`."""
        n = self.loop.test_no
        return [r for r in list(self.loop.cycles) if r["test"] == n and r["cycle"] > cycle]

    def events_since(self, n: int = 0) -> list[dict[str, Any]]:
        return self.log.since(n)
