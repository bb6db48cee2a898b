"""Analog I/O of the rig (thesis Table 3.2): inputs p_a, p_b, p_s and the load cell, outputs the
valve command and the supply-pressure setpoint, a relay for the amplifier enable. Backends:
`simulated` (registers in shared memory, so the virtual rig can be another process) and `nidaqmx`
(NI hardware, imported only when chosen). Values are calibrated per channel (SI)."""
from __future__ import annotations

from multiprocessing import resource_tracker, shared_memory
from typing import Any

import numpy as np

from htm.devices.config import ANALOG_INPUTS, GAUGE_INPUTS, PHYSICAL, AnalogConfig
from htm.errors import DeviceError

FULL_SCALE_V = 10.0
LSB_V = 2 * FULL_SCALE_V / 65536  # 16-bit converters (NI 9215 / 9263)
_AI, _AO, _RELAY = 0, PHYSICAL["ai"], PHYSICAL["ai"] + PHYSICAL["ao"]
_SIZE = _RELAY + PHYSICAL["relay"]
_CREATED: set[str] = set()  # blocks this process created (and so must unlink)


def quantize(volts: float) -> float:
    """What a ±10 V, 16-bit converter makes of `volts`."""
    v = min(max(volts, -FULL_SCALE_V), FULL_SCALE_V - LSB_V)
    return round(v / LSB_V) * LSB_V


class SimulatedDaq:
    """The simulated DAQ's registers (volts; relays 0/1) in a named shared-memory block.
    The virtual rig creates it (`create=True`); the controller side attaches by name."""

    def __init__(self, name: str, create: bool = False):
        self.name, self.owner = name, create
        try:
            self._shm = shared_memory.SharedMemory(name=name, create=create, size=_SIZE * 8)
        except FileExistsError:
            raise DeviceError(f"simulated DAQ {name!r} already exists (another virtual rig is running)") from None
        except FileNotFoundError:
            raise DeviceError(f"simulated DAQ {name!r} not found: start the virtual rig first (htm rig serve)") from None
        if create:
            _CREATED.add(name)
        elif name not in _CREATED:  # Python < 3.13 would unlink a block it merely attached to at exit
            resource_tracker.unregister(self._shm._name, "shared_memory")  # type: ignore[attr-defined]
        self.reg = np.ndarray((_SIZE,), dtype=np.float64, buffer=self._shm.buf)
        if create:
            self.reg[:] = 0.0

    def close(self) -> None:
        self.reg = np.zeros(_SIZE)
        self._shm.close()
        if self.owner:
            self._shm.unlink()
            _CREATED.discard(self.name)

    # rig side: what the sensors put on the inputs, what the controller put on the outputs
    def set_input(self, i: int, volts: float) -> None:
        self.reg[_AI + i] = quantize(volts)

    def output(self, i: int) -> float:
        return float(self.reg[_AO + i])

    def relay(self, i: int) -> bool:
        return bool(self.reg[_RELAY + i])

    # controller side
    def read_inputs(self, idx: list[int]) -> list[float]:
        r = self.reg
        return [float(r[_AI + i]) for i in idx]

    def write_output(self, i: int, volts: float) -> None:
        self.reg[_AO + i] = quantize(volts)

    def write_relay(self, i: int, on: bool) -> None:
        self.reg[_RELAY + i] = 1.0 if on else 0.0


