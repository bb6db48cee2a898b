"""Rig configuration (TOML): CAN bus, transducer node and EDS, analog channel map and calibration,
loop rate and limits. Everything is validated before anything is opened or energised; errors name
the field, the value and what is allowed."""
from __future__ import annotations

import math
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import canopen

from htm.devices.calibration import Channel, load_calibration
from htm.errors import DeviceError
from htm.inputs import read_text

BUILTIN_EDS = Path(__file__).with_name("btl5_h1.eds")
# objects the master needs from the transducer's EDS (index, subindex or None)
REQUIRED_EDS = {
    (0x1000, None): "device type",
    (0x1017, None): "producer heartbeat time",
    (0x1006, None): "communication cycle period",
    (0x1800, 1): "TPDO1 COB-ID",
    (0x1800, 2): "TPDO1 transmission type",
    (0x1A00, 1): "TPDO1 mapping 1",
    (0x6004, None): "position value",
    (0x6005, 1): "position step setting",
    (0x6030, 1): "speed value",
}
ANALOG_INPUTS = ("p_a", "p_b", "p_s", "load")
# the crack gauges (ASTM E647), wired when the rig has them: a clip gauge's opening (`cod`), the
# direct-current potential drop (`dcpd`, the amplified potential after current reversal) and its
# current monitor (`dcpd_current`); on a second 4-channel input module (ai4..ai7)
CRACK_INPUTS = ("cod", "dcpd", "dcpd_current")
# the specimen's strain gauges (ASTM E606): an axial extensometer's elongation (calibration V → m,
# over its gauge length `analog.extensometer_gauge_length_m` the strain), wired when the rig has one
STRAIN_INPUTS = ("extensometer",)
GAUGE_INPUTS = CRACK_INPUTS + STRAIN_INPUTS
ANALOG_OUTPUTS = ("valve", "supply_setpoint")
RELAYS = ("amplifier_enable",)
# the thesis rig's wiring (Table 3.2): NI 9215 inputs, NI 9263 outputs, NI 9481 relay
THESIS_CHANNELS = {"p_a": "ai0", "p_b": "ai1", "p_s": "ai2", "load": "ai3",
                   "supply_setpoint": "ao0", "valve": "ao1", "amplifier_enable": "relay0"}
PHYSICAL = {"ai": 8, "ao": 4, "relay": 4}
INTERFACES = ("virtual", "udp_multicast", "socketcan")

# Limit detectors: name -> (channel, lo, hi, action). Channels are the loop's watched values.
CHANNELS = ("position_m", "velocity_m_s", "force_n", "p_a_pa", "p_b_pa", "p_s_pa", "following_error_m",
            "amplitude_error_pct", "force_band", "transducer_age_periods", "transducer_fault", "heartbeat_age_s",
            "can_error_frames", "bus_off", "position_plausibility_m", "load_plausibility_n", "force_unexplained",
            "gauge_v", "gauge_jump_m", "dcpd_current_a", "extensometer_v", "extensometer_jump_m")
