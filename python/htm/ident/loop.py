"""The machine-loop model family: `machine_position` records (a machine that closes its own
displacement loop: `y_ref`, `y`, optional `f`, no `u`), modelled by the core's displacement-loop
model (`crates/htm-core/src/outer_loop.rs`, `LoopParams`) driven by the recorded command.

Its base model is the closed loop itself (gain, offset, bandwidth, delay, velocity
feed-forward) and, where the load cell is read, the specimen (spring, viscous damping) whose
force the model predicts (and which loads the loop). Its
effects (`docs/effects.md`) are the loop's own imperfections and the specimen's: the ids of
EFFECTS.md where one fits (`valve_dynamics`, `sensor_offset` on f, `specimen_nonlinearity`),
project ids for the rest (`direction_asymmetry`, `actuator_friction`, `backlash`,
`load_dependent_velocity`, `loop_compliance`, `command_quantisation`, `specimen_friction`).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from htm.core import LoopParams, loop_simulate
from htm.errors import HtmError, InputError, RecordError
from htm.ident.family import Family
from htm.ident.features import smooth
from htm.ident.model import Candidate, Free, lin, logf
from htm.ident.records import Record
from htm.ident.settings import DEFAULT, SearchSettings

FAMILY = "machine_position"
# What the loop model predicts (DATA_FORMAT channels).
CHANNELS = ("y", "v", "f")

# Effect id -> {effect parameter name: LoopParams key}; sensor_offset is on f only.
EFFECT_FIELDS: dict[str, dict[str, str]] = {
    "valve_dynamics": {"tau_s": "valve_tau_s"},
    "direction_asymmetry": {"asymmetry": "asymmetry"},
    "actuator_friction": {"velocity_loss_m_s": "velocity_loss_m_s"},
    "backlash": {"half_width_m": "backlash_m"},
    "load_dependent_velocity": {"stall_force_n": "load_stall_force_n"},
    "loop_compliance": {"compliance_m_per_n": "compliance_m_per_n"},
    "command_quantisation": {"step_m": "command_step_m", "update_period_s": "command_period_s"},
    "sensor_offset": {"offset_n": "sensor_offset_f"},
    "specimen_friction": {"friction_n": "specimen_friction_n", "velocity_m_s": "specimen_friction_velocity_m_s"},
    "specimen_nonlinearity": {"closure_stiffness_n_m": "specimen_closure_stiffness_n_m",
                              "closure_offset_m": "specimen_closure_offset_m"},
}
# The channel a finding names (sensor and specimen effects show in the load cell).
EFFECT_CHANNEL = {"sensor_offset": "f", "specimen_friction": "f", "specimen_nonlinearity": "f"}
# Update periods of the command tried (in samples): a controller's or a command generator's
# cycle is one of these multiples of a record's sample period (1: quantisation alone).
COMMAND_PERIODS = (1, 2, 4, 5, 8, 10, 16, 20, 25, 50)
# Quanta of the command tried [m]: the 1-2-5 series. The model's grid is aligned on zero, and
# a quantum is found only where the staircase it makes is timed exactly right (a quantum off by
# a fraction of a percent puts every step elsewhere over a long travel), so it is a discrete
# choice, not a least-squares parameter.
COMMAND_QUANTA = tuple(m * 10.0**e for e in range(-7, -2) for m in (1.0, 2.0, 5.0))
# Loop bandwidths [Hz] and feed-forward shares the start of the fit is chosen among.
START_BANDWIDTHS = (0.3, 0.7, 1.5, 3.0, 6.0, 12.0, 25.0, 50.0)
START_FEEDFORWARD = (0.0, 1.0)


def params_from_meta(meta: dict[str, Any]) -> LoopParams:
    """The loop model's nominal parameters from a record's metadata: every effect off, the
    declared loop bandwidth (`controller.bandwidth_hz`) if any, the declared specimen."""
    p = LoopParams()
    ctrl = meta.get("controller") or {}
    bw = ctrl.get("bandwidth_hz")
    if bw is not None:
        if isinstance(bw, bool) or not isinstance(bw, (int, float)) or not (0 < bw < 1e4):
            raise RecordError(f"metadata `controller.bandwidth_hz` = {bw!r} must be a number in (0, 10000) Hz")
        p["bandwidth_hz"] = float(bw)
    spec = meta.get("specimen")
    if isinstance(spec, dict):
        for key, field in (("stiffness_n_m", "specimen_stiffness_n_m"), ("zero_force_position_m", "specimen_zero_force_position_m")):
            v = spec.get(key)
            if v is not None:
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                    raise RecordError(f"metadata `specimen.{key}` = {v!r} must be a finite number")
                p[field] = float(v)
    return p


def effect_fields(effect: str) -> dict[str, str]:
    """{effect parameter name: LoopParams key} of one of the loop family's effects."""
    if effect not in EFFECT_FIELDS:
        raise InputError(f"unknown displacement-loop effect `{effect}`; known: {', '.join(EFFECT_FIELDS)}")
    return dict(EFFECT_FIELDS[effect])