class NidaqmxDaq:
    """NI hardware through `nidaqmx` (optional extra `htm[nidaqmx]`): one task per direction,
    software-timed single samples (the loop's own period is the clock)."""

    def __init__(self, device: str, channels: dict[str, str]):
        try:
            import nidaqmx  # noqa: PLC0415 — optional, only when chosen
        except ImportError:
            raise DeviceError("analog.backend = nidaqmx needs the nidaqmx package: pip install 'htm[nidaqmx]'") from None
        self._ai = nidaqmx.Task("htm-ai")
        self._ao = nidaqmx.Task("htm-ao")
        self._do = nidaqmx.Task("htm-relay")
        # the inputs up to the highest wired (a rig without crack gauges has one 4-channel module)
        n_ai = 1 + max(int(c[2:]) for c in channels.values() if c.startswith("ai"))
        for i in range(n_ai):
            self._ai.ai_channels.add_ai_voltage_chan(f"{device}/ai{i}", min_val=-10.0, max_val=10.0)
        for i in range(PHYSICAL["ao"]):
            self._ao.ao_channels.add_ao_voltage_chan(f"{device}/ao{i}", min_val=-10.0, max_val=10.0)
        for i in range(PHYSICAL["relay"]):
            self._do.do_channels.add_do_chan(f"{device}/port0/line{i}")
        self._ao_v = [0.0] * PHYSICAL["ao"]
        self._do_v = [False] * PHYSICAL["relay"]
        self._ao.write(self._ao_v)
        self._do.write(self._do_v)

    def read_inputs(self, idx: list[int]) -> list[float]:
        v = self._ai.read()
        return [float(v[i]) for i in idx]

    def write_output(self, i: int, volts: float) -> None:
        self._ao_v[i] = max(-10.0, min(10.0, volts))
        self._ao.write(self._ao_v)

    def write_relay(self, i: int, on: bool) -> None:
        self._do_v[i] = bool(on)
        self._do.write(self._do_v)

    def close(self) -> None:
        for t in (self._ao, self._do, self._ai):
            t.close()


def _index(ch: str) -> int:
    return int(ch.lstrip("airelyo"))


class AnalogIO:
    """The controller's view of the analog channels, calibrated (SI in, SI out)."""

    def __init__(self, cfg: AnalogConfig, daq: Any | None = None):
        self.cfg = cfg
        self.daq = daq or (SimulatedDaq(cfg.device) if cfg.backend == "simulated" else NidaqmxDaq(cfg.device, cfg.channels))
        self._in_idx = [_index(cfg.channels[s]) for s in ANALOG_INPUTS]
        self._in_cal = [cfg.calibration[s] for s in ANALOG_INPUTS]
        self._valve = _index(cfg.channels["valve"])
        self._valve_cal = cfg.calibration["valve"]
        self._supply = _index(cfg.channels["supply_setpoint"])
        self._supply_cal = cfg.calibration["supply_setpoint"]
        self._relay = _index(cfg.channels["amplifier_enable"])
        self._crack = [(s, _index(cfg.channels[s]), cfg.calibration[s]) for s in GAUGE_INPUTS if s in cfg.channels]
        self._gauge_m = cfg.extensometer_gauge_length_m
        self.valve_v = 0.0
        self.amplifier = False

    def read(self) -> tuple[float, float, float, float]:
        """(p_a [Pa], p_b [Pa], p_s [Pa], load [N])."""
        v = self.daq.read_inputs(self._in_idx)
        c = self._in_cal
        return (c[0].to_value(v[0]), c[1].to_value(v[1]), c[2].to_value(v[2]), c[3].to_value(v[3]))

    def read_crack(self) -> dict[str, tuple[float, float]]:
        """The specimen's gauges wired: name -> (value [SI], volts); the crack gauges' value as
        calibrated, the extensometer's the strain (its elongation over its gauge length)."""
        if not self._crack:
            return {}
        v = self.daq.read_inputs([i for _, i, _ in self._crack])
        out = {s: (c.to_value(x), x) for (s, _, c), x in zip(self._crack, v)}
        if "extensometer" in out:
            e, x = out["extensometer"]
            out["extensometer"] = (e / self._gauge_m, x)
        return out

    def write_valve(self, u_v: float) -> None:
        """Valve command [V] (clipped to ±10 V)."""
        self.valve_v = u_v
        self.daq.write_output(self._valve, self._valve_cal.to_volts(u_v))

    def write_supply(self, p_pa: float) -> None:
        """Supply pressure setpoint [Pa]."""
        self.daq.write_output(self._supply, self._supply_cal.to_volts(p_pa))

    def set_amplifier(self, on: bool) -> None:
        self.amplifier = bool(on)
        self.daq.write_relay(self._relay, on)

    def close(self) -> None:
        self.daq.close()
