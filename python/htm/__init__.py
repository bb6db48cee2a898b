"""htm — open software for servo-hydraulic fatigue testing machines.

`import htm` gives the plant (`Machine`, `Params`), open- and closed-loop simulation, command
profiles, measurement records, and the error hierarchy. All quantities are SI.
"""
from htm._core import Machine, Params, __version__
from htm.errors import (
    DeviceError,
    HtmError,
    InputError,
    InterlockTripped,
    ParameterError,
    RecordError,
    SolverError,
    SpecError,
)
from htm.simulate import simulate, track

__all__ = [
    "Machine",
    "Params",
    "simulate",
    "track",
    "HtmError",
    "ParameterError",
    "InputError",
    "SolverError",
    "SpecError",
    "RecordError",
    "DeviceError",
    "InterlockTripped",
    "__version__",
]
