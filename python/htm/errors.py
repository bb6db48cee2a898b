"""The htm exception hierarchy: everything derives from `HtmError` (defined in the Rust core)."""
from htm.core import HtmError, InputError, ParameterError, SolverError


class SpecError(HtmError, ValueError):
    """A test specification is invalid; the message names the field, value and allowed range."""


class SpecParameterError(SpecError, ParameterError):
    """A spec value out of its range: `field` is the spec's own path (``loading.r_ratio``),
    `value` the value given, `allowed` the allowed range with its unit; the message is built
    from them."""

    def __init__(self, field: str, value: float, allowed: str) -> None:
        super().__init__(f"{field} = {value:g} is out of range: allowed {allowed}")
        self.field, self.value, self.allowed = field, value, allowed

    @classmethod
    def of(cls, e: ParameterError) -> "SpecParameterError":
        """The spec's error for a core ParameterError (which names the spec's field)."""
        return cls(e.field, e.value, e.allowed)


class InfeasibleTest(SpecError):
    """The rig cannot run a test (force, valve flow, frequency, stroke or the E647 size
    criterion); the message names the limit that fails and the largest feasible value."""


class RecordError(HtmError, ValueError):
    """A measurement record is malformed (DATA_FORMAT.md)."""


class DeviceError(HtmError):
    """A device (CAN node, DAQ channel) is misconfigured or stopped answering."""


class InterlockTripped(HtmError):
    """A safety interlock latched; the machine was brought to a safe state."""


__all__ = ["HtmError", "ParameterError", "InputError", "SolverError", "SpecError", "SpecParameterError", "InfeasibleTest", "RecordError",
           "DeviceError", "InterlockTripped"]
