"""The CANopen position transducer (CiA 406 linear encoder): the device side (a canopen
`LocalNode`, used by the virtual rig) and the master side (a `RemoteNode`: SDO configuration
check at start-up, NMT start/stop, TPDO1 = position + speed on SYNC, heartbeat consumer, EMCY).

The loop drives the bus itself: it sends SYNC and pumps received frames into canopen
(`Network.notify`) from its own thread, so a period never waits on another thread's wake-up."""
from __future__ import annotations

import math
import struct
from collections.abc import Callable

import can
import canopen
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from htm.devices.config import BusConfig, TransducerConfig
from htm.errors import DeviceError

PROFILE = 406
INVALID_POSITION = -(2**31)  # sent instead of a position when the magnet is lost (NaN)
CAN_ERR_BUSOFF = 0x40  # error-frame class bit (linux/can/error.h)
EMCY_SENSOR = 0x7300  # "sensor" error code (CiA 301)


def open_bus(cfg: BusConfig) -> can.BusABC:
    """Open the python-can bus named by the configuration (DeviceError if it cannot)."""
    try:
        return can.Bus(**cfg.kwargs())
    except (can.CanError, OSError, ValueError, ImportError) as e:
        raise DeviceError(f"cannot open CAN bus {cfg.interface}:{cfg.channel}: {e}") from None


def network_on(bus: can.BusABC, threaded: bool, handover: bool = False) -> canopen.Network:
    """A canopen network on `bus`; `threaded` starts python-can's notifier thread. With
    `handover` the thread only serves the start-up (SDO) before the loop pumps the bus itself:
    its idle wait is short, so handing the bus over takes milliseconds instead of up to the
    1 s python-can waits (a message wakes it at once either way)."""
    net = canopen.Network(bus)
    net.NOTIFIER_SHUTDOWN_TIMEOUT = 1.0
    if handover:
        net.NOTIFIER_CYCLE = 0.05
    if threaded:
        net.connect()
    return net


def stop_notifier(net: canopen.Network) -> None:
    """Hand the bus to whoever pumps it (`pump`)."""
    if net.notifier is not None:
        net.notifier.stop(1.0)
        net.notifier = None


class TransducerDevice:
    """The device: answers SDO and NMT, sends TPDO1 (position, speed) on each SYNC while
    operational, a heartbeat every `0x1017` ms of SYNC time (`0x1006` cycle period), and EMCY on
    a fault. `sample()` gives (position [m], speed [m/s]) at each SYNC (the rig's plant step).
    Faults: `silent`, `stuck`, `nan`; `heartbeat = False` stops the heartbeat only."""

    def __init__(self, net: canopen.Network, cfg: TransducerConfig, sample: Callable[[], tuple[float, float]]):
        self.net, self.cfg, self.sample = net, cfg, sample
        self.node = canopen.LocalNode(cfg.node_id, str(cfg.eds))
        net.add_node(self.node)
        # heartbeats follow SYNC time here, not a wall-clock thread
        self.node._write_callbacks.remove(self.node.nmt.on_write)
        self.node.add_read_callback(self._on_read)
        self.node.tpdo.read(from_od=True)
        self.tpdo = self.node.tpdo[1]
        self._pos, self._speed = self.tpdo[0], self.tpdo[1]
        net.subscribe(0x80, self._on_sync)
        self.fault: str | None = None
        self.heartbeat = True
        self.syncs = 0
        self._raw = (0, 0)
        self._emcy_sent = False
        self.node.nmt._state = 127  # pre-operational after boot
        net.send_message(0x700 + cfg.node_id, [0])  # boot-up

    @property
    def resolution_m(self) -> float:
        return self.node.sdo[0x6005][1].raw * 1e-9

    def _on_read(self, index: int, subindex: int, od) -> int | None:
        if index == 0x6004:
            return self._raw[0]
        return None

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        self.syncs += 1
        y, v = self.sample()
        if self.node.nmt.state != "OPERATIONAL":
            return
        period_us = self.node.sdo[0x1006].raw
        hb_ms = self.node.sdo[0x1017].raw
        if self.heartbeat and period_us and hb_ms:
            every = max(1, round(hb_ms * 1000 / period_us))
            if self.syncs % every == 0:
                self.net.send_message(0x700 + self.cfg.node_id, [0x05])
        if self.fault == "silent":
            return
        if self.fault == "nan" or not math.isfinite(y):
            raw = (INVALID_POSITION, 0)
            if not self._emcy_sent:
                self.node.emcy.send(EMCY_SENSOR, 0x01)
                self._emcy_sent = True
        elif self.fault == "stuck":
            raw = self._raw
        else:
            res = self.resolution_m
            raw = (round(y / res), max(-32768, min(32767, round(v / 1e-4))))
        self._raw = raw
        self._pos.raw, self._speed.raw = raw
        self.tpdo.transmit()


