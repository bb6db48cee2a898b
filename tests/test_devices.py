"""Device layer on the real python-can and canopen stacks: two Networks on one virtual channel
(the transducer as a LocalNode, the master as a RemoteNode), configuration refused at start-up,
calibration, the nidaqmx backend (mocked: the hardware cannot exist here)."""
import sys
import types

import canopen
import pytest

from htm.control import Session
from htm.devices.analog import AnalogIO, SimulatedDaq
from htm.devices.config import BUILTIN_EDS, parse_config, virtual_config
from htm.devices.rig import VirtualRig
from htm.devices.transducer import TransducerDevice, TransducerMaster
from htm.errors import DeviceError


@pytest.fixture
def two_networks():
    """As canopen's test_local.py: a device network and a master network on one virtual channel."""
    cfg = virtual_config("lockstep")
    dev_net, master_net = canopen.Network(), canopen.Network()
    for n in (dev_net, master_net):
        n.NOTIFIER_SHUTDOWN_TIMEOUT = 0.5
        n.connect(cfg.bus.channel, interface="virtual")
    state = {"y": 0.1234567, "v": -0.0123}
    dev = TransducerDevice(dev_net, cfg.transducer, lambda: (state["y"], state["v"]))
    master = TransducerMaster(master_net, cfg.transducer, 0.002)
    yield cfg, dev, master, state
    for n in (dev_net, master_net):
        n.disconnect()


def test_sdo_check_nmt_start_and_tpdo_on_sync(two_networks):
    cfg, dev, master, state = two_networks
    info = master.configure()
    assert info["device_type"] & 0xFFFF == 406 and info["cob_id"] == 0x180 + cfg.transducer.node_id
    assert dev.node.sdo[0x1006].raw == 2000, "master wrote the cycle period over SDO"
    got = []
    master.tpdo_seen = got
    master._tpdo.add_callback(lambda m: got.append(bytes(m.data)))
    master.send_sync()
    master.net.bus  # noqa: B018
    import time

    time.sleep(0.05)
    assert got == [], "no TPDO before NMT start (pre-operational)"
    master.start()
    time.sleep(0.05)
    master.send_sync()
    t0 = time.time()
    while master.age_periods and time.time() - t0 < 1:
        time.sleep(0.001)
    assert master.age_periods == 0
    assert master.position_m == pytest.approx(0.1234567, abs=5e-6) and abs(master.position_m / 5e-6 - round(master.position_m / 5e-6)) < 1e-6
    assert master.speed_m_s == pytest.approx(-0.0123, abs=1e-4)
    assert len(got[-1]) == 6, "TPDO1 = position (4 bytes) + speed (2 bytes)"


def test_heartbeat_and_emcy_reach_the_master(two_networks):
    import time

    cfg, dev, master, state = two_networks
    master.configure()
    master.start()
    time.sleep(0.05)
    for _ in range(60):  # heartbeat every 100 ms of SYNC time = 50 SYNCs at 2 ms
        master.send_sync()
        time.sleep(0.001)
    time.sleep(0.05)
    assert master.hb_state == 5, "operational heartbeat"
    dev.fault = "nan"
    master.send_sync()
    time.sleep(0.05)
    assert master.emcy and master.emcy[0][0] == 0x7300
    import math

    assert math.isnan(master.position_m), "the invalid-position marker reads as NaN"


def _virtual_doc(**extra):
    cfg = virtual_config("lockstep")
    doc = {"bus": {"interface": "virtual", "channel": cfg.bus.channel}, "analog": {"device": cfg.analog.device},
           "loop": {"mode": "lockstep"}}
    doc.update(extra)
    return doc


