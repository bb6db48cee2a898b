"""Models the identification engine fits: free parameters in normalised coordinates, a model
(a nominal parameter set plus the free parameters' coordinates) and candidate effects.

Family-neutral: a parameter set is anything with `copy()`, `p[key]` and `p[key] = value` (the
core's `Params` for the valve-level plant, `LoopParams` for a machine's closed displacement loop).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

# Distance (in normalised coordinates) from a bound at which a parameter counts as pinned.
PIN = 0.02


@dataclass(frozen=True)
class Free:
    """One free parameter in normalised coordinates x: value = ref*exp(x) (log) or origin + unit*x."""

    key: str
    lo: float
    hi: float
    log: bool = False
    unit: float = 1.0
    step: float = 0.02  # finite-difference / screening step in x
    origin: float = 0.0  # the "effect off" value of a linear parameter (x = 0)
    prior: float = 0.0  # prior width in x around the nominal (0 = no prior)

    def value(self, x: float, ref: float) -> float:
        return ref * math.exp(x) if self.log else self.origin + self.unit * x

    def coord(self, value: float, ref: float) -> float:
        return math.log(value / ref) if self.log else (value - self.origin) / self.unit

    def pinned(self, x: float) -> bool:
        return x <= self.lo + PIN or x >= self.hi - PIN


def lin(key: str, unit: float, lo: float, hi: float, step: float = 1.0, origin: float = 0.0, prior: float = 0.0) -> Free:
    """A linear free parameter: value = origin + unit*x, x in [lo, hi]."""
    return Free(key, lo, hi, unit=unit, step=step, origin=origin, prior=prior)


def logf(key: str, lo: float, hi: float, step: float = 0.02, prior: float = 0.0) -> Free:
    """A free parameter scaled around its nominal value: value = nominal*exp(x), lo <= value/nominal <= hi."""
    return Free(key, math.log(lo), math.log(hi), log=True, step=step, prior=prior)


@dataclass(frozen=True)
class Derived:
    """A key that is not a single field of a family's parameter set (the valve family's symmetric
    Coulomb level and its asymmetry over the pos/neg pair): how to read, write and test it, and
    the fields it stands for in a report. A family registers its own (`derive`); the engine
    knows none by name."""

    key: str
    get: Callable[[Any], float]
    set: Callable[[Any, float], None]
    fields: tuple[str, ...]


DERIVED: dict[str, Derived] = {}


def derive(d: Derived) -> None:
    """Register a family's derived key (idempotent)."""
    DERIVED[d.key] = d


def set_value(p: Any, key: str, value: float) -> None:
    if key in DERIVED:
        DERIVED[key].set(p, value)
    else:
        p[key] = value


def get_value(p: Any, key: str) -> float:
    return DERIVED[key].get(p) if key in DERIVED else p[key]


def has_key(p: Any, key: str) -> bool:
    return all(k in p for k in DERIVED[key].fields) if key in DERIVED else key in p


