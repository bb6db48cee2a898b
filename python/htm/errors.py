"""The htm exception hierarchy: everything derives from `HtmError` (defined in the Rust core)."""
from htm.core import HtmError, InputError, ParameterError, SolverError


class SpecError(HtmError, ValueError):
    """A test specification is invalid; the message names the field, value and allowed range."""


class InfeasibleTest(SpecError):
    """The rig cannot run a test (force, valve flow, frequency, stroke or the E647 size
    criterion); the message names the limit that fails and the largest feasible value."""


class RecordError(HtmError, ValueError):
    """A measurement record is malformed (DATA_FORMAT.md)."""


class DeviceError(HtmError):
    """A device (CAN node, DAQ channel) is misconfigured or stopped answering."""


class InterlockTripped(HtmError):
    """A safety interlock latched; the machine was brought to a safe state."""


__all__ = ["HtmError", "ParameterError", "InputError", "SolverError", "SpecError", "InfeasibleTest", "RecordError", "DeviceError", "InterlockTripped"]
