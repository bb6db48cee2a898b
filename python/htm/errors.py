"""The htm exception hierarchy: everything derives from `HtmError` (defined in the Rust core)."""
from htm._core import HtmError, InputError, ParameterError, SolverError


class SpecError(HtmError, ValueError):
    """A test specification is invalid; the message names the field, value and allowed range."""


class RecordError(HtmError, ValueError):
    """A measurement record is malformed (DATA_FORMAT.md)."""


class DeviceError(HtmError):
    """A device (CAN node, DAQ channel) is misconfigured or stopped answering."""


class InterlockTripped(HtmError):
    """A safety interlock latched; the machine was brought to a safe state."""


__all__ = ["HtmError", "ParameterError", "InputError", "SolverError", "SpecError", "RecordError", "DeviceError", "InterlockTripped"]