# the crack gauges' watches when a channel is not wired: inside every limit
GAUGE_ABSENT = {"gauge_v": 0.0, "gauge_jump_m": 0.0, "extensometer_v": 0.0, "extensometer_jump_m": 0.0}
DEFAULT_LIMITS: dict[str, dict[str, Any]] = {
    "position": {"channel": "position_m", "lo": 0.002, "hi": 0.198, "action": "stop"},
    "velocity": {"channel": "velocity_m_s", "lo": -0.3, "hi": 0.3, "action": "power_off"},
    "force": {"channel": "force_n", "lo": -25e3, "hi": 25e3, "action": "stop"},
    "pressure_a": {"channel": "p_a_pa", "lo": -1e5, "hi": 25e6, "action": "stop"},
    "pressure_b": {"channel": "p_b_pa", "lo": -1e5, "hi": 25e6, "action": "stop"},
    "supply_pressure": {"channel": "p_s_pa", "lo": 12e6, "hi": 25e6, "action": "power_off"},
    "following_error": {"channel": "following_error_m", "lo": -2e-3, "hi": 2e-3, "action": "hold"},
    "amplitude_error": {"channel": "amplitude_error_pct", "lo": -10.0, "hi": 10.0, "action": "indicate"},
    "force_band": {"channel": "force_band", "lo": -math.inf, "hi": 0.25, "action": "power_off"},
    "transducer_silent": {"channel": "transducer_age_periods", "lo": 0.0, "hi": 1.0, "action": "power_off"},
    "transducer_fault": {"channel": "transducer_fault", "lo": 0.0, "hi": 0.0, "action": "power_off"},
    "heartbeat": {"channel": "heartbeat_age_s", "lo": 0.0, "hi": 0.15, "action": "power_off"},
    "can_errors": {"channel": "can_error_frames", "lo": 0.0, "hi": 3.0, "action": "stop"},
    "bus_off": {"channel": "bus_off", "lo": 0.0, "hi": 0.0, "action": "power_off"},
    "position_plausibility": {"channel": "position_plausibility_m", "lo": 0.0, "hi": 15e-6, "action": "power_off"},
    "load_plausibility": {"channel": "load_plausibility_n", "lo": 0.0, "hi": 3000.0, "action": "hold"},
    # the specimen broke: the force stopped following the displacement (htm.control.safety.FractureWatch,
    # a fraction of the test's force range); with nothing to push against, the force loop would drive
    # the piston into its end stop, so the amplifier goes off at once
    "fracture": {"channel": "force_unexplained", "lo": 0.0, "hi": 0.05, "action": "power_off"},
    # the crack gauges (E647): a reading the crack size cannot come from holds the test (cycles stop
    # counting, nothing is lost) until the operator has put it right and resumes. The clip gauge's
    # signal near its converter's end (out of range), an opening that jumps by more than the force
    # explains (the gauge slipped on its knife edges), the potential drop's current lost
    "gauge_range": {"channel": "gauge_v", "lo": -9.8, "hi": 9.8, "action": "hold"},
    "gauge_slip": {"channel": "gauge_jump_m", "lo": 0.0, "hi": 20e-6, "action": "hold"},
    "dcpd_current": {"channel": "dcpd_current_a", "lo": 1.0, "hi": 100.0, "action": "hold"},
    # the extensometer (E606): its signal near the converter's end (out of range: the arms opened
    # past their travel or came off), an elongation that jumps by more than the piston's motion
    # and the force's change explain (a knife edge slipped on the bar) hold the test
    "extensometer_range": {"channel": "extensometer_v", "lo": -9.8, "hi": 9.8, "action": "hold"},
    "extensometer_slip": {"channel": "extensometer_jump_m", "lo": 0.0, "hi": 20e-6, "action": "hold"},
}
ACTIONS = ("indicate", "hold", "stop", "power_off")


@dataclass(frozen=True)
class BusConfig:
    interface: str = "virtual"
    channel: str = "htm"
    options: dict[str, Any] = field(default_factory=dict)

    def kwargs(self) -> dict[str, Any]:
        """Arguments for `can.Bus` (python-can)."""
        return {"interface": self.interface, "channel": self.channel, **self.options}


@dataclass(frozen=True)
class TransducerConfig:
    node_id: int = 5
    eds: Path = BUILTIN_EDS
    resolution_m: float = 5e-6
    speed_resolution_m_s: float = 1e-4
    heartbeat_ms: int = 100
    sdo_timeout_s: float = 0.5


@dataclass(frozen=True)
class AnalogConfig:
    backend: str = "simulated"
    device: str = "htm-sim"
    channels: dict[str, str] = field(default_factory=lambda: dict(THESIS_CHANNELS))
    calibration: dict[str, Channel] = field(default_factory=lambda: load_calibration(None))
    # the extensometer's gauge length [m]: its elongation over this is the strain
    extensometer_gauge_length_m: float = 0.025


@dataclass(frozen=True)
class LoopConfig:
    rate_hz: float = 500.0
    mode: str = "realtime"
    # largest |valve command| after a stop or hold trip [V]
    safe_command_v: float = 1.0
    # real time: how long to wait for the TPDO after SYNC, as a fraction of the period
    tpdo_wait: float = 0.4
    # real time: SCHED_FIFO priority of the loop thread (and the in-process rig's); 0 = normal
    priority: int = 0


