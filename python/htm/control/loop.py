"""The fixed-period control loop: each period send SYNC, take the transducer's TPDO and the
analog inputs, check freshness, call the Rust controller, evaluate the limits, write the valve
command. Lock-step runs periods back to back against an in-process virtual rig; real time keeps
a wall-clock schedule on a dedicated thread (sleep to just before the deadline, then spin)."""
from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from htm import core
from htm.control.safety import CH, FRACTURE_STATES, EventLog, FractureWatch, Safety
from htm.control.timing import Timing
from htm.devices.analog import AnalogIO
from htm.devices.config import RigConfig
from htm.devices.realtime import set_priority
from htm.devices.transducer import TransducerMaster

ERROR_WINDOW = 50  # periods over which CAN error frames are counted
SPIN_NS = 300_000  # real time: sleep until this long before the deadline, then spin
FEED_HZ = 20.0
PLAUS_WINDOW = 4  # periods over which the position is checked against the integrated speed
LOCKSTEP_REPLY_S = 0.05  # lock-step against a rig in another process: its answer to one SYNC


def position_settings(cfg: RigConfig, params: core.Params) -> dict[str, float]:
    """The controller's position-mode settings: the configuration's `[position]` with the plant
    data the hydraulic start-up needs (working and tank pressure, piston area, moving weight)."""
    return {"supply_pa": params["supply_pressure_pa"], "tank_pa": params["tank_pressure_pa"],
            "area_m2": max(params["area_a_m2"], params["area_b_m2"]),
            "weight_n": params["moving_mass_kg"] * params["gravity_m_s2"], **cfg.position}


