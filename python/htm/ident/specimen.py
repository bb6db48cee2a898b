"""The specimen family: `displacement_input` records (DATA_FORMAT.md: a displacement `y`, or a
clip gauge's `cod`, and the force `f`; `"controller": {"type": "displacement_input"}`), modelled
by the core's specimen and load-train force model (`crates/htm-core/src/specimen_force.rs`,
`SpecimenParams`) driven by the measured displacement.

Its base model is EFFECTS.md's for such records: a linear spring (stiffness identified; the
zero-force position identified unless the metadata declares it, which DATA_FORMAT.md trusts like
the geometry) with viscous damping. Its effects are EFFECTS.md's "Specimen and load train" ids:
`specimen_nonlinearity` (crack closure: a stiffer spring below a closure position),
`specimen_friction`, `load_train_backlash` and `sensor_offset` on `f`. The search, its stages and
its rules are the engine's own (`search.py`); this module only says what the model is. One effect
is the project's own id (EFFECTS.md allows it): `presliding_friction`, a friction that builds up
over a displacement after each reversal (an elasto-plastic element) where `specimen_friction`
builds up over a velocity; behind a load-train play it unloads, rests over the gap and loads again
(the core's model). A play with a friction behind it, the gap large against the travel, pays off
only as a whole: the family offers that pair as composites (`play_with_friction`), which the
search refits beside the single effects and reports as two findings.

The displacement is the model's input: its prediction is the record's own reading (an error of
zero, reported as such), and every finding shows in the force.
"""
from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from htm.core import SpecimenParams, specimen_force
from htm.errors import HtmError, InputError, RecordError
from htm.ident.family import Family
from htm.ident.features import smooth
from htm.ident.model import Candidate, Free, lin, logf
from htm.ident.records import Record, displacement_input
from htm.ident.settings import DEFAULT, SearchSettings

FAMILY = "displacement_input"
# What the model reads (y, the input) and predicts (f).
CHANNELS = ("y", "f")
# Effect id -> {effect parameter name: SpecimenParams key} (EFFECTS.md names).
EFFECT_FIELDS: dict[str, dict[str, str]] = {
    "sensor_offset": {"offset_n": "sensor_offset_f"},
    "specimen_friction": {"friction_n": "specimen_friction_n", "velocity_m_s": "specimen_friction_velocity_m_s"},
    "load_train_backlash": {"gap_m": "load_train_gap_m"},
    # the project's own id (EFFECTS.md lets a tool propose its own): friction that builds up over a
    # displacement after each reversal (pre-sliding, an elasto-plastic element) rather than over a
    # velocity — a dry friction damper's band, a bolted joint
    "presliding_friction": {"friction_n": "specimen_presliding_friction_n", "presliding_m": "specimen_presliding_m"},
    "specimen_nonlinearity": {"closure_stiffness_n_m": "specimen_closure_stiffness_n_m",
                              "closure_offset_m": "specimen_closure_offset_m"},
}
# How an effect of the model is reported (EFFECTS.md's ids are what a reader and a judge go by):
# the pre-sliding form is a friction in the load path as EFFECTS.md's `specimen_friction` means
# it ("a force that opposes the motion", a damper's, a guide's), built up over a displacement
# instead of a velocity; it is reported under that id with its own build-up parameter
# (`friction_n`, `presliding_m`), so the model keeps one friction of either form.
REPORTED_AS = {"presliding_friction": "specimen_friction"}
# The window of the central difference that gives the specimen's velocity [s] (at least one sample
# each side): 20 ms keeps a displacement transducer's noise out of the friction and the damping
# (a micrometre of noise differenced over one millisecond is a velocity of about a mm/s, the size
# of a friction's build-up velocity) and is exact for the sines and rounded ramps of a test.
VELOCITY_WINDOW_S = 0.02
# Friction's build-up velocity starts at this share of the record's fast velocities (99th
# percentile), and the screen tries these factors on it.
FRICTION_VELOCITY_SHARE = 0.05
FRICTION_VELOCITY_STARTS = (0.2, 1.0, 5.0)
# A play with a friction behind it (composites): the friction's build-up velocity (factors on its
# nominal) and the pre-sliding displacement (shares of the travel) the refits start from.
COMPOSITE_VELOCITY_STARTS = (1.0, 5.0)
COMPOSITE_PRESLIDING_STARTS = (0.05, 0.15, 0.4)
# Pre-sliding displacement: nominal share of the travel, and the shares the screen starts from.
PRESLIDING_SHARE = 0.01
PRESLIDING_STARTS = (0.002, 0.01, 0.05)


