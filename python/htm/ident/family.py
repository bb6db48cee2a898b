"""Model families the identification engine fits, and which one a record calls for.

A family gives, for one record: the nominal parameter set (anything with `copy()`, `p[key]`,
`p[key] = value` and `key in p`), the base model's free parameters, the candidate effects and
the simulator. Two families: the valve-level plant (records with a valve command `u`) and a
machine's closed displacement loop (`machine_position` records: `y_ref`, `y`, optional `f`).
"""
from __future__ import annotations

from typing import Any, Callable

import numpy as np

from htm.core import closure_spring
from htm.ident.model import Candidate, Form, Free, Model, lin
from htm.ident.records import Record, displacement_input, machine_position
from htm.ident.settings import DEFAULT, SearchSettings

# Effects that are faults of one sensor's reading (EFFECTS.md's sensor effects): a family names
# them on a channel and the search judges them in that reading.
SENSOR_EFFECTS = ("sensor_offset", "sensor_gain", "sensor_delay")
# Of those, the faults of a reading's level (`Candidate.level`).
LEVEL_FAULTS = ("sensor_offset", "sensor_gain")
# Where along the travel the closure of a specimen is first placed (percentiles of the position).
CLOSURE_PERCENTILES = (10, 30, 50, 70, 90)
# The closure stays inside the travel the record visits (these percentiles): a kink beyond it is a
# stiffer spring with an offset, not closure.
CLOSURE_TRAVEL = (2, 98)