def simulate(plist: list[LoopParams], rec: Record, *, threads: int = 0) -> list[dict[str, np.ndarray]]:
    """Each parameter set's predicted readings (`y`, `v`, `f`) over `rec`, driven by its `y_ref`
    and loaded by its recorded force `f` if any (else by the modelled specimen's); one batch in
    Rust on all cores (`threads` = 0) with the GIL released. A failed simulation gives NaN arrays."""
    t = np.asarray(rec.columns["t"], dtype=float)
    if len(t) < 2:
        raise RecordError(f"record `{rec.name}` has {len(t)} samples; at least 2 are needed to simulate")
    if "y_ref" not in rec.columns:
        raise RecordError(f"record `{rec.name}` has no position command `y_ref` to drive the machine's loop with")
    dt = float(np.median(np.diff(t)))
    load = np.ascontiguousarray(rec.columns["f"], dtype=float) if "f" in rec.columns else None
    out = loop_simulate(list(plist), dt, np.ascontiguousarray(rec.columns["y_ref"], dtype=float), load=load, threads=threads)
    # a set the solver could not carry comes back as its error: NaN readings, a failed set to the fit
    return [{c: np.full(len(t), np.nan) for c in CHANNELS} if isinstance(r, HtmError) else {c: r[c] for c in CHANNELS}
            for r in out]