class TransducerMaster:
    """The master side of the transducer on a canopen network whose bus the loop pumps."""

    def __init__(self, net: canopen.Network, cfg: TransducerConfig, period_s: float):
        self.net, self.cfg, self.period_s = net, cfg, period_s
        self.node = canopen.RemoteNode(cfg.node_id, str(cfg.eds))
        self.node.sdo.RESPONSE_TIMEOUT = cfg.sdo_timeout_s
        net.add_node(self.node)
        self.position_m = math.nan
        self.speed_m_s = math.nan
        self.seq = 0  # SYNCs sent
        self.fresh_seq = -1  # SYNC that the last TPDO answered
        self.hb_seq = 0  # SYNC count at the last heartbeat
        self.hb_state: int | None = None
        self.emcy: list[tuple[int, str]] = []
        self.error_frames = 0
        self.bus_off = False
        self._res = cfg.resolution_m

    def configure(self) -> dict[str, int]:
        """SDO check and set-up (needs a running notifier): profile, resolution, cycle period,
        heartbeat, TPDO1 mapping; raises DeviceError naming what is wrong."""
        where = f"node {self.cfg.node_id}"
        try:
            dev = self.node.sdo[0x1000].raw
        except SdoCommunicationError:
            raise DeviceError(f"no CANopen node {self.cfg.node_id} answers (SDO timeout {self.cfg.sdo_timeout_s} s): "
                              f"check transducer.node_id and the bus") from None
        try:
            if dev & 0xFFFF != PROFILE:
                raise DeviceError(f"{where}: device type 0x{dev:08X} is not a CiA {PROFILE} encoder")
            step_nm = round(self.cfg.resolution_m * 1e9)
            self.node.sdo[0x6005][1].raw = step_nm
            if self.node.sdo[0x6005][1].raw != step_nm:
                raise DeviceError(f"{where}: position step did not take {step_nm} nm")
            self.node.sdo[0x1006].raw = round(self.period_s * 1e6)
            self.node.sdo[0x1017].raw = self.cfg.heartbeat_ms
            self.node.tpdo.read()  # mapping and transmission type over SDO
        except (SdoAbortedError, SdoCommunicationError) as e:
            raise DeviceError(f"{where}: SDO configuration failed: {e}") from None
        t = self.node.tpdo[1]
        mapped = [(v.index, v.subindex) for v in t.map]
        if not t.enabled or (0x6004, 0) not in mapped or (0x6030, 1) not in mapped or not 1 <= (t.trans_type or 0) <= 240:
            raise DeviceError(f"{where}: TPDO1 must map 0x6004 and 0x6030sub1 and be sent on SYNC (got {mapped}, type {t.trans_type})")
        self._tpdo = t
        self._pos, self._speed = t[0x6004], t[0x6030]
        t.add_callback(self._on_tpdo)
        self.node.nmt.add_heartbeat_callback(self._on_heartbeat)
        self.node.emcy.add_callback(self._on_emcy)
        return {"device_type": dev, "step_nm": step_nm, "cob_id": t.cob_id}

    def start(self) -> None:
        """NMT start: the transducer sends TPDO1 on SYNC from now on."""
        self.node.nmt.state = "OPERATIONAL"

    def stop(self) -> None:
        self.node.nmt.state = "PRE-OPERATIONAL"

    def _on_tpdo(self, m) -> None:
        pos, speed = struct.unpack_from("<ih", m.data)
        self.position_m = math.nan if pos == INVALID_POSITION else pos * self._res
        self.speed_m_s = speed * 1e-4
        self.fresh_seq = self.seq

    def _on_heartbeat(self, state: int) -> None:
        self.hb_seq = self.seq
        self.hb_state = state

    def _on_emcy(self, err) -> None:
        self.emcy.append((err.code, err.get_desc()))

    def send_sync(self) -> None:
        self.seq += 1
        self.net.send_message(0x80, b"")

    def pump(self, timeout: float) -> None:
        """Feed received frames to canopen until this SYNC's TPDO is in or `timeout` [s] passed;
        counts error frames and notes bus-off."""
        bus, notify = self.net.bus, self.net.notify
        t = timeout
        while True:
            msg = bus.recv(t)
            if msg is None:
                return
            if msg.is_error_frame:
                self.error_frames += 1
                if msg.arbitration_id & CAN_ERR_BUSOFF:
                    self.bus_off = True
            else:
                notify(msg.arbitration_id, msg.data, msg.timestamp)
                if self.fresh_seq == self.seq:
                    t = 0.0  # drain what is already there, then go
    @property
    def age_periods(self) -> int:
        """SYNCs since the last fresh TPDO (0 = answered this period)."""
        return self.seq - self.fresh_seq

    @property
    def heartbeat_age_s(self) -> float:
        return (self.seq - self.hb_seq) * self.period_s