@dataclass(frozen=True)
class LimitConfig:
    name: str
    channel: str
    lo: float
    hi: float
    action: str
    persist: int = 1


@dataclass(frozen=True)
class RigConfig:
    """The whole rig: see `examples/rig_virtual.toml` for every key."""

    bus: BusConfig = field(default_factory=BusConfig)
    transducer: TransducerConfig = field(default_factory=TransducerConfig)
    analog: AnalogConfig = field(default_factory=AnalogConfig)
    loop: LoopConfig = field(default_factory=LoopConfig)
    limits: tuple[LimitConfig, ...] = ()
    position: dict[str, float] = field(default_factory=dict)
    # the virtual rig's machine: preset and parameter overrides (SI)
    rig_preset: str = "thesis"
    rig_overrides: dict[str, float] = field(default_factory=dict)
    # `[virtual.effects]`: the virtual rig's hidden effects (EFFECTS.md id -> its parameters, SI,
    # and `channel` for a sensor effect). None = the preset's machine as it is; a table (even an
    # empty one) = the EFFECTS.md base model of the rig with exactly these effects (nothing but
    # the virtual rig's plant knows them: not the controller, the spec nor the session)
    virtual_effects: dict[str, dict[str, Any]] | None = None
    # `[virtual.specimen]`: how the virtual rig's specimen departs from the spec's law (c_factor,
    # m, c_scatter: the standard deviation of ln C drawn per specimen, seed); `[virtual.gauges]`:
    # its crack gauges' noise, resolution, drift, closure (see `htm.devices.rig`)
    virtual_specimen: dict[str, float] = field(default_factory=dict)
    virtual_gauges: dict[str, dict[str, float]] = field(default_factory=dict)

    @property
    def crack_channels(self) -> tuple[str, ...]:
        """The crack gauges wired (`cod`, `dcpd`, `dcpd_current`)."""
        return tuple(s for s in CRACK_INPUTS if s in self.analog.channels)

    @property
    def has_extensometer(self) -> bool:
        """An extensometer is wired (`analog.channels.extensometer`)."""
        return "extensometer" in self.analog.channels

    def detector_specs(self) -> list[dict[str, Any]]:
        """The limits as `htm.core.Detectors` items."""
        return [{"name": lim.name, "channel": CHANNELS.index(lim.channel), "lo": lim.lo, "hi": lim.hi, "action": lim.action,
                 "persist": lim.persist} for lim in self.limits]


def _err(msg: str) -> DeviceError:
    return DeviceError(f"rig config: {msg}")


def _keys(d: dict, allowed: set[str], where: str) -> None:
    bad = sorted(set(d) - allowed)
    if bad:
        raise _err(f"[{where}] unknown key{'s' if len(bad) > 1 else ''} {', '.join(bad)}; allowed: {', '.join(sorted(allowed))}")


def _num(d: dict, key: str, where: str, default: float, lo: float, hi: float, unit: str = "") -> float:
    v = d.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (lo <= float(v) <= hi):
        raise _err(f"{where}.{key} = {v!r} is out of range: allowed [{lo:g}, {hi:g}]{' ' + unit if unit else ''}")
    return float(v)


def check_eds(path: Path, node_id: int) -> None:
    """Refuse an EDS that lacks an object the master needs (names the index and what it is)."""
    if not path.exists():
        raise _err(f"transducer.eds = {str(path)!r} does not exist")
    try:
        od = canopen.import_od(str(path), node_id)
    except Exception as e:  # the EDS parser raises many kinds
        raise _err(f"transducer.eds {path}: cannot be read: {e}") from None
    for (index, sub), what in REQUIRED_EDS.items():
        ok = index in od and (sub is None or sub in od[index])
        if not ok:
            entry = f"0x{index:04X}" + (f"sub{sub}" if sub is not None else "")
            raise _err(f"transducer.eds {path.name} has no entry {entry} ({what}): a CiA 406 transducer needs it")


