"""Model families the identification engine fits, and which one a record calls for.

A family gives, for one record: the nominal parameter set (anything with `copy()`, `p[key]`,
`p[key] = value` and `key in p`), the base model's free parameters, the candidate effects and
the simulator. Two families: the valve-level plant (records with a valve command `u`) and a
machine's closed displacement loop (`machine_position` records: `y_ref`, `y`, optional `f`).
"""
from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from htm.ident.model import Candidate, Free, Model
from htm.ident.records import Record, machine_position


class Family(Protocol):
    name: str
    nominal: Any
    base_frees: list[Free]
    rig_keys: set[str]  # base parameters the metadata states (nominal values)
    opts: dict[str, Any]  # simulator options for this record
    closed_loop: bool  # sensor noise acts inside a loop the model re-simulates
    has_command: bool  # a recorded command the model can be driven with instead of its loop
    # Optional `whole_record: bool`: fit on the whole record, not only the caller's first
    # `work_s` seconds (a family whose simulation is cheap; absent = False). Optional
    # `first_stage: frozenset[str]`: details held while the gross parameters are first fitted.

    def start(self, base: Model) -> np.ndarray: ...  # the coordinates a fit starts from

    def candidates(self, scales: dict[str, float], rate_hz: float) -> list[Candidate]: ...

    def simulate(self, plist: list[Any], rec: Record, **opts: Any) -> list[dict[str, np.ndarray]]: ...


def for_record(rec: Record, channels: list[str], horizon_s: float | None = None) -> Family:
    """The family that models `rec`: a machine's displacement loop for a `machine_position`
    record, else the valve-level plant."""
    if machine_position(rec):
        from htm.ident.loop import LoopFamily

        return LoopFamily(rec, channels)
    from htm.ident.valve import ValveFamily

    return ValveFamily(rec, channels, horizon_s)