@dataclass
class Model:
    """A parameter set: the nominal one, the free parameters and their coordinates."""

    nominal: Any
    frees: list[Free]
    x: np.ndarray

    def params(self, x: np.ndarray | None = None) -> Any:
        x = self.x if x is None else x
        p = self.nominal.copy()
        for f, xi in zip(self.frees, x):
            set_value(p, f.key, f.value(float(xi), get_value(self.nominal, f.key) if f.log else 0.0))
        return p

    def at(self, x: np.ndarray) -> "Model":
        return Model(self.nominal, self.frees, np.asarray(x, dtype=float))

    def start(self) -> np.ndarray:
        """Coordinates of the nominal values (0 for a log parameter)."""
        return np.array([0.0 if f.log else f.coord(get_value(self.nominal, f.key), 0.0) for f in self.frees])

    def pinned(self, n: int | None = None) -> list[str]:
        """Keys of the (first `n`) free parameters that sit at a bound."""
        return [f.key for f, x in zip(self.frees[:n], self.x[:n]) if f.pinned(x)]

    def unpinned(self, start: np.ndarray, nominal: np.ndarray | None = None) -> "Model":
        """This model with parameters that sit at a bound moved back to `start`: a base parameter
        pinned at its bound was standing in for an effect the model lacked. One that started at
        a bound (a spool started static) stays there if it never left it, else goes to `nominal`."""
        x = self.x.copy()
        for i, f in enumerate(self.frees[: len(start)]):
            if not f.pinned(x[i]):
                continue
            if not f.pinned(start[i]):
                x[i] = start[i]
            elif nominal is not None and abs(x[i] - start[i]) > 2 * PIN:
                x[i] = nominal[i]
        return self.at(x)

    def moved_to(self, values: dict[str, float]) -> "Model":
        """This model with the free parameters named in `values` at those values (within their
        bounds); the others as they are."""
        x = self.x.copy()
        for i, f in enumerate(self.frees):
            if f.key in values:
                x[i] = min(max(f.coord(values[f.key], get_value(self.nominal, f.key) if f.log else 0.0), f.lo), f.hi)
        return self.at(x)

    def with_candidate(self, cand: "Candidate", x0: float | None = None) -> "Model":
        """This model with a candidate effect added (its first parameter at x0, default its step)."""
        nominal = self.nominal
        if cand.switch:
            nominal = nominal.copy()
            for k, v in cand.switch:
                nominal[k] = v
        xs = [cand.frees[0].step if x0 is None else x0, *cand.starts] if cand.frees else []
        return Model(nominal, [*self.frees, *cand.frees], np.append(self.x, xs))

    def without(self, cand: "Candidate", nominal: Any) -> "Model":
        """This model with an accepted effect taken out (its parameters removed, its switch undone
        back to `nominal`)."""
        nom = self.nominal
        if cand.switch:
            nom = nom.copy()
            for k, _ in cand.switch:
                nom[k] = nominal[k]
        if not cand.frees:
            return Model(nom, self.frees, self.x)
        i = self.frees.index(cand.frees[0])
        j = i + len(cand.frees)
        return Model(nom, self.frees[:i] + self.frees[j:], np.concatenate([self.x[:i], self.x[j:]]))

    def ablated(self, before: "Model", cand: "Candidate") -> "Model":
        """This model (= `before` plus `cand`) with the candidate switched off, other parameters kept."""
        x = self.x.copy()
        x[len(before.x):] = 0.0
        return Model(before.nominal if cand.switch else self.nominal, self.frees, x)

    def truncated(self, n: int) -> "Model":
        """The model with only its first `n` free parameters (the nominal kept)."""
        return Model(self.nominal, self.frees[:n], self.x[:n])

    def values(self) -> dict[str, float]:
        """The free parameters' values (a derived key by the fields it stands for)."""
        p = self.params()
        out: dict[str, float] = {}
        for f in self.frees:
            for k in DERIVED[f.key].fields if f.key in DERIVED else (f.key,):
                out[k] = p[k]
        return out


# The base values a refit without an effect starts from, where the base's own form can make what
# the effect makes (`Candidate.form`): given that model's parameter set and the effect's parameters.
Form = Callable[[Any, dict[str, float]], "dict[str, float] | None"]


