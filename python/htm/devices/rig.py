"""The virtual rig: the Rust plant and a cracking specimen behind the real interfaces — a CANopen
`LocalNode` transducer on the configured bus and the simulated DAQ — answering each SYNC with
one plant period. In-process it is pumped by the loop, in lock-step and in real time alike: it
answers each SYNC within the period, as a transducer on the wire does, however loaded the host
(on a thread of its own a starved host delayed the rig's answer, and the loop saw a silent
transducer a real one would not be). `htm rig serve` runs it as another process, on its own
notifier thread. Faults can be injected."""
from __future__ import annotations

import math
import random

import can

from htm import core
from htm.devices.analog import SimulatedDaq
from htm.devices.config import RigConfig
from htm.devices.realtime import set_priority
from htm.devices.transducer import CAN_ERR_BUSOFF, TransducerDevice, network_on, open_bus, stop_notifier
from htm.errors import InputError
from htm.params import with_overrides

# the virtual rig's sensors as built (the calibration file corrects them): pressure transducers
# 0–400 bar over 0–10 V with chamber A reading 4 bar high, a 25 kN load cell at ±10 V, and the
# relief valve setting 250 bar at 10 V
SENSOR = {"p_a": (4.0e6, 4.0e5), "p_b": (4.0e6, 0.0), "p_s": (4.0e6, 0.0), "load": (2500.0, 0.0)}
SUPPLY_PA_PER_V = 2.5e6
FAULTS = ("transducer_silent", "transducer_stuck", "transducer_nan", "heartbeat_lost", "can_error_frames", "bus_off",
          "supply_loss", "valve_stuck", "load_drift", "fracture", "gauge_slip", "gauge_out_of_range", "dcpd_current_lost",
          "extensometer_slip", "extensometer_out_of_range")


def true_bar(cfg: RigConfig, life: dict) -> dict:
    """The virtual rig's own life specimen: the spec's bar (`life`: a life test's core dict) with
    the rig's truth the spec does not know (`[virtual.specimen]`): its own life factor
    10^(σ·z) drawn from its `seed` with σ = `life_scatter_log10` (1 without), its cyclic K′ times
    `k_prime_factor`, its short crack's Paris C times `c_factor`; run on the rig's loop rate."""
    from htm.devices.config import life_on_loop

    vs = cfg.virtual_specimen
    out = life_on_loop(life, cfg.loop.rate_hz)
    sigma = vs.get("life_scatter_log10", 0.0)
    z = random.Random(int(vs.get("seed", 1))).gauss(0.0, 1.0) if sigma > 0.0 else 0.0
    out["life_factor"] = 10.0 ** (sigma * z)
    if "k_prime_factor" in vs:
        out["k_prime_pa"] = float(life.get("k_prime_pa", 1200e6)) * vs["k_prime_factor"]
    if "c_factor" in vs:
        out["paris_c"] = float(life.get("paris_c", 1e-29)) * vs["c_factor"]
    return out


class BarPlant:
    """The plant of a life test's virtual rig, as `RigPlant` offers it to `VirtualRig`: the
    machine with the virtual bar on it (`core.LifeRig`: its own cyclic material, life and crack),
    the load cell reading the bar's force; the extensometer's strain is `strain`."""

    def __init__(self, params: core.Params, life: dict):
        self.life = life
        self.rig = core.LifeRig(life, params)
        self.strain = self.rig.outputs()[6]
        self.gauge_readings: list[float] = []

    def step(self, u: float, dt: float) -> tuple[float, ...]:
        o = self.rig.step_all(u, dt)
        self.strain = o[6]
        return o[:6]

    def outputs(self) -> tuple[float, ...]:
        return self.rig.outputs()[:6]

    @property
    def supply_setpoint_pa(self) -> float:
        return self.rig.supply_setpoint_pa

    @supply_setpoint_pa.setter
    def supply_setpoint_pa(self, v: float) -> None:
        self.rig.supply_setpoint_pa = v

    @property
    def valve_null_bias_v(self) -> float:
        return self.rig.valve_null_bias_v

    def truth(self) -> dict:
        """The bar's hidden state (cycles, damage, crack, milestones): for tests, never the controller."""
        return self.rig.truth()