def _channel_map(channels: dict[str, Any]) -> dict[str, str]:
    known = ANALOG_INPUTS + GAUGE_INPUTS + ANALOG_OUTPUTS + RELAYS
    _keys(channels, set(known), "analog.channels")
    out = dict(THESIS_CHANNELS)
    out.update({k: str(v) for k, v in channels.items()})
    seen: dict[str, str] = {}
    for sig, ch in out.items():
        kind = "ai" if sig in ANALOG_INPUTS + GAUGE_INPUTS else "ao" if sig in ANALOG_OUTPUTS else "relay"
        num = ch[len(kind):]
        if not (ch.startswith(kind) and num.isdigit() and int(num) < PHYSICAL[kind]):
            raise _err(f"analog.channels.{sig} = {ch!r}: allowed {kind}0..{kind}{PHYSICAL[kind] - 1}")
        if ch in seen:
            raise _err(f"analog.channels: {ch} is mapped twice ({seen[ch]} and {sig}); each physical channel carries one signal")
        seen[ch] = sig
    return out


def parse_config(doc: dict[str, Any], base: Path | None = None) -> RigConfig:
    """Validate a parsed TOML document into a `RigConfig` (raises DeviceError)."""
    base = base or Path.cwd()
    _keys(doc, {"bus", "transducer", "analog", "loop", "limits", "position", "rig", "virtual"}, "config")
    b = doc.get("bus", {})
    _keys(b, {"interface", "channel", "options"}, "bus")
    interface = str(b.get("interface", "virtual"))
    valid = sorted(set(can.interfaces.VALID_INTERFACES))
    if interface not in valid:
        raise _err(f"bus.interface = {interface!r} is unknown: use one of {', '.join(valid)}")
    bus = BusConfig(interface, str(b.get("channel", "htm")), dict(b.get("options", {})))

    t = doc.get("transducer", {})
    _keys(t, {"node_id", "eds", "resolution_m", "speed_resolution_m_s", "heartbeat_ms", "sdo_timeout_s"}, "transducer")
    node_id = t.get("node_id", 5)
    if isinstance(node_id, bool) or not isinstance(node_id, int) or not 1 <= node_id <= 127:
        raise _err(f"transducer.node_id = {node_id!r} is out of range: allowed 1..127 (CANopen node ID)")
    eds = BUILTIN_EDS if t.get("eds", "builtin") == "builtin" else (base / str(t["eds"])).resolve()
    check_eds(eds, node_id)
    hb = int(_num(t, "heartbeat_ms", "transducer", 100, 1, 65535, "ms"))
    tr = TransducerConfig(node_id, eds, _num(t, "resolution_m", "transducer", 5e-6, 1e-7, 1e-3, "m"),
                          _num(t, "speed_resolution_m_s", "transducer", 1e-4, 1e-6, 1e-2, "m/s"), hb,
                          _num(t, "sdo_timeout_s", "transducer", 0.5, 0.01, 10.0, "s"))

    a = doc.get("analog", {})
    _keys(a, {"backend", "device", "channels", "calibration", "extensometer_gauge_length_m"}, "analog")
    backend = a.get("backend", "simulated")
    if backend not in ("simulated", "nidaqmx"):
        raise _err(f"analog.backend = {backend!r}: use simulated or nidaqmx")
    channels = _channel_map(dict(a.get("channels", {})))
    cal_path = a.get("calibration", "builtin")
    cal = load_calibration(cal_path if cal_path == "builtin" else base / str(cal_path))
    missing = [s for s in ANALOG_INPUTS + ANALOG_OUTPUTS + tuple(c for c in GAUGE_INPUTS if c in channels) if s not in cal]
    if missing:
        raise _err(f"analog.calibration has no entry for {', '.join(missing)}")
    device = str(a.get("device", "htm-sim" if backend == "simulated" else "cRIO1"))
    analog = AnalogConfig(backend, device, channels, cal, _num(a, "extensometer_gauge_length_m", "analog", 0.025, 1e-3, 0.5, "m"))

    lp = doc.get("loop", {})
    _keys(lp, {"rate_hz", "mode", "safe_command_v", "tpdo_wait", "priority"}, "loop")
    mode = lp.get("mode", "realtime")
    if mode not in ("realtime", "lockstep"):
        raise _err(f"loop.mode = {mode!r}: use realtime or lockstep")
    loop = LoopConfig(_num(lp, "rate_hz", "loop", 500.0, 50.0, 5000.0, "Hz"), mode,
                      _num(lp, "safe_command_v", "loop", 1.0, 0.0, 10.0, "V"), _num(lp, "tpdo_wait", "loop", 0.4, 0.0, 0.9),
                      int(_num(lp, "priority", "loop", 0, 0, 99, "(SCHED_FIFO; 0 = normal)")))

    lim = doc.get("limits", {})
    _keys(lim, set(DEFAULT_LIMITS), "limits")
    limits = []
    for name, dflt in DEFAULT_LIMITS.items():
        d = {**dflt, **lim.get(name, {})}
        _keys(d, {"channel", "lo", "hi", "action", "persist"}, f"limits.{name}")
        if d["action"] not in ACTIONS:
            raise _err(f"limits.{name}.action = {d['action']!r}: use one of {', '.join(ACTIONS)}")
        lo, hi = float(d["lo"]), float(d["hi"])
        if not lo <= hi:
            raise _err(f"limits.{name}: lo = {lo:g} must not exceed hi = {hi:g}")
        limits.append(LimitConfig(name, dflt["channel"], lo, hi, d["action"], int(d.get("persist", 1))))

    pos = doc.get("position", {})
    _keys(pos, {"bandwidth_per_s", "velocity_gain_m_s_per_v", "integral_time_s", "max_speed_m_s", "protect_force_n",
                "protect_stiffness_n_m", "y_min_m", "y_max_m", "u_max_v", "low_supply_pa", "startup_low_s", "startup_ramp_s"},
          "position")
    rig = doc.get("rig", {})
    _keys(rig, {"preset", "overrides"}, "rig")
    virt = doc.get("virtual", {})
    _keys(virt, {"effects", "specimen", "gauges"}, "virtual")
    effects = _effects(virt["effects"]) if "effects" in virt else None
    if "dcpd" in channels and "dcpd_current" not in channels:
        raise _err("analog.channels: dcpd needs its current monitor dcpd_current (a lost current must hold the test)")
    vs = virt.get("specimen", {})
    _keys(vs, set(SPECIMEN_KEYS), "virtual.specimen")
    vspec = {k: _num(vs, k, "virtual.specimen", d, lo, hi) for k, (d, lo, hi) in SPECIMEN_KEYS.items() if k in vs}
    vg = virt.get("gauges", {})
    _keys(vg, set(GAUGE_KEYS), "virtual.gauges")
    gauges = {}
    for g, keys in GAUGE_KEYS.items():
        t = vg.get(g, {})
        _keys(t, set(keys), f"virtual.gauges.{g}")
        gauges[g] = {k: _num(t, k, f"virtual.gauges.{g}", d, lo, hi) for k, (d, lo, hi) in keys.items()}
    return RigConfig(bus, tr, analog, loop, tuple(limits), {k: float(v) for k, v in pos.items()},
                     str(rig.get("preset", "thesis")), {k: float(v) for k, v in rig.get("overrides", {}).items()}, effects,
                     vspec, gauges)


