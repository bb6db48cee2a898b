"""Devices of the rig: the CANopen position transducer (CiA 406), analog I/O (simulated, nidaqmx),
per-channel calibration, the rig configuration, and the virtual rig that answers on the same
interfaces."""
from htm.devices.config import RigConfig, load_config, parse_config, virtual_config

__all__ = ["RigConfig", "load_config", "parse_config", "virtual_config"]