def displacement_record(rec: Record) -> Record:
    """`rec` with its displacement in `y`: a clip gauge's `cod` is the displacement of a
    `displacement_input` record that has no `y` (the same record otherwise)."""
    if displacement_input(rec) and "y" not in rec.columns and "cod" in rec.columns:
        return Record({**rec.columns, "y": rec.columns["cod"]}, rec.meta, rec.name)
    return rec


def params_from_meta(meta: dict[str, Any]) -> SpecimenParams:
    """The specimen model's nominal parameters from a record's metadata: every effect off, the
    declared stiffness and zero-force position if any."""
    p = SpecimenParams()
    spec = meta.get("specimen")
    if isinstance(spec, dict):
        for key, field in (("stiffness_n_m", "specimen_stiffness_n_m"), ("zero_force_position_m", "specimen_zero_force_position_m")):
            v = spec.get(key)
            if v is not None:
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                    raise RecordError(f"metadata `specimen.{key}` = {v!r} must be a finite number")
                p[field] = float(v)
    return p


def declared_zero(meta: dict[str, Any]) -> bool:
    spec = meta.get("specimen")
    return isinstance(spec, dict) and spec.get("zero_force_position_m") is not None


def effect_fields(effect: str) -> dict[str, str]:
    """{effect parameter name: SpecimenParams key} of one of the specimen family's effects."""
    if effect not in EFFECT_FIELDS:
        raise InputError(f"unknown specimen effect `{effect}`; known: {', '.join(EFFECT_FIELDS)}")
    return dict(EFFECT_FIELDS[effect])


def simulate(plist: list[SpecimenParams], rec: Record, *, threads: int = 0) -> list[dict[str, np.ndarray]]:
    """Each parameter set's readings over `rec`: `y`, the measured displacement (the input, as
    recorded) and `f`, the load cell's force the model gives for it; one batch in Rust on all
    cores (`threads` = 0) with the GIL released. A set that cannot be evaluated gives NaN forces."""
    rec = displacement_record(rec)
    t = np.asarray(rec.columns["t"], dtype=float)
    if len(t) < 2:
        raise RecordError(f"record `{rec.name}` has {len(t)} samples; at least 2 are needed to simulate")
    if "y" not in rec.columns:
        raise RecordError(f"record `{rec.name}` has no displacement (`y` or `cod`) to drive the specimen model with")
    dt = float(np.median(np.diff(t)))
    y = np.ascontiguousarray(rec.columns["y"], dtype=float)
    out = specimen_force(list(plist), dt, y, threads=threads)
    return [{"y": y, "f": np.full(len(t), np.nan) if isinstance(r, HtmError) else np.asarray(r)} for r in out]