# `[virtual.specimen]` and `[virtual.gauges]` keys: (default, lo, hi), SI
# (a life test's bar: `life_scatter_log10` the σ of log10 of its initiation life drawn from `seed`,
# `k_prime_factor` its cyclic K′ against the spec's, `c_factor` its short crack's Paris C)
SPECIMEN_KEYS = {"c_factor": (1.0, 0.01, 100.0), "m": (math.nan, 1.0, 10.0), "c_scatter": (0.0, 0.0, 1.0), "seed": (1, 0, 2**31),
                 "life_scatter_log10": (0.0, 0.0, 1.0), "k_prime_factor": (1.0, 0.5, 2.0)}
GAUGE_KEYS = {
    "cod": {"noise_m": (0.2e-6, 0.0, 1e-4), "resolution_m": (0.0, 0.0, 1e-4), "drift_m_per_cycle": (0.0, -1e-6, 1e-6),
            "closure_opening_fraction": (0.0, 0.0, 0.8), "gauge_x_over_w": (-0.25, -0.345, 0.0)},
    "dcpd": {"noise": (1e-4, 0.0, 0.1), "resolution": (0.0, 0.0, 0.1), "probe_y_m": (0.004, 1e-4, 1.0), "current_a": (10.0, 0.1, 100.0)},
    "extensometer": {"noise_m": (0.0, 0.0, 1e-5)},
}