class ControlLoop:
    """One control period at a time (`period()`), or `run_realtime` on a thread."""

    def __init__(self, cfg: RigConfig, master: TransducerMaster, io: AnalogIO, params: core.Params,
                 pump_rig: Callable[[], None] | None = None, log: EventLog | None = None):
        self.cfg, self.master, self.io, self.pump_rig = cfg, master, io, pump_rig
        self.rate_hz = cfg.loop.rate_hz
        self.dt = 1.0 / self.rate_hz
        self.position_settings = position_settings(cfg, params)
        self.ctrl = core.CyclicController(self.rate_hz, self.position_settings)
        self.log = log or EventLog()
        self.safety = Safety(cfg, self.log)
        self.timing = Timing()
        self.k = 0
        self.powered = False
        self.load_offset_n = 0.0
        self.supply_pa = params["supply_pressure_pa"]
        self._area_a, self._area_b = params["area_a_m2"], params["area_b_m2"]
        self._weight = params["moving_mass_kg"] * params["gravity_m_s2"]
        self._errs: deque[int] = deque([0] * ERROR_WINDOW, maxlen=ERROR_WINDOW)
        self._err_seen = 0
        # fresh position samples of the last PLAUS_WINDOW periods: (period, y, v)
        self._fresh: deque[tuple[int, float, float]] = deque(maxlen=PLAUS_WINDOW + 1)
        self._fracture = FractureWatch(self.dt, cfg.transducer.speed_resolution_m_s)
        self._last_results = 0
        # the crack measurement's channel of the running test (`cod` or `dcpd`; None: the law),
        # and the clip gauge's slip watch: compliance from the recent periods, last (cod, force)
        self.crack_channel: str | None = None
        self._slip = [0.0, 0.0, math.nan, math.nan]  # Σ Δv·ΔF, Σ ΔF², last v, last F
        # the extensometer's slip watch: Σ of Δy², Δy·ΔF, ΔF², Δl·Δy, Δl·ΔF over the recent
        # periods, and the last (elongation, force, position)
        self._ext = [0.0] * 5 + [math.nan] * 3
        self._ext_range = self._limit("extensometer_range")
        self._decim = max(1, round(self.rate_hz / FEED_HZ))
        # how long to wait for this SYNC's TPDO: a share of the period in real time; in lock-step
        # nothing when the rig is pumped here, else long enough for another process to answer
        if cfg.loop.mode == "realtime":
            self._wait = cfg.loop.tpdo_wait * self.dt
        else:
            self._wait = 0.0 if pump_rig is not None else LOCKSTEP_REPLY_S
        # per-cycle rows of every test of the session, each tagged with its test's number (`test`):
        # cycle numbers restart at 1 with each test, so a consumer keeps to its own test's rows
        self.test_no = 0
        self.cycles: deque[dict[str, Any]] = deque(maxlen=100_000)
        self.feed: deque[dict[str, Any]] = deque(maxlen=400)
        self.commands: deque[Callable[[], None]] = deque()
        self.meas = {"y": math.nan, "v": math.nan, "f": math.nan, "p_a": math.nan, "p_b": math.nan, "p_s": math.nan, "u": 0.0,
                     "e": math.nan}
        self.max_abs_u_after_trip = 0.0
        self.trip_period: int | None = None
        self.stop_requested = False
        self._supply_written = 0.0
        io.write_valve(0.0)
        io.set_amplifier(False)
        io.write_supply(0.0)  # hydraulics off until a motion or a test: position control starts them low

    # -- outputs ----------------------------------------------------------------------------------
    def supply_demand_pa(self) -> float:
        """The supply pressure to ask for now [Pa]: the position start-up's while it runs."""
        c = self.ctrl
        return c.supply_demand_pa if c.starting_up else self.supply_pa

    def write_supply(self, pa: float) -> None:
        self._supply_written = pa
        self.io.write_supply(pa)

    def energise(self) -> None:
        if not self.powered:
            self.write_supply(self.supply_demand_pa())
            self.io.set_amplifier(True)
            self.powered = True
            self.log.add(self.k, "amplifier", "amplifier enabled")

    def power_off(self, why: str) -> None:
        self.ctrl.idle()
        self.io.write_valve(0.0)
        self.io.set_amplifier(False)
        self.write_supply(0.0)
        if self.powered:
            self.log.add(self.k, "amplifier", f"valve null, amplifier disabled, supply unloaded ({why})")
        self.powered = False

    def _act(self, action: str, y: float) -> None:
        c = self.ctrl
        self.trip_period = self.k if self.trip_period is None else self.trip_period
        if action == "indicate":
            return
        if action == "power_off":
            self.power_off("trip")
            return
        c.command_limit_v = min(c.command_limit_v, self.cfg.loop.safe_command_v)
        if action == "hold":
            if c.state in ("starting", "running"):
                c.hold()
            elif c.state == "position":
                c.position(y, c.u_last_v)
        elif action == "stop":
            c.stop()
        self.log.add(self.k, "action", f"{action}: controller {c.state}, |command| ≤ {c.command_limit_v:g} V")

    # -- one period -------------------------------------------------------------------------------
    def period(self) -> float:
        """One control period; returns the valve command written [V]."""
        self.k += 1
        while self.commands:
            self.commands.popleft()()
        m = self.master
        m.send_sync()
        if self.pump_rig is not None:
            self.pump_rig()
        m.pump(self._wait)
        y, v = m.position_m, m.speed_m_s
        p_a, p_b, p_s, load = self.io.read()
        f = load - self.load_offset_n
        c = self.ctrl
        fed = self.k % self._decim == 0
        f_ref = c.force_ref_n if fed else math.nan  # the setpoint at this period's force (set by the last step)
        crack = self.io.read_crack()
        src = self.crack_channel
        m_src = crack[src][0] if src in crack else math.nan
        if src == "extensometer" and not self._ext_range[0] < crack[src][1] < self._ext_range[1]:
            m_src = math.nan  # out of its range: no strain to control by (the controller commands no flow)
        u = c.step(f, y, m_src)
        st = c.state
        # watched values (see htm.devices.config.CHANNELS)
        val = self.safety.values
        val[CH["position_m"]] = y
        val[CH["velocity_m_s"]] = v
        val[CH["force_n"]] = f
        val[CH["p_a_pa"]] = p_a
        val[CH["p_b_pa"]] = p_b
        # the supply against what is asked of it: during the start-up, scaled to the working pressure
        demand = self.supply_demand_pa()
        val[CH["p_s_pa"]] = (p_s * self.supply_pa / demand if demand > 0.0 else p_s) if self.powered else self.supply_pa
        val[CH["following_error_m"]] = c.reference_m - y if st == "position" and not c.protecting else 0.0
        band = 0.0
        if st in ("running", "holding") and c.targets is not None:
            fmax, fmin, _ = c.targets
            band = max(fmin - f, f - fmax) / (fmax - fmin)
        val[CH["force_band"]] = band
        r = None
        if c.results != self._last_results:
            self._last_results = c.results
            r = c.last_cycle()  # None when a new test has just replaced the controller
        if r is not None:
            r["period"] = self.k
            r["test"] = self.test_no
            self.cycles.append(r)
            # judged cycles only: the ramp-in and the ramp back in after a hold are not
            val[CH["amplitude_error_pct"]] = r["df_err_pct"] if r["judged"] else 0.0
        elif st not in ("running", "holding"):
            val[CH["amplitude_error_pct"]] = 0.0
        val[CH["transducer_age_periods"]] = m.age_periods
        val[CH["transducer_fault"]] = 1.0 if (math.isnan(y) and m.age_periods == 0) or m.emcy else 0.0
        val[CH["heartbeat_age_s"]] = m.heartbeat_age_s
        self._errs.append(m.error_frames - self._err_seen)
        self._err_seen = m.error_frames
        val[CH["can_error_frames"]] = sum(self._errs)
        val[CH["bus_off"]] = 1.0 if m.bus_off else 0.0
        fresh = m.age_periods == 0
        plaus = 0.0
        if fresh and math.isfinite(y):
            plaus = self._plausibility(y, v)
        val[CH["position_plausibility_m"]] = plaus
        unexplained = 0.0
        if st in FRACTURE_STATES and c.targets is not None and fresh and math.isfinite(y):
            fw = self._fracture
            if fw.test is not c:  # a new test (a new controller): a new specimen, its own stiffness
                fw.new_test(c, c.info()["samples_per_cycle"])
            unexplained = fw.update(self.k, f, v, c.targets[0] - c.targets[1])
        val[CH["force_unexplained"]] = unexplained
        f_hyd = self._area_a * p_a - self._area_b * p_b - self._weight
        val[CH["load_plausibility_n"]] = abs(f - f_hyd) if self.powered else 0.0
        if crack:
            self._watch_gauges(crack, f, st)
            if "extensometer" in crack:
                self._watch_extensometer(crack["extensometer"], f, y, st)
        worst = self.safety.check(self.k)
        if worst is not None:
            self._act(worst, y)
        # outputs: nothing beyond the safe value after a trip; nothing at all when powered off
        if c.state in ("idle",) or not self.powered:
            if self.powered:
                self.power_off("idle")
            u = 0.0
        elif c.state == "stopped":
            self.io.write_valve(c.u_null_v)
            self.power_off(f"test {c.end_reason or 'stopped'}")
            u = 0.0
        else:
            lim = c.command_limit_v
            u = max(-lim, min(lim, u))
            if demand != self._supply_written:
                self.write_supply(demand)
        self.io.write_valve(u)
        if self.trip_period is not None:
            self.max_abs_u_after_trip = max(self.max_abs_u_after_trip, abs(u))
        mm = self.meas
        mm["y"], mm["v"], mm["f"], mm["p_a"], mm["p_b"], mm["p_s"], mm["u"] = y, v, f, p_a, p_b, p_s, u
        mm["e"] = crack["extensometer"][0] if "extensometer" in crack else math.nan
        if fed:
            self.feed.append({"period": self.k, "t_s": self.k * self.dt, "state": c.state, "cycle": c.cycle, "f_ref": f_ref, **mm})
        return u

    def _watch_gauges(self, crack: dict[str, tuple[float, float]], f: float, st: str) -> None:
        """The crack gauges' watches: the clip gauge's signal [V] (out of range near ±10 V), its
        jump [m] (the opening's change less what the force's change explains with the compliance
        of the recent periods: a slip on the knife edges is a step the force does not make), the
        potential drop's current [A]."""
        val = self.safety.values
        if "dcpd_current" in crack:
            val[CH["dcpd_current_a"]] = crack["dcpd_current"][0]
        if "cod" not in crack:
            return
        cod, volts = crack["cod"]
        val[CH["gauge_v"]] = volts
        s = self._slip
        jump = 0.0
        lo, hi = self._limit("gauge_range")
        if not lo < volts < hi:
            cod = math.nan  # out of its range: no opening to judge a slip by (gauge_range's business)
        if st in FRACTURE_STATES and math.isfinite(cod) and math.isfinite(f) and math.isfinite(s[2]):
            dv, df = cod - s[2], f - s[3]
            comp = s[0] / s[1] if s[1] > 0.0 else 0.0
            jump = abs(dv - comp * df)
            if jump < self._limit("gauge_slip")[1]:  # a slip does not teach the compliance
                s[0], s[1] = 0.995 * s[0] + dv * df, 0.995 * s[1] + df * df
        elif st not in FRACTURE_STATES:
            s[0] = s[1] = 0.0
        s[2], s[3] = cod, f
        val[CH["gauge_jump_m"]] = jump

    def _watch_extensometer(self, reading: tuple[float, float], f: float, y: float, st: str) -> None:
        """The extensometer's watches: its signal [V] (out of range near ±10 V) and its jump [m]:
        the elongation's change less what the piston's motion and the force's change explain.
        The bar and the load train are in series, so the piston's travel is the gauge's
        elongation (times the bar's length over the gauge's) plus the load train's stretch:
        Δl = a·Δy + b·ΔF with a, b fitted over the recent periods — a linear relation however
        the bar yields. A knife edge slipping on the bar is a step the piston does not make."""
        strain, volts = reading
        val = self.safety.values
        val[CH["extensometer_v"]] = volts
        w = self._ext
        lo, hi = self._limit("extensometer_range")
        l_m = strain * self.cfg.analog.extensometer_gauge_length_m if lo < volts < hi else math.nan
        jump = 0.0
        if st in FRACTURE_STATES and all(math.isfinite(x) for x in (l_m, f, y, w[5], w[6], w[7])):
            dl, df, dy = l_m - w[5], f - w[6], y - w[7]
            syy, syf, sff, sly, slf = w[:5]
            det = syy * sff - syf * syf
            # judged once the piston's motion is well beyond its transducer's resolution
            if det > 1e-9 * syy * sff and syy > 100.0 * self.cfg.transducer.resolution_m ** 2:
                a = (sly * sff - slf * syf) / det
                b = (slf * syy - sly * syf) / det
                jump = abs(dl - a * dy - b * df)
            if jump < self._limit("extensometer_slip")[1]:  # a slip does not teach the relation
                k = 0.995
                w[0], w[1], w[2], w[3], w[4] = k * syy + dy * dy, k * syf + dy * df, k * sff + df * df, k * sly + dl * dy, k * slf + dl * df
        elif st not in FRACTURE_STATES:
            w[:5] = [0.0] * 5
        w[5], w[6], w[7] = l_m, f, y
        val[CH["extensometer_jump_m"]] = jump

    def _limit(self, name: str) -> tuple[float, float]:
        for lim in self.cfg.limits:
            if lim.name == name:
                return lim.lo, lim.hi
        return -math.inf, math.inf

    def _plausibility(self, y: float, v: float) -> float:
        """|position change − integrated speed| [m] over the fresh samples of the last
        PLAUS_WINDOW periods (trapezoid): a frozen or jumping position adds up period by period,
        so a transducer stuck at a slow move shows within a few periods, while the quantisation
        of one sample does not grow. A silence breaks the window (its own detector's business).
        What the trapezoid cannot know is taken off: where within a period the speed changed
        (half of each change times the period; nothing at a steady speed, so a stuck transducer
        at a steady move shows as before, while a strain-controlled bar's yield or a crack
        closing turns the piston within a period without a false trip)."""
        w = self._fresh
        if w and w[-1][0] != self.k - 1:
            w.clear()
        w.append((self.k, y, v))
        if len(w) < 2:
            return 0.0
        pairs = list(zip(w, list(w)[1:]))
        dist = sum(0.5 * (a[2] + b[2]) * self.dt for a, b in pairs)
        slack = sum(0.5 * abs(b[2] - a[2]) * self.dt for a, b in pairs)
        return max(abs((w[-1][1] - w[0][1]) - dist) - slack, 0.0)

    # -- schedulers ---------------------------------------------------------------------------------
    def run_lockstep(self, periods: int) -> None:
        for _ in range(periods):
            self.period()

    def run_realtime(self, seconds: float | None = None, stop: Callable[[], bool] | None = None) -> None:
        """Wall-clock periods on this thread until `seconds` pass or `stop()` is true."""
        refused = set_priority(self.cfg.loop.priority)
        if refused:
            self.log.add(0, "warning", refused)
        period_ns = round(self.dt * 1e9)
        perf, sleep = time.perf_counter_ns, time.sleep
        t0 = perf()
        deadline = t0 + period_ns
        end = None if seconds is None else t0 + round(seconds * 1e9)
        while not (stop is not None and stop()) and not self.stop_requested:
            now = perf()
            rem = deadline - now
            if rem > SPIN_NS:
                sleep((rem - SPIN_NS) / 1e9)
            while perf() < deadline:
                pass
            start = perf()
            self.period()
            done = perf()
            over = done > deadline + period_ns
            self.timing.record(start - deadline, done - start, over)
            deadline += period_ns
            if done > deadline:  # late: skip the missed slots, keep the grid
                deadline += ((done - deadline) // period_ns + 1) * period_ns
            if end is not None and deadline > end:
                break