def true_specimen(cfg: RigConfig, specimen: dict | None) -> dict | None:
    """The virtual rig's own specimen: the spec's (its geometry, material, initial crack) with a
    growth law the spec does not know (`[virtual.specimen]`: C times `c_factor`, another `m`,
    ln C scattered by `c_scatter` per specimen, drawn from `seed`). With another m, C is kept
    where the two laws agree at 10 MPa·√m, so the rig's specimen stays in the spec's range."""
    vs = cfg.virtual_specimen
    if specimen is None or not vs:
        return specimen
    law = dict(specimen["law"])
    if "c" not in law:  # a law without a Paris-like C: the spec's as it is
        return specimen
    c = float(law["c"]) * vs.get("c_factor", 1.0)
    m_new = vs.get("m", math.nan)
    if math.isfinite(m_new) and "m" in law:
        c *= 10e6 ** (float(law["m"]) - m_new)
        law["m"] = m_new
    if vs.get("c_scatter", 0.0) > 0.0:
        rng = random.Random(int(vs.get("seed", 1)))
        c *= math.exp(rng.gauss(0.0, vs["c_scatter"]))
    law["c"] = c
    return {**specimen, "law": law}


def plant_params(cfg: RigConfig) -> core.Params:
    """The virtual rig's machine: the preset with its overrides; with `[virtual.effects]`, the
    EFFECTS.md base model of that rig (what `htm diagnose` starts from, built by the same
    function) with exactly the configured effects switched on (`htm.ident.sim.with_effect`)."""
    p = with_overrides(core.Params(cfg.rig_preset), cfg.rig_overrides)
    if cfg.virtual_effects is None:
        return p
    from htm.ident.plant import with_effects
    from htm.ident.sim import params_from_meta
    from htm.params import rig_metadata

    rig = {**rig_metadata(p), "valve_polarity": p["valve_polarity"], "valve_underlap_v": p["valve_underlap_v"],
           **{k: p[k] for k in p.keys() if k.startswith("friction_")}}
    base = params_from_meta({"rig": rig, "specimen": None})
    # what the metadata does not carry stays the rig's (the installation: the specimen's zero-force
    # position); the same function builds an identified model's twin (`htm run --model`)
    return with_effects(base, ((eid, e["values"], e["channel"]) for eid, e in cfg.virtual_effects.items()), p)


def _idx(ch: str) -> int:
    return int(ch.lstrip("airelyo"))