class SpecimenFamily(Family):
    """The specimen and load train of one `displacement_input` record: nominal parameters
    (started at the least-squares spring and damper through the measured force), the base
    model's free parameters and the candidate effects."""

    name = FAMILY
    vocabulary = tuple(EFFECT_FIELDS)
    closed_loop = False
    has_command = False
    whole_record = True  # a simulation costs microseconds per parameter set: fit every block

    def __init__(self, rec: Record, channels: list[str], settings: SearchSettings = DEFAULT) -> None:
        self.settings = settings
        rec = displacement_record(rec)
        other = [c for c in channels if c not in CHANNELS]
        if other or "f" not in channels:
            raise RecordError(f"record `{rec.name}` is a displacement_input record: its model reads the displacement "
                              f"(`y` or `cod`) and predicts the force `f`; it cannot model "
                              + (f"column(s) {', '.join(other)}" if other else "a record without `f`"))
        self.rec = rec
        self.channels = channels
        self.opts: dict[str, Any] = {}
        self.rig_keys: set[str] = set()
        t = np.asarray(rec.columns["t"], dtype=float)
        self.dt = dt = float(np.median(np.diff(t)))
        y = _filled(rec.columns["y"])
        f = _filled(rec.columns["f"])
        v = np.gradient(smooth(y, max(1, int(round(VELOCITY_WINDOW_S / dt)))), dt)
        self.v_max = max(float(np.percentile(np.abs(v), 99)), 1e-9)
        self.y_lo, self.y_hi = float(np.percentile(y, 1)), float(np.percentile(y, 99))
        self.y_span = max(self.y_hi - self.y_lo, 1e-9)
        self.f_max = max(float(np.percentile(np.abs(f - np.median(f)), 99)), 1e-3)
        nominal = params_from_meta(rec.meta)
        self.zero_declared = declared_zero(rec.meta)
        if not self.zero_declared:
            nominal["specimen_zero_force_position_m"] = float(np.median(y))
        nominal["velocity_window_s"] = max(VELOCITY_WINDOW_S, 2.0 * dt)
        nominal["specimen_friction_velocity_m_s"] = FRICTION_VELOCITY_SHARE * self.v_max
        nominal["specimen_presliding_m"] = PRESLIDING_SHARE * self.y_span
        self._start(nominal, y, v, f, stiffness_declared=nominal["specimen_stiffness_n_m"] > 0)
        self.nominal = nominal
        self.base_frees: list[Free] = self._base_frees()

    def _start(self, p: SpecimenParams, y: np.ndarray, v: np.ndarray, f: np.ndarray, *, stiffness_declared: bool) -> None:
        """The least-squares spring and damper through the measured force (a constant takes up the
        load cell's offset, which the search judges, or places the zero-force position when the
        metadata does not declare it)."""
        y0 = p["specimen_zero_force_position_m"]
        a = np.column_stack([y - y0, v, np.ones_like(y)])
        coef, *_ = np.linalg.lstsq(a, f, rcond=None)
        k = float(max(coef[0], 0.0))
        if not stiffness_declared:
            p["specimen_stiffness_n_m"] = k
        p["specimen_damping_n_s_m"] = float(max(coef[1], 0.0))
        if not self.zero_declared and k > 0:
            lo, hi = self._zero_bounds()
            p["specimen_zero_force_position_m"] = float(np.clip(y0 - coef[2] / k, lo, hi))

    def _zero_bounds(self) -> tuple[float, float]:
        """Where an undeclared zero-force position may lie: within the travel the record visits
        and as far again on either side (a specimen loaded in tension throughout has it below)."""
        return self.y_lo - 2.0 * self.y_span, self.y_hi + 2.0 * self.y_span

    def _base_frees(self) -> list[Free]:
        k_unit = self.f_max / self.y_span * 0.01
        frees = [
            lin("specimen_stiffness_n_m", k_unit, 0.0, 1e6, step=1.0),
            lin("specimen_damping_n_s_m", self.f_max / self.v_max * 0.01, 0.0, 1e6, step=1.0),
        ]
        if not self.zero_declared:
            unit = 1e-3 * self.y_span
            lo, hi = self._zero_bounds()
            frees.append(lin("specimen_zero_force_position_m", unit, lo / unit, hi / unit, step=1.0))
        return frees

    @staticmethod
    def effect_fields(effect: str, channel: str | None = None) -> dict[str, str]:
        return effect_fields(effect)

    @staticmethod
    def simulate(plist: list[SpecimenParams], rec: Record, **opts: Any) -> list[dict[str, np.ndarray]]:
        if opts:
            raise RecordError(f"the specimen model takes no simulation options (got {', '.join(opts)})")
        return simulate(plist, rec)

    def candidates(self, scales: dict[str, float], rate_hz: float) -> list[Candidate]:
        """EFFECTS.md's specimen and load-train effects, and the load cell's offset."""
        fmax = self.f_max
        out = [
            self.sensor_candidate("sensor_offset", "f", scales["f"], bound=1e4),
            self.candidate("load_train_backlash", "f", (lin("load_train_gap_m", 0.01 * self.y_span, 0.0, 50.0),), "sign(v)"),
        ]
        # friction's build-up velocity is not smooth to find from far off (a tanh far too sharp
        # chatters on the noise, far too soft is viscous damping): a few starts are screened
        for factor in FRICTION_VELOCITY_STARTS:
            out.append(self.candidate("specimen_friction", "f", (lin("specimen_friction_n", 0.01 * fmax, 0.0, 1e4),
                                                                 logf("specimen_friction_velocity_m_s", 1e-3, 1e2, step=0.1)),
                                      "sign(v)", starts=(float(np.log(factor)),)))
        for share in PRESLIDING_STARTS:
            out.append(self.candidate("presliding_friction", "f",
                                      (lin("specimen_presliding_friction_n", 0.01 * fmax, 0.0, 1e4),
                                       logf("specimen_presliding_m", 1e-3, 1e2, step=0.1)),
                                      "sign(v)", starts=(float(np.log(share / PRESLIDING_SHARE)),)))
        out += self.play_with_friction()
        k = max(self.nominal["specimen_stiffness_n_m"], fmax / self.y_span)
        # the closure position's step a tenth of its unit: the kink is sharp (its corner is 20 um)
        # and a coarse difference stalls the fit a few percent short of it
        out += [dataclasses.replace(c, frees=(c.frees[0], dataclasses.replace(c.frees[1], step=0.1)))
                for c in self.closure_candidates(self.rec.columns["y"], self.nominal["specimen_zero_force_position_m"], k,
                                                 self.rec.columns["f"])]
        return out


    def candidate(self, effect: str, channel: str | None, frees: tuple[Free, ...], signature: str, **kw: Any) -> Candidate:
        """A candidate of the vocabulary, under the id it is reported by (`REPORTED_AS`)."""
        c = super().candidate(effect, channel, frees, signature, **kw)
        return dataclasses.replace(c, effect=REPORTED_AS[effect]) if effect in REPORTED_AS else c

    def play_with_friction(self) -> list[Candidate]:
        """A play with a friction behind it (a dry friction damper with play, guides with a loose
        grip): after each reversal the friction falls away, the displacement travels the gap at no
        friction force and the friction builds up the other way. With a gap that is large against
        the travel neither pays off alone — the friction alone misses where the force rests, the
        play alone has nothing to hold during the gap, and the base model's damper soaks up the
        rest — so they are refitted together as well (composites, beside the single effects) and
        found as two findings. The gap is scanned (it is not smooth to find); the friction starts
        at half the step between the force's plateaus while the displacement moves fast one way
        and the other (the damper and the spring's share of it vanish where the motion is
        symmetric), its build-up as the single candidates' is."""
        y, f = _filled(self.rec.columns["y"]), _filled(self.rec.columns["f"])
        v = np.gradient(smooth(y, max(1, int(round(VELOCITY_WINDOW_S / self.dt)))), self.dt)
        up, down = v > 0.5 * self.v_max, v < -0.5 * self.v_max
        level = 0.5 * float(np.median(f[up]) - np.median(f[down])) if up.any() and down.any() else 0.0
        level = float(np.clip(level, 0.05 * self.f_max, self.f_max))
        unit = 0.01 * self.f_max
        gap = lin("load_train_gap_m", 0.01 * self.y_span, 0.0, 50.0)
        play = self.candidate("load_train_backlash", "f", (gap,), "sign(v)")
        friction = self.candidate("specimen_friction", "f", (lin("specimen_friction_n", unit, 0.0, 1e4),
                                                             logf("specimen_friction_velocity_m_s", 1e-3, 1e2, step=0.1)), "sign(v)")
        presliding = self.candidate("presliding_friction", "f", (lin("specimen_presliding_friction_n", unit, 0.0, 1e4),
                                                                 logf("specimen_presliding_m", 1e-3, 1e2, step=0.1)), "sign(v)")
        frictions = [(friction, (level / unit, float(np.log(factor)))) for factor in COMPOSITE_VELOCITY_STARTS]
        frictions += [(presliding, (level / unit, float(np.log(share / PRESLIDING_SHARE)))) for share in COMPOSITE_PRESLIDING_STARTS]
        return [Candidate(f"{play.effect}+{fr.effect}", "f", play.frees + fr.frees, "sign(v)", starts=starts,
                          fields=play.fields + fr.fields, parts=(play, fr)) for fr, starts in frictions]


def _filled(x: np.ndarray) -> np.ndarray:
    """A column with dropped samples (NaN) bridged linearly (for start values and scales)."""
    x = np.asarray(x, dtype=float)
    ok = np.isfinite(x)
    if ok.all():
        return x
    return np.interp(np.arange(len(x)), np.flatnonzero(ok), x[ok])