class Family:
    """A model family for one record (subclasses: `valve.ValveFamily`, `loop.LoopFamily`).

    It owns its vocabulary (`vocabulary`: the effect ids it can add, `effect_fields`: effect
    parameter names to parameter-set keys), the nominal parameter set (anything with `copy()`,
    `p[key]`, `p[key] = value`, `key in p`), the base model's free parameters, the candidates
    and the simulator. The candidates every family shares are built here once: a sensor's
    faults (`sensor_candidate`, judged in the sensor's own reading) and the closure of a
    specimen (`closure_candidates`)."""

    name: str = ""
    vocabulary: tuple[str, ...] = ()
    nominal: Any
    base_frees: list[Free]
    rig_keys: set[str]  # base parameters the metadata states (nominal values)
    opts: dict[str, Any]  # simulator options for this record
    closed_loop: bool = False  # sensor noise acts inside a loop the model re-simulates
    has_command: bool = False  # a recorded command the model can be driven with instead of its loop
    whole_record: bool = False  # fit the whole record, not only the first `work_s` seconds (cheap simulation)
    first_stage: frozenset[str] = frozenset()  # details held while the gross parameters are first fitted
    has_probes: bool = False  # `probes` looks for structure outside the vocabulary
    settings: SearchSettings = DEFAULT
    # Readings measured alike, by channel (the two chamber pressures): a sensor fault found on one
    # is checked against the same fault on the other (`Candidate.sibling`).
    siblings: dict[str, str] = {}

    def effect_fields(self, effect: str, channel: str | None = None) -> dict[str, str]:
        raise NotImplementedError

    def start(self, base: Model) -> np.ndarray:
        """The coordinates a fit starts from (the nominal values)."""
        return base.start()

    def candidates(self, scales: dict[str, float], rate_hz: float) -> list[Candidate]:
        raise NotImplementedError

    def probes(self, residual: dict[str, np.ndarray], rate_hz: float) -> list[Candidate]:
        return []

    def simulate(self, plist: list[Any], rec: Record, **opts: Any) -> list[dict[str, np.ndarray]]:
        raise NotImplementedError

    def candidate(self, effect: str, channel: str | None, frees: tuple[Free, ...], signature: str, **kw: Any) -> Candidate:
        """A candidate of this family's vocabulary, its report fields from `effect_fields`; a
        sensor effect is judged in its own reading."""
        fields = tuple(self.effect_fields(effect, channel).items())
        sensor = effect in SENSOR_EFFECTS
        return Candidate(effect, channel, frees, signature, fields=fields, own_reading=sensor,
                         sibling=self.siblings.get(channel or "") if sensor else None,
                         level=effect in LEVEL_FAULTS, **kw)

    def sensor_candidate(self, effect: str, channel: str, unit: float, *, bound: float = 1e3,
                         claimable: Claim | None = None, form: Form | None = None) -> Candidate:
        """A fault of one sensor's reading (EFFECTS.md): `sensor_offset` (in units of `unit`,
        the channel's scale, within ±`bound` of them), `sensor_gain` (in 1 % steps, 0.5-1.5 and
        beyond) or `sensor_delay` (in units of `unit`, the sample period, up to 100 of them);
        the parameter-set keys are `sensor_offset_<c>`, `sensor_gain_<c>`, `sensor_delay_<c>_s`."""
        if effect == "sensor_offset":
            free, signature = lin(f"sensor_offset_{channel}", unit, -bound, bound), "constant"
        elif effect == "sensor_gain":
            free, signature = lin(f"sensor_gain_{channel}", 0.01, -50.0, 50.0, origin=1.0), f"predicted {channel}"
        elif effect == "sensor_delay":
            free, signature = lin(f"sensor_delay_{channel}_s", unit, 0.0, 100.0), f"d(predicted {channel})/dt"
        else:
            raise ValueError(f"`{effect}` is not a sensor effect ({', '.join(SENSOR_EFFECTS)})")
        return self.candidate(effect, channel, (free,), signature, claimable=claimable, form=form)

    def closure_candidates(self, y: np.ndarray, zero_position_m: float, stiffness_n_m: float,
                           f: np.ndarray | None = None) -> list[Candidate]:
        """A specimen's closure (EFFECTS.md `specimen_nonlinearity` on f: a stiffer spring
        beyond a closure position): its position is not smooth to find, so a few starts along
        the travel are screened, and it stays inside the travel the record visits. Its stiffness
        in units of a tenth of `stiffness_n_m` (up to 1000 times it). With the force `f` read, a
        refit also starts from the spring the force shows against the position (`closure_spring`:
        the specimen's stiffness, closure stiffness and closure position), which a base fitted
        without the closure has averaged over both branches (`Candidate.restart`)."""
        y = np.asarray(y, dtype=float)
        unit_off = max(1e-6, 0.1 * float(np.nanstd(y)))
        lo, hi = ((float(np.nanpercentile(y, q)) - zero_position_m) / unit_off for q in CLOSURE_TRAVEL)
        restart: tuple[tuple[str, float], ...] = ()
        if f is not None and (spring := closure_spring(np.asarray(f, dtype=float), y)) is not None:
            k, k_cl, at = spring
            restart = (("specimen_stiffness_n_m", k), ("specimen_closure_stiffness_n_m", k_cl),
                       ("specimen_closure_offset_m", at - zero_position_m))
        out = []
        for q in CLOSURE_PERCENTILES:
            off = float(np.nanpercentile(y, q)) - zero_position_m
            out.append(self.candidate("specimen_nonlinearity", "f",
                                      (lin("specimen_closure_stiffness_n_m", 0.1 * stiffness_n_m, 0.0, 1e4),
                                       lin("specimen_closure_offset_m", unit_off, lo, hi)), "y", starts=(off / unit_off,),
                                      restart=restart))
        return out


Claim = Callable[[dict[str, float]], bool]


def for_record(rec: Record, channels: list[str], horizon_s: float | None = None,
               settings: SearchSettings = DEFAULT) -> Family:
    """The family that models `rec`: a machine's displacement loop for a `machine_position`
    record, else the valve-level plant."""
    if displacement_input(rec):  # a specimen and its load train: displacement in, force out
        from htm.ident.specimen import SpecimenFamily

        return SpecimenFamily(rec, channels, settings)
    if machine_position(rec):
        from htm.ident.loop import LoopFamily

        return LoopFamily(rec, channels, settings)
    from htm.ident.valve import ValveFamily

    return ValveFamily(rec, channels, horizon_s, settings)
