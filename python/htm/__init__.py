"""htm — open software for servo-hydraulic fatigue testing machines.

`import htm` is all a script needs; every quantity is SI (m, N, Pa, s, V; ΔK in Pa·√m).

- the machine: `Machine`, `Params`, `thesis_rig`, `simulate`, `track`
- a fatigue test: `TestSpec`, `load_spec`, `run_test` (simulated), `Session` with `virtual_config`
  (the live or virtual rig), `Store` (every recorded test)
- fatigue data: `read_a_n`, `CrackData`, `Setup`, `e647` (ASTM E647 reduction)
- S-N and strain-life: `read_sn`, `sn_fit` (E739 or maximum likelihood with run-outs), `staircase`
  (ISO 12107), `miner_damage` (rainflow + Miner), `read_en`, `en_fit` (E606 strain-life, K', n')
- measurement records: `read_record`, `write_record`, `Record`, `diagnose`, and `proving_record`
  (a record of the simulated rig with effects switched on, to try a diagnosis on)
- errors: `HtmError` and its subclasses

The names below the machine's are imported on first use, so `import htm` stays cheap.
"""
from __future__ import annotations

from importlib import import_module as _import_module
from typing import TYPE_CHECKING

from htm.core import Machine, Params, __version__
from htm.errors import (
    DeviceError,
    HtmError,
    InfeasibleTest,
    InputError,
    InterlockTripped,
    ParameterError,
    RecordError,
    SolverError,
    SpecError,
)
from htm.params import thesis_rig
from htm.simulate import simulate, track

# public name → (module, name there): loaded by __getattr__ on first use
_LAZY = {
    "TestSpec": ("htm.spec", "TestSpec"),
    "load_spec": ("htm.spec", "load"),
    "run_test": ("htm.run", "run_test"),
    "Store": ("htm.record.store", "Store"),
    "Session": ("htm.control.session", "Session"),
    "virtual_config": ("htm.devices.config", "virtual_config"),
    "read_a_n": ("htm.fatigue.data", "read_a_n"),
    "CrackData": ("htm.fatigue.data", "CrackData"),
    "Setup": ("htm.fatigue.data", "Setup"),
    "e647": ("htm.fatigue.e647", "reduce"),
    "read_sn": ("htm.fatigue.sn", "read_sn"),
    "sn_fit": ("htm.fatigue.sn", "sn_fit"),
    "miner_damage": ("htm.fatigue.sn", "miner_damage"),
    "staircase": ("htm.fatigue.staircase", "dixon_mood"),
    "read_en": ("htm.fatigue.strainlife", "read_en"),
    "en_fit": ("htm.fatigue.strainlife", "en_fit"),
    "read_record": ("htm.ident.records", "read_record"),
    "Record": ("htm.ident.records", "Record"),
    "write_record": ("htm.ident.records", "write_record"),
    "proving_record": ("htm.ident.proving", "make_record"),
    "diagnose": ("htm.ident.diagnose", "diagnose"),
}

__all__ = [
    "Machine",
    "Params",
    "thesis_rig",
    "simulate",
    "track",
    *_LAZY,
    "HtmError",
    "ParameterError",
    "InputError",
    "SolverError",
    "SpecError",
    "InfeasibleTest",
    "RecordError",
    "DeviceError",
    "InterlockTripped",
    "__version__",
]


if TYPE_CHECKING:
    from typing import Any


def __getattr__(name: str) -> Any:
    if name not in _LAZY:
        raise AttributeError(f"module 'htm' has no attribute {name!r}")
    module, attr = _LAZY[name]
    value = getattr(_import_module(module), attr)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    """The public names only (`__all__`): no helpers, no submodules imported on the way."""
    return sorted(__all__)