def test_bad_configs_are_refused_with_one_line_errors(tmp_path):
    with pytest.raises(DeviceError, match=r"transducer.node_id = 200 .*1..127"):
        parse_config(_virtual_doc(transducer={"node_id": 200}))
    with pytest.raises(DeviceError, match=r"bus.interface = 'canbus9' is unknown: use one of .*udp_multicast.*virtual"):
        parse_config(_virtual_doc(bus={"interface": "canbus9"}))
    with pytest.raises(DeviceError, match=r"ai3 is mapped twice \(p_s and load\)"):
        parse_config(_virtual_doc(analog={"channels": {"p_s": "ai3"}}))
    eds = tmp_path / "no_speed.eds"
    text = BUILTIN_EDS.read_text()
    eds.write_text(text.replace("[6030]", "[6031]").replace("[6030sub", "[6031sub"))
    with pytest.raises(DeviceError, match=r"has no entry 0x6030sub1 \(speed value\)"):
        parse_config(_virtual_doc(transducer={"eds": str(eds)}))


def test_wrong_node_id_on_the_bus_is_refused_and_nothing_is_energised():
    """The rig's transducer is node 5; a master configured for node 6 finds nobody and stops
    before anything is energised (relay off, valve and supply outputs at 0 V)."""
    cfg = virtual_config("lockstep", transducer={"sdo_timeout_s": 0.1})
    rig = VirtualRig(cfg)
    try:
        wrong = parse_config({"bus": {"interface": "virtual", "channel": cfg.bus.channel}, "analog": {"device": cfg.analog.device},
                              "loop": {"mode": "lockstep"}, "transducer": {"node_id": 6, "sdo_timeout_s": 0.1}})
        supply_v = rig.daq.output(0)
        with pytest.raises(DeviceError, match="no CANopen node 6 answers"):
            Session().open(wrong, thread=False)
        assert not rig.daq.relay(0), "amplifier never enabled"
        assert rig.daq.output(1) == 0.0, "valve command stayed at 0 V"
        assert rig.daq.output(0) == supply_v, "supply setpoint untouched"
    finally:
        rig.close()


def test_calibration_corrects_the_thesis_4_bar_offset():
    cfg = virtual_config("lockstep")
    daq = SimulatedDaq(cfg.analog.device, create=True)
    try:
        io = AnalogIO(cfg.analog)
        daq.set_input(0, (10e6 + 4e5) / 4e6)  # chamber A transducer reads 4 bar high
        daq.set_input(3, 4450.0 / 2500.0)
        p_a, _, _, load = io.read()
        assert p_a == pytest.approx(10e6, abs=2e3) and load == pytest.approx(4450.0, abs=1.0)
        io.write_valve(-2.5)
        io.set_amplifier(True)
        assert daq.output(1) == pytest.approx(-2.5, abs=1e-3) and daq.relay(0)
    finally:
        daq.close()


def test_nidaqmx_backend_is_imported_only_when_chosen(monkeypatch):
    """A stand-in nidaqmx module records the channels and writes (no NI hardware here)."""
    calls = []

    class Chans:
        def __init__(self, kind):
            self.kind = kind

        def __getattr__(self, name):
            return lambda phys, **kw: calls.append((self.kind, phys))

    class Task:
        def __init__(self, name):
            self.ai_channels = self.ao_channels = self.do_channels = Chans(name)

        def write(self, v):
            calls.append(("write", list(v)))

        def read(self):
            return [1.0, 2.0, 3.0, 0.5]

        def close(self):
            pass

    monkeypatch.setitem(sys.modules, "nidaqmx", types.SimpleNamespace(Task=Task))
    cfg = parse_config({"analog": {"backend": "nidaqmx", "device": "cRIO1/Mod1"}})
    io = AnalogIO(cfg.analog)
    assert ("htm-ai", "cRIO1/Mod1/ai3") in calls and ("htm-relay", "cRIO1/Mod1/port0/line0") in calls
    assert io.read()[3] == pytest.approx(1250.0)
    io.write_valve(3.0)
    assert calls[-1] == ("write", [0.0, 3.0, 0.0, 0.0]), "valve on ao1 per Table 3.2"
    monkeypatch.setitem(sys.modules, "nidaqmx", None)
    with pytest.raises(DeviceError, match="pip install 'htm\\[nidaqmx\\]'"):
        AnalogIO(cfg.analog)