class LoopFamily(Family):
    """The machine's closed displacement loop for one `machine_position` record: nominal
    parameters (started where a coarse scan of the record puts them), free parameters,
    candidate effects; the model is driven by the recorded command (no loop to re-close)."""

    name = FAMILY
    vocabulary = tuple(EFFECT_FIELDS)
    closed_loop = False  # the model runs on the recorded command; sensor noise does not enter it
    has_command = False  # no valve command: nothing to fit on instead of the model's own run
    whole_record = True  # a simulation costs milliseconds: fit every block of the record

    def __init__(self, rec: Record, channels: list[str], settings: SearchSettings = DEFAULT) -> None:
        self.settings = settings
        other = [c for c in channels if c not in CHANNELS]
        if other:
            raise RecordError(f"record `{rec.name}` declares a machine that closes its own loop, whose model predicts "
                              f"{', '.join(CHANNELS)}; it cannot model column(s) {', '.join(other)}: drop them or "
                              "record the valve level (with `u`)")
        self.rec = rec
        self.channels = channels
        self.opts: dict[str, Any] = {}
        self.rig_keys: set[str] = set()
        t = np.asarray(rec.columns["t"], dtype=float)
        self.dt = float(np.median(np.diff(t)))
        y = filled(rec.columns["y"])
        r = filled(rec.columns["y_ref"])
        self.force = "f" in channels
        v = np.gradient(smooth(y, 5), self.dt)
        self.v_max = max(float(np.percentile(np.abs(v), 99)), 1e-6)
        self.y_span = max(float(np.percentile(y, 99) - np.percentile(y, 1)), 1e-6)
        nominal = params_from_meta(rec.meta)
        nominal["offset_m"] = float(np.median(y) - np.median(r))
        if self.force:
            f = filled(rec.columns["f"])
            self.f_max = max(float(np.percentile(np.abs(f - np.median(f)), 99)), 1e-3)
            spec = rec.meta.get("specimen") if isinstance(rec.meta.get("specimen"), dict) else {}
            if spec.get("zero_force_position_m") is None:
                # DATA_FORMAT's default is mid-stroke; without a stroke, the record's middle position
                stroke = (rec.meta.get("rig") or {}).get("stroke_m")
                nominal["specimen_zero_force_position_m"] = (0.5 * float(stroke) if isinstance(stroke, (int, float)) and stroke > 0
                                                             else float(np.median(y)))
            nominal["specimen_friction_velocity_m_s"] = 0.02 * self.v_max
            _start_specimen(nominal, y, v, f, declared=spec.get("stiffness_n_m") is not None)
        self.nominal = nominal
        self.base_frees: list[Free] = self._base_frees()
        self._start_loop()

    def _base_frees(self) -> list[Free]:
        sy = max(self.y_span * 1e-3, 1e-7)
        frees = [
            lin("offset_m", sy, -1e5, 1e5),
            logf("gain", 0.5, 2.0, step=0.005),
            logf("bandwidth_hz", 0.02, 50.0, step=0.02),
            lin("delay_s", self.dt, 0.0, 300.0, step=0.5),
            lin("feedforward", 0.05, -20.0, 40.0, step=0.5),
        ]
        if self.force:
            k_unit = self.f_max / self.y_span * 0.01
            frees += [
                lin("specimen_stiffness_n_m", k_unit, 0.0, 1e6, step=1.0),
                lin("specimen_damping_n_s_m", self.f_max / self.v_max * 0.01, 0.0, 1e6, step=1.0),
            ]
        return frees

    def _start_loop(self) -> None:
        """Start the fit at the best of a few loop bandwidths and feed-forward shares (one batch
        of simulations): a far start lands a least-squares fit of a delay and a bandwidth in
        the wrong valley."""
        trials = []
        for bw in START_BANDWIDTHS:
            for ff in START_FEEDFORWARD:
                p = self.nominal.copy()
                p["bandwidth_hz"], p["feedforward"] = bw, ff
                trials.append(p)
        preds = self.simulate(trials, self.rec)
        y = np.asarray(self.rec.columns["y"], dtype=float)
        ok = np.isfinite(y)
        costs = [float(np.sum((pr["y"][ok] - y[ok]) ** 2)) if np.all(np.isfinite(pr["y"][ok])) else np.inf for pr in preds]
        best = trials[int(np.argmin(costs))]
        self.nominal["bandwidth_hz"] = best["bandwidth_hz"]
        self.nominal["feedforward"] = best["feedforward"]

    @staticmethod
    def effect_fields(effect: str, channel: str | None = None) -> dict[str, str]:
        return effect_fields(effect)

    @staticmethod
    def simulate(plist: list[LoopParams], rec: Record, **opts: Any) -> list[dict[str, np.ndarray]]:
        if opts:
            raise RecordError(f"the displacement-loop model takes no simulation options (got {', '.join(opts)})")
        return simulate(plist, rec)

    def candidates(self, scales: dict[str, float], rate_hz: float) -> list[Candidate]:
        """The loop's effects, and the specimen's and load cell's where `f` is recorded."""
        dt = 1.0 / rate_hz
        sy = scales["y"]

        def cand(effect: str, frees: tuple[Free, ...], signature: str, **kw: Any) -> Candidate:
            return self.candidate(effect, EFFECT_CHANNEL.get(effect), frees, signature, **kw)

        out = [
            cand("valve_dynamics", (lin("valve_tau_s", 1e-3, 0.0, 300.0, step=2.0),), "v"),
            cand("direction_asymmetry", (lin("asymmetry", 0.01, -90.0, 90.0),), "sign(v)"),
            cand("actuator_friction", (lin("velocity_loss_m_s", 0.005 * self.v_max, 0.0, 1e4),), "sign(v)"),
            cand("backlash", (lin("backlash_m", 0.2 * sy, 0.0, 1e5),), "sign(v)"),
        ]
        # held and quantised: every period with every quantum that a record can show (above the
        # position noise, below a tenth of the travel), each a switch without free parameters
        quanta = [0.0] + [q for q in COMMAND_QUANTA if 0.05 * sy <= q <= 0.1 * self.y_span]
        for n in COMMAND_PERIODS:
            for q in quanta:
                if n > 1 or q > 0:
                    out.append(cand("command_quantisation", (), "v",
                                    switch=(("command_period_s", n * dt), ("command_step_m", q))))
        if self.force:
            fmax = self.f_max
            out += [
                cand("load_dependent_velocity", (lin("load_per_stall_n", 0.01 / fmax, 0.0, 95.0),), "y"),
                # a finding, not a base parameter: on a record whose force follows its velocity
                # (a damper) a compliance trades with the delay and would not carry to other loads
                cand("loop_compliance", (lin("compliance_m_per_n", sy / fmax, 0.0, 1e5, step=1.0),), "y"),
                self.sensor_candidate("sensor_offset", "f", scales["f"], bound=1e4),
                cand("specimen_friction", (lin("specimen_friction_n", 0.01 * fmax, 0.0, 1e4),
                                           logf("specimen_friction_velocity_m_s", 0.02, 50.0, step=0.1)), "sign(v)",
                     starts=(0.0,)),
            ]
            k = max(self.nominal["specimen_stiffness_n_m"], fmax / self.y_span)
            out += self.closure_candidates(self.rec.columns["y"], self.nominal["specimen_zero_force_position_m"], k,
                                           self.rec.columns["f"])
        return out


def filled(x: np.ndarray) -> np.ndarray:
    """A column with dropped samples (NaN) bridged linearly (for start values and scales)."""
    x = np.asarray(x, dtype=float)
    ok = np.isfinite(x)
    if ok.all():
        return x
    return np.interp(np.arange(len(x)), np.flatnonzero(ok), x[ok])


def _start_specimen(p: LoopParams, y: np.ndarray, v: np.ndarray, f: np.ndarray, *, declared: bool) -> None:
    """Start the specimen at the least-squares spring and damper through the measured force
    (a constant takes up the load cell's offset, which the search judges), unless declared."""
    a = np.column_stack([y - p["specimen_zero_force_position_m"], v, np.ones_like(y)])
    coef, *_ = np.linalg.lstsq(a, f, rcond=None)
    if not declared:
        p["specimen_stiffness_n_m"] = float(max(coef[0], 0.0))
    p["specimen_damping_n_s_m"] = float(max(coef[1], 0.0))