class VirtualRig:
    """Plant + specimen + transducer + DAQ. `specimen` is a `RigPlant` specimen dict (or None)."""

    def __init__(self, cfg: RigConfig, specimen: dict | None = None, threaded: bool = True, handover: bool = False):
        """`threaded`: a notifier thread answers the bus; `handover`: only until the loop pumps
        the rig (`hand_over`, in-process), else for good (`htm rig serve`)."""
        self.cfg = cfg
        self.handover = handover
        self.params = plant_params(cfg)
        self.gripped = specimen  # the specimen dict as given (the spec's; the rig's truth departs from it)
        # a life test's round bar (`{"life": core dict}`), else a cracking specimen (or none)
        self.bar: BarPlant | None = None
        if specimen is not None and "life" in specimen:
            self.bar = BarPlant(self.params, true_bar(cfg, specimen["life"]))
            self.plant = self.bar
            specimen = None
        else:
            self.plant = core.RigPlant(self.params, true_specimen(cfg, specimen))
        self.dt = 1.0 / cfg.loop.rate_hz
        ch = cfg.analog.channels
        self._ai = {s: _idx(ch[s]) for s in SENSOR}
        # the crack gauges wired, read from the rig's own specimen through their chains
        self._gauges: dict[str, tuple[int, int]] = {}  # name -> (plant gauge index, ai channel)
        self._cal = cfg.analog.calibration
        g = cfg.virtual_gauges
        seed = int(cfg.virtual_specimen.get("seed", 1))  # the gauges' noise draws follow the specimen's seed
        if specimen is not None and "cod" in ch:
            c = g.get("cod", {})
            self._gauges["cod"] = (self.plant.add_gauge(
                "compliance", noise=c.get("noise_m", 0.2e-6), resolution=c.get("resolution_m", 0.0),
                drift_per_cycle=c.get("drift_m_per_cycle", 0.0), closure_opening_fraction=c.get("closure_opening_fraction", 0.0),
                gauge_x_over_w=c.get("gauge_x_over_w", -0.25), gauge_y_m=c.get("gauge_y_m", math.nan), seed=2 * seed + 1), _idx(ch["cod"]))
        if specimen is not None and "dcpd" in ch:
            d = g.get("dcpd", {})
            self._gauges["dcpd"] = (self.plant.add_gauge("potential_drop", noise=d.get("noise", 1e-4), resolution=d.get("resolution", 0.0),
                                                         gauge_y_m=d.get("probe_y_m", 0.004), seed=2 * seed + 2), _idx(ch["dcpd"]))
        self._current = (_idx(ch["dcpd_current"]), g.get("dcpd", {}).get("current_a", 10.0)) if "dcpd_current" in ch else None
        # the extensometer on the bar: its elongation over its gauge length, its slips [m]
        self._ext = _idx(ch["extensometer"]) if "extensometer" in ch and self.bar is not None else None
        self._ext_gauge_m = cfg.analog.extensometer_gauge_length_m
        self._ext_noise = g.get("extensometer", {}).get("noise_m", 0.0)
        self._ext_rng = random.Random(3 * seed + 1)
        self.extensometer_offset_m = 0.0
        self._valve, self._supply, self._relay = _idx(ch["valve"]), _idx(ch["supply_setpoint"]), _idx(ch["amplifier_enable"])
        self.daq = SimulatedDaq(cfg.analog.device, create=True)
        try:
            self.bus = open_bus(cfg.bus)
            self.net = network_on(self.bus, threaded, handover=handover)
            self._write_sensors(self.plant.outputs())
            self.daq.write_output(self._supply, self.params["supply_pressure_pa"] / SUPPLY_PA_PER_V)
            self.device = TransducerDevice(self.net, cfg.transducer, self._on_sync)
        except BaseException:
            self.close()
            raise
        self.faults: dict[str, float] = {}
        self.load_offset_n = 0.0
        self.valve_command_v = 0.0
        self.periods = 0

    # -- one plant period per SYNC ------------------------------------------------------------
    def _on_sync(self) -> tuple[float, float]:
        if self.periods == 0 and self.cfg.loop.mode == "realtime" and not self.handover:
            set_priority(self.cfg.loop.priority)  # its own thread; refused: the rig runs on at normal priority
        f = self.faults
        u = self.daq.output(self._valve)
        self.valve_command_v = u
        if not self.daq.relay(self._relay):
            u = -self.plant.valve_null_bias_v  # amplifier off: the spool centres
        if "valve_stuck" in f:
            u = f["valve_stuck"]
        supply = 0.0 if "supply_loss" in f else self.daq.output(self._supply) * SUPPLY_PA_PER_V
        self.plant.supply_setpoint_pa = max(supply, 0.0)
        o = self.plant.step(u, self.dt)
        self.periods += 1
        if "load_drift" in f:
            self.load_offset_n += f["load_drift"] * self.dt
        self._write_sensors(o)
        if "can_error_frames" in f:
            for _ in range(int(f["can_error_frames"])):
                self.bus.send(can.Message(is_error_frame=True, arbitration_id=0x004, dlc=8, data=bytes(8)))
        return o[0], o[1]

    def _write_sensors(self, o: tuple) -> None:
        y, v, p_a, p_b, p_s, force = o
        d, s = self.daq, SENSOR
        for name, val in (("p_a", p_a), ("p_b", p_b), ("p_s", p_s), ("load", force + self.__dict__.get("load_offset_n", 0.0))):
            gain, offset = s[name]
            d.set_input(self._ai[name], (val + offset) / gain)
        f = self.__dict__.get("faults", {})
        if self.__dict__.get("_ext") is not None:
            dl = self.bar.strain * self._ext_gauge_m + self.extensometer_offset_m
            if self._ext_noise > 0.0:
                dl += self._ext_rng.gauss(0.0, self._ext_noise)
            volts = 10.0 if "extensometer_out_of_range" in f else self._cal["extensometer"].to_volts(dl)
            d.set_input(self._ext, volts)
        if not self._gauges and self._current is None:
            return
        readings = self.plant.gauge_readings
        for name, (i, ai) in self._gauges.items():
            val = readings[i]
            if name == "dcpd" and "dcpd_current_lost" in f:
                val = 0.0  # no current, no potential (only the thermal EMFs, cancelled by the reversal)
            volts = self._cal[name].to_volts(val) if math.isfinite(val) else 0.0
            if name == "cod" and "gauge_out_of_range" in f:
                volts = 10.0  # the gauge opened past its travel: the converter saturates
            d.set_input(ai, volts)
        if self._current is not None:
            ai, amps = self._current
            d.set_input(ai, self._cal["dcpd_current"].to_volts(0.0 if "dcpd_current_lost" in f else amps))

    def pump(self) -> None:
        """Handle every frame waiting on the rig's bus (in-process: the loop's thread, no notifier thread)."""
        bus, notify = self.bus, self.net.notify
        while (msg := bus.recv(0)) is not None:
            if not msg.is_error_frame:
                notify(msg.arbitration_id, msg.data, msg.timestamp)

    def hand_over(self) -> None:
        """Stop the notifier thread: the loop pumps the rig from now on."""
        stop_notifier(self.net)

    # -- faults -----------------------------------------------------------------------------------
    def inject(self, fault: str, value: float = 1.0) -> None:
        """Inject a fault (see FAULTS); `value` is the stuck command [V], the drift rate [N/s] or
        the error frames per period."""
        if fault not in FAULTS:
            raise InputError(f"unknown fault {fault!r}: one of {', '.join(FAULTS)}")
        dev = self.device
        if fault == "transducer_silent":
            dev.fault = "silent"
        elif fault == "transducer_stuck":
            dev.fault = "stuck"
        elif fault == "transducer_nan":
            dev.fault = "nan"
        elif fault == "heartbeat_lost":
            dev.heartbeat = False
        elif fault == "bus_off":
            self.bus.send(can.Message(is_error_frame=True, arbitration_id=CAN_ERR_BUSOFF, dlc=8, data=bytes(8)))
            dev.fault = "silent"
        elif fault == "fracture" and self.bar is None:
            self.plant.fracture()
        elif fault == "extensometer_slip":
            if self._ext is None:
                raise InputError("extensometer_slip needs an extensometer on a life test's bar (analog.channels.extensometer)")
            self.extensometer_offset_m += value if value != 1.0 else 50e-6
        elif fault == "fracture" and self.bar is not None:
            raise InputError("fracture: a life test's bar breaks by its own crack")
        elif fault == "gauge_slip":
            if "cod" not in self._gauges:
                raise InputError("gauge_slip needs a clip gauge (analog.channels.cod)")
            self.plant.slip_gauge(self._gauges["cod"][0], value if value != 1.0 else 50e-6)
        self.faults[fault] = value

    def clear_faults(self) -> None:
        self.faults.clear()
        self.device.fault = None
        self.device.heartbeat = True
        self.load_offset_n = 0.0
        self.extensometer_offset_m = 0.0  # the extensometer seated again on the bar
        if "cod" in self._gauges:  # the gauge seated again on its knife edges
            i = self._gauges["cod"][0]
            self.plant.slip_gauge(i, -self.plant_gauge_offset(i))

    def plant_gauge_offset(self, i: int) -> float:
        return self.plant.gauge_offset(i)

    def close(self) -> None:
        net = getattr(self, "net", None)
        if net is not None:
            stop_notifier(net)
        bus = getattr(self, "bus", None)
        if bus is not None:
            bus.shutdown()
            self.bus = None
        self.daq.close()