def life_on_loop(config: dict[str, Any], rate_hz: float) -> dict[str, Any]:
    """A life test's core dict (`htm.fatigue.lifetest.LifeSpec.config`) on a loop of fixed rate:
    a whole number of periods per cycle, the frequency run accordingly."""
    f = float(config.get("frequency_hz", 5.0))
    n = max(1, round(rate_hz / f))
    return {**config, "frequency_hz": rate_hz / n, "control_rate_hz": float(rate_hz), "jump": False}


def _effects(table: Any) -> dict[str, dict[str, Any]]:
    """Validate `[virtual.effects]`: each key an EFFECTS.md id, its value a table of that effect's
    parameters (SI; `channel` for sensor effects), each switched on once on the base model so that
    an unknown id, parameter or channel and an out-of-range value are refused here."""
    from htm.core import Params
    from htm.ident.sim import effect_fields, with_effect

    if not isinstance(table, dict):
        raise _err("[virtual.effects] must be a table: one key per EFFECTS.md id, e.g. valve_null_bias = { bias_v = 0.1 }")
    out: dict[str, dict[str, Any]] = {}
    for eid, spec in table.items():
        where = f"virtual.effects.{eid}"
        if not isinstance(spec, dict):
            raise _err(f"{where} = {spec!r}: give the effect's parameters as a table, e.g. {{ bias_v = 0.1 }}")
        values = {k: v for k, v in spec.items() if k != "channel"}
        bad = [k for k, v in values.items() if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)]
        if bad:
            raise _err(f"{where}.{bad[0]} = {values[bad[0]]!r}: a finite number (SI) is needed")
        channel = spec.get("channel")
        try:
            with_effect(Params("base"), eid, values, channel)
            missing = [k for k in effect_fields(eid, channel) if k not in values]
            if missing:
                raise _err(f"{where}: needs {', '.join(missing)} (EFFECTS.md)")
        except DeviceError:
            raise
        except Exception as e:  # InputError or ParameterError of the effect's parameters
            raise _err(f"{where}: {e}") from None
        out[eid] = {"channel": channel, "values": {k: float(v) for k, v in values.items()}}
    return out


def load_config(path: str | Path) -> RigConfig:
    """Read and validate a rig configuration file."""
    p = Path(path)
    try:
        doc = tomllib.loads(read_text(p, "rig configuration", DeviceError))
    except tomllib.TOMLDecodeError as e:
        raise _err(f"{p}: not valid TOML: {e}") from None
    def sets(d: Any) -> bool:
        return not isinstance(d, dict) or any(sets(v) for v in d.values())

    if not sets(doc):
        raise _err(f"{p} sets nothing (empty, or sections without keys): give at least [bus] and [transducer] "
                   "(see examples/rig_virtual.toml)")
    try:
        return parse_config(doc, p.parent)
    except DeviceError as e:  # the file named in the one line
        raise DeviceError(str(e).replace("rig config: ", f"rig config {p}: ", 1)) from None


def virtual_config(mode: str = "lockstep", rate_hz: float = 500.0, **sections: dict[str, Any]) -> RigConfig:
    """The configuration of an in-process virtual rig: a private virtual CAN channel and
    shared-memory DAQ.

    Parameters
    ----------
    mode : str
        ``"lockstep"`` (one plant period per SYNC, as fast as the host allows) or ``"realtime"``.
    rate_hz : float
        Control loop rate [Hz].
    **sections : dict
        Configuration sections to merge in (``limits``, ``loop``, ...), SI values.

    Returns
    -------
    RigConfig
        The validated configuration, for `Session.open`.
    """
    tag = f"htm-{os.getpid()}-{next(_counter)}"
    doc: dict[str, Any] = {"bus": {"interface": "virtual", "channel": tag}, "analog": {"device": tag},
                           "loop": {"mode": mode, "rate_hz": rate_hz}}
    for k, v in sections.items():
        doc[k] = {**doc.get(k, {}), **v}
    return parse_config(doc)


def _count():
    i = 0
    while True:
        i += 1
        yield i


_counter = _count()