@dataclass(frozen=True)
class Candidate:
    """An effect the model can take on: free parameters (the first is screened, the others start
    at `starts`) and/or a switch applied to the nominal parameters. `signature` names the signal
    the effect's residual follows (report and plots); `report` maps the model's parameters to the
    effect's own (EFFECTS.md names)."""

    effect: str
    channel: str | None
    frees: tuple[Free, ...]
    signature: str
    starts: tuple[float, ...] = ()
    switch: tuple[tuple[str, float], ...] = ()
    fields: tuple[tuple[str, str], ...] = ()  # (effect parameter name, parameter-set key)
    # The smallest size worth claiming, as a test of the effect's reported parameters (None: any
    # size that pays off): below it the effect is within what the base model's form can mimic.
    claimable: Callable[[dict[str, float]], bool] | None = None
    # A tone (a probe at a fixed frequency): judged in its own narrow band around this frequency,
    # where a broadband residual would drown it.
    tone_hz: float | None = None
    # The effect is a fault of the reading of `channel` (a sensor's): its signature is judged in
    # that reading (through restarts from the measured state it moves the others too).
    own_reading: bool = False
    # The channel of a reading measured alike (the other chamber's pressure): the same fault on
    # both readings is the plant's form (lines, the valve), not two sensors' (`Selector.sibling_check`).
    sibling: str | None = None
    # The fault shifts or scales the reading's level (an offset, a gain): the sibling's other level
    # fault contends with it too (`Selector.other_kind`; the base's pressure levels move both
    # chambers together, so one chamber's offset can be fitted as the other's gain).
    level: bool = False
    # A composite (effects that pay off only together, as a play with the friction behind it): its
    # parts, each a candidate on a contiguous run of these frees; refitted beside the single
    # candidates every round, and found as one finding per part.
    parts: tuple["Candidate", ...] = ()
    # The samples where the effect stands apart from what the base's own parameters can mimic
    # (entrained air: where a chamber's pressure runs low), as a mask over the record (None: no
    # such test). The effect must cut the held-out error there (`search.pays_off`); a record that
    # never gets there cannot tell it from the base's form.
    shows: Callable[[], np.ndarray] | None = None
    # ...and must cut it there about as well as elsewhere, not only gain there (a leak: its flow
    # is in every sample, largest against the actuator's where the load holds it slow; one that
    # gains mostly elsewhere stands in for the base's dynamics): the share of the error it leaves
    # where it shows at most `SearchSettings.shows_ratio` times the share it leaves elsewhere, or
    # the share it takes there at least `shows_gain` times the share it takes elsewhere.
    shows_against_rest: bool = False
    # The samples where the effect acts alone in the record (a leak: the actuator standing still,
    # where its flow has no motion or line dynamics beside it), as a mask over the record (None: no
    # such test): it must take at least `SearchSettings.still_share` of the held-out error there
    # (`search.takes_at_standstill`).
    still: Callable[[], np.ndarray] | None = None
    # Values (parameter key, value: base parameters or the effect's own) at which a refit also
    # starts, beside the current fit and the nominal base (`search._restarts`): what the record
    # itself shows of the effect and of the base parameters it trades with (a closure's spring
    # read from the force against the position). Keys the model does not free are left alone.
    restart: tuple[tuple[str, float], ...] = ()
    # The same effect on another coordinate (a vertical rig's asymmetry with the weight it trades
    # with held): refitted beside this one, the better fit kept (`Selector.coordinates`).
    alternate: "Candidate | None" = None
    # Where the coordinate holds, as a test of a fitted point's whole parameter set (None: everywhere):
    # a weighed asymmetry holds the weight it trades with only while its mass stays above the floor
    # its setter clamps at; a fit beyond that is the plain asymmetry with the mass moved, not this
    # coordinate's, and `Selector.judged` judges the other coordinate's fit instead.
    holds: Callable[[Any], bool] | None = None

    # The base's own form that can make what the effect makes (a reading's delay: the base's spool
    # slower by the delay), as the base values (parameter key: value) a refit of the model without
    # the effect starts from, given that model's parameter set and the effect's reported parameters
    # (None: no such form). The effect must pay off against that refit too (`Selector.own_form`).
    form: "Form | None" = None

    def report(self, p: Any) -> dict[str, float]:
        return {name: float(p[key]) for name, key in self.fields}

    @property
    def label(self) -> str:
        return self.effect + (f" on {self.channel}" if self.channel else "")

    @property
    def key(self) -> tuple[str, str | None]:
        return (self.effect, self.channel)

    @property
    def keys(self) -> set[tuple[str, str | None]]:
        """The keys of the effects this candidate adds (its parts' for a composite)."""
        return {c.key for c in self.parts} if self.parts else {self.key}
