"""The virtual rig: the Rust plant and a cracking specimen behind the real interfaces — a CANopen
`LocalNode` transducer on the configured bus and the simulated DAQ — answering each SYNC with
one plant period. In-process it is pumped by the loop (lock-step) or runs on its own notifier
thread (real time); `htm rig serve` runs it as another process. Faults can be injected."""
from __future__ import annotations

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
          "supply_loss", "valve_stuck", "load_drift", "fracture")


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

    def __init__(self, cfg: RigConfig, specimen: dict | None = None, threaded: bool = True):
        self.cfg = cfg
        self.params = plant_params(cfg)
        self.plant = core.RigPlant(self.params, specimen)
        self.dt = 1.0 / cfg.loop.rate_hz
        ch = cfg.analog.channels
        self._ai = {s: _idx(ch[s]) for s in SENSOR}
        self._valve, self._supply, self._relay = _idx(ch["valve"]), _idx(ch["supply_setpoint"]), _idx(ch["amplifier_enable"])
        self.daq = SimulatedDaq(cfg.analog.device, create=True)
        try:
            self.bus = open_bus(cfg.bus)
            self.net = network_on(self.bus, threaded, lockstep=cfg.loop.mode == "lockstep")
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
        if self.periods == 0 and self.cfg.loop.mode == "realtime":
            set_priority(self.cfg.loop.priority)  # refused: the rig runs on at normal priority
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

    def pump(self) -> None:
        """Handle every frame waiting on the rig's bus (lock-step, no notifier thread)."""
        bus, notify = self.bus, self.net.notify
        while (msg := bus.recv(0)) is not None:
            if not msg.is_error_frame:
                notify(msg.arbitration_id, msg.data, msg.timestamp)

    def lockstep(self) -> None:
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
        elif fault == "fracture":
            self.plant.fracture()
        self.faults[fault] = value

    def clear_faults(self) -> None:
        self.faults.clear()
        self.device.fault = None
        self.device.heartbeat = True
        self.load_offset_n = 0.0

    def close(self) -> None:
        net = getattr(self, "net", None)
        if net is not None:
            stop_notifier(net)
        bus = getattr(self, "bus", None)
        if bus is not None:
            bus.shutdown()
            self.bus = None
        self.daq.close()
