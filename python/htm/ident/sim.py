"""Re-simulation of records for model fitting: the base model from a record's metadata, the
EFFECTS.md ids as parameter fields, and `predict` (the Rust closed/open loop, batched on all cores).

Conventions (agreed with `diagnose`):

* `params_from_meta` gives the base model of EFFECTS.md: every effect off (no null bias, static
  valve, no dead band/play, stiff supply, no leakage, symmetric pressure-independent friction,
  no entrained air, linear specimen, ideal sensors), a linear spool characteristic and the
  orifice (sqrt dp) flow law.
* `load_pressure_feedback`: the base model already has orifice flow, so this effect only exists
  for a rig whose metadata declares a linear, pressure-compensated valve
  (`rig.valve_flow_law = "linear"`): its base model then starts with flow proportional to the
  spool (`valve_linear_flow = 1`) and the effect is the switch to the sqrt(p_s - p_L) law
  (`valve_linear_flow = 0`). It has no parameters.
* `specimen_nonlinearity` is a bilinear (crack-closure) spring: `closure_stiffness_n_m` added
  below `zero-force position + closure_offset_m`, with no force at the zero-force position on
  either branch (a closure above it, at a positive force, puts that position on the stiffer one).
* The sensor effects act in the loop: in closed loop the controller sees the simulated readings.
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from htm.core import CHANNELS, Params, replay
from htm.errors import HtmError, InputError, RecordError, SolverError
from htm.ident.dsp import running_max, running_median, running_min
from htm.ident.records import Record
from htm.ident.family import SENSOR_EFFECTS

# Open-loop predictions restart from the measured state this often [s].
DEFAULT_HORIZON_S = 0.5
# Closed-loop predictions first hold the first reference this long [s] so the model settles.
PREROLL_S = 1.0
# Integrator tolerance of re-simulation: readings stay within ~1e-4 relative of rtol 1e-6
# (far below sensor noise) at a fifth of the cost; see benchmarks/replay_speed.py.
RTOL = 1e-4

# A measured supply whose level moves by more than this share was switched between pressure
# levels (a power unit's low and high pressure): the model's supply set-point follows it.
SUPPLY_SWITCH = 0.05
# Window of the supply's upper envelope [s]: longer than a motion's sag dip, so that the sag
# stays for the model to explain (it is zero whenever the valve closes, at every reversal).
SUPPLY_WINDOW_S = 2.5

_OFFSET_NAME = {"y": "offset_m", "v": "offset_m_s", "p_a": "offset_pa", "p_b": "offset_pa", "p_s": "offset_pa", "f": "offset_n"}

# EFFECTS.md id -> {effect parameter name: Params field}; sensor effects are per channel.
EFFECT_FIELDS: dict[str, dict[str, str]] = {
    "valve_null_bias": {"bias_v": "valve_null_bias_v"},
    "valve_dynamics": {"tau_s": "valve_tau_s"},
    "valve_deadband": {"half_width_v": "valve_deadband_half_width_v"},
    "valve_hysteresis": {"half_width_v": "valve_hysteresis_half_width_v"},
    "supply_pressure_sag": {"resistance_pa_s_per_m3": "supply_resistance_pa_s_per_m3"},
    "internal_leakage": {"coeff_m3_per_s_pa": "leakage_coeff_m3_per_s_pa"},
    "friction_asymmetry": {"coulomb_pos_n": "friction_coulomb_pos_n", "coulomb_neg_n": "friction_coulomb_neg_n"},
    "pressure_dependent_friction": {"coeff_n_per_pa": "friction_pressure_coeff_n_per_pa"},
    "entrained_air": {"air_fraction": "air_fraction"},
    "load_pressure_feedback": {},
    "specimen_nonlinearity": {"closure_stiffness_n_m": "specimen_closure_stiffness_n_m",
                              "closure_offset_m": "specimen_closure_offset_m"},
}
EFFECT_IDS = SENSOR_EFFECTS + tuple(EFFECT_FIELDS)
# Channel named in a finding for non-sensor effects (EFFECTS.md table).
EFFECT_CHANNEL = {"specimen_nonlinearity": "f"}


def effect_fields(effect: str, channel: str | None = None) -> dict[str, str]:
    """{effect parameter name (EFFECTS.md): Params field} of one effect (sensor ones need `channel`)."""
    if effect in SENSOR_EFFECTS:
        if channel not in CHANNELS:
            raise InputError(f"effect `{effect}` needs a channel among {', '.join(CHANNELS)}, got {channel!r}")
        return {"sensor_offset": {_OFFSET_NAME[channel]: f"sensor_offset_{channel}"},
                "sensor_gain": {"gain": f"sensor_gain_{channel}"},
                "sensor_delay": {"delay_s": f"sensor_delay_{channel}_s"}}[effect]
    if effect not in EFFECT_FIELDS:
        raise InputError(f"unknown effect `{effect}`; known: {', '.join(EFFECT_IDS)}")
    return dict(EFFECT_FIELDS[effect])


def with_effect(params: Params, effect: str, values: Mapping[str, float], channel: str | None = None) -> Params:
    """A copy of `params` with `effect` switched on at `values` (EFFECTS.md parameter names, SI)."""
    p = params.copy()
    fields = effect_fields(effect, channel)
    if effect == "load_pressure_feedback":
        p["valve_linear_flow"] = 0.0
    for name, value in values.items():
        if name not in fields:
            raise InputError(f"effect `{effect}` has no parameter `{name}`; it has {', '.join(fields) or 'none'}")
        p[fields[name]] = float(value)
    p.validate()
    return p


def effect_values(params: Params, effect: str, channel: str | None = None) -> dict[str, float]:
    """The effect's parameters (EFFECTS.md names) as set in `params`."""
    return {name: params[field] for name, field in effect_fields(effect, channel).items()}


def params_from_meta(meta: Mapping[str, Any]) -> Params:
    """The base model of EFFECTS.md from a record's metadata (`rig`, `specimen`, `controller`), SI.

    Nominal rig values come from `rig`; friction, underlap and the valve's transition drop start
    at the thesis rig's values (the metadata has none; they are identified). Optional `rig` keys
    beyond DATA_FORMAT: `valve_polarity` (else inferred from the sign of a declared position
    controller's kp — a stable loop has kp*polarity > 0 — else -1 as on the thesis rig),
    `valve_underlap_v`, `valve_lap_smoothing_v` (the width over which a metering edge opens),
    `valve_flow_law` ("orifice" or "linear"), `friction_*` fields (`friction_sign_shape`: the form
    of friction's smoothed sign, 0 the thesis's, 1 tanh). A stated form is the base model's form.
    """
    rig = meta.get("rig")
    if not isinstance(rig, Mapping):
        raise RecordError("metadata has no `rig` block (DATA_FORMAT.md); cannot build the base model")
    p = Params("base")
    off = {"valve_null_bias_v": 0.0, "valve_tau_s": 0.0, "valve_deadband_half_width_v": 0.0,
           "valve_hysteresis_half_width_v": 0.0, "supply_resistance_pa_s_per_m3": 0.0,
           "leakage_coeff_m3_per_s_pa": 0.0, "friction_pressure_coeff_n_per_pa": 0.0, "air_fraction": 0.0,
           "eggerth_k1_per_pa": 0.0, "eggerth_k2_per_pa": 0.0, "eggerth_lambda": 0.0, "friction_bump_n": 0.0,
           "specimen_closure_stiffness_n_m": 0.0, "specimen_closure_offset_m": 0.0, "valve_linear_flow": 0.0,
           "valve_natural_hz": 0.0, "bulk_modulus_slope": 0.0}
    for c in CHANNELS:
        off |= {f"sensor_offset_{c}": 0.0, f"sensor_gain_{c}": 1.0, f"sensor_delay_{c}_s": 0.0,
                f"sensor_lowpass_{c}_hz": declared_lowpass(meta, c)}
    for k, v in off.items():
        p[k] = v
    p.valve_map = ([], [])
    numeric = ("area_a_m2", "area_b_m2", "stroke_m", "supply_pressure_pa", "tank_pressure_pa", "valve_rated_flow_m3_s",
               "valve_rated_dp_pa", "valve_max_command_v", "moving_mass_kg", "bulk_modulus_pa", "dead_volume_a_m3",
               "dead_volume_b_m3", "oil_density_kg_m3", "valve_underlap_v", "valve_polarity",
               "friction_viscous_n_s_m", "friction_coulomb_pos_n", "friction_coulomb_neg_n", "friction_static_n",
               "friction_stribeck_m_s", "friction_smoothing_m_s", "friction_sign_shape", "valve_lap_smoothing_v")
    for k in numeric:
        if k in rig and rig[k] is not None:
            p[k] = _number(rig[k], f"rig.{k}")
    if "friction_coulomb_n" in rig:
        p["friction_coulomb_pos_n"] = p["friction_coulomb_neg_n"] = _number(rig["friction_coulomb_n"], "rig.friction_coulomb_n")
    orient = rig.get("orientation", "vertical")
    if orient not in ("vertical", "horizontal"):
        raise RecordError(f"rig.orientation = {orient!r}: use \"vertical\" or \"horizontal\"")
    p["gravity_m_s2"] = 9.80665 if orient == "vertical" else 0.0
    law = rig.get("valve_flow_law", "orifice")
    if law not in ("orifice", "linear"):
        raise RecordError(f"rig.valve_flow_law = {law!r}: use \"orifice\" or \"linear\"")
    p["valve_linear_flow"] = 1.0 if law == "linear" else 0.0
    if "valve_polarity" not in rig:
        # a stable declared loop has kp*polarity > 0 (a positive spool drives the piston up)
        ctrl = meta.get("controller") or {}
        gain = ctrl.get("kp_v_per_m", ctrl.get("kp_v_per_n"))
        p["valve_polarity"] = 1.0 if isinstance(gain, (int, float)) and gain > 0 else -1.0
    spec = meta.get("specimen")
    if spec:
        if not isinstance(spec, Mapping) or "stiffness_n_m" not in spec:
            raise RecordError("metadata `specimen` must be null or hold at least `stiffness_n_m`")
        p["specimen_stiffness_n_m"] = _number(spec["stiffness_n_m"], "specimen.stiffness_n_m")
        p["specimen_zero_force_position_m"] = _number(spec.get("zero_force_position_m", 0.5 * p["stroke_m"]),
                                                      "specimen.zero_force_position_m")
    else:  # no specimen: its (unused) zero-force position mid-stroke, inside any declared stroke
        p["specimen_stiffness_n_m"] = 0.0
        p["specimen_zero_force_position_m"] = 0.5 * p["stroke_m"]
    try:
        p.validate()
    except Exception as e:
        raise RecordError(f"metadata gives an invalid rig: {e}") from None
    return p


def declared_lowpass(meta: Mapping[str, Any], channel: str) -> float:
    """The cut-off [Hz] of a channel's declared anti-alias filter (`sensors.<ch>.lowpass_hz`), 0 if none."""
    s = (meta.get("sensors") or {}).get(channel) or {}
    v = s.get("lowpass_hz") if isinstance(s, Mapping) else None
    if v is None:
        return 0.0
    return _number(v, f"sensors.{channel}.lowpass_hz") if v else 0.0


def _number(x: Any, name: str) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not np.isfinite(x):
        raise RecordError(f"metadata `{name}` = {x!r} must be a finite number")
    return float(x)


def closed_loop(rec: Record) -> bool:
    """True when the record declares a controller, so predictions re-simulate the closed loop."""
    return bool(rec.meta.get("controller"))


def supply_schedule(rec: Record) -> np.ndarray | None:
    """The supply read at rest over time (the `supply` of `replay`), as a factor of the metadata's
    `supply_pressure_pa` (else of its median), from the measured `p_s`: its upper envelope, a
    closing (rolling max, then rolling min over `SUPPLY_WINDOW_S`) that removes the sag dips of
    motions and keeps level switches where they happen. None when there is no `p_s` or its level stays within
    `SUPPLY_SWITCH` (a constant supply: the model's own)."""
    if "p_s" not in rec.columns:
        return None
    ps = np.asarray(rec.columns["p_s"], dtype=float)
    ok = np.isfinite(ps)
    if ok.sum() < 10:
        return None
    ps = np.interp(np.arange(len(ps)), np.flatnonzero(ok), ps[ok])  # dropped samples bridged
    t = np.asarray(rec.columns["t"], dtype=float)
    rate = 1.0 / float(np.median(np.diff(t)))
    # The max of raw noise is biased high: a median first (it keeps a switch's edges where they
    # are, though it shaves the narrow un-sagged tops of fast motions by a fraction of a percent).
    ps = running_median(ps, max(1, int(round(0.1 * rate)) | 1))
    w = max(3, int(round(SUPPLY_WINDOW_S * rate)) | 1)
    # Padded a window long with the top of each end's last half window: a sag dip at an end is
    # not taken for a new level (a switch within half a window of an end is not followed).
    q = max(1, w // 2)
    padded = np.concatenate([np.full(w, ps[:q].max()), ps, np.full(w, ps[-q:].max())])
    env = running_min(running_max(padded, w), w)[w:-w]
    mid = float(np.median(env))
    if mid <= 0 or (np.max(env) - np.min(env)) < SUPPLY_SWITCH * mid:
        return None
    ref = (rec.meta.get("rig") or {}).get("supply_pressure_pa")
    ref = float(ref) if isinstance(ref, (int, float)) and ref > 0 else mid
    return np.clip(env / ref, 0.01, 10.0)


def _setup(rec: Record, command: bool = False) -> dict[str, Any]:
    t = np.asarray(rec.columns["t"], dtype=float)
    if len(t) < 2:
        raise RecordError(f"record `{rec.name}` has {len(t)} samples; at least 2 are needed to simulate")
    dt = float(np.median(np.diff(t)))
    measured = {c: np.ascontiguousarray(rec.columns[c], dtype=float) for c in CHANNELS if c in rec.columns}
    args: dict[str, Any] = {"dt": dt, "u": np.ascontiguousarray(rec.columns["u"], dtype=float), "measured": measured}
    ctrl = None if command else rec.meta.get("controller")
    if ctrl:
        kind = ctrl.get("type")
        col = {"position_pff": "y_ref", "force_p": "f_ref"}.get(kind)
        if col is None:
            raise RecordError(f"record `{rec.name}`: controller type {kind!r} cannot be re-simulated; use position_pff or force_p")
        if col not in rec.columns:
            raise RecordError(f"record `{rec.name}` declares a {kind} controller but has no `{col}` column to re-simulate it from")
        args["controller"] = dict(ctrl)
        args["reference"] = np.ascontiguousarray(rec.columns[col], dtype=float)
    return args


def predict(params: Params | list[Params], rec: Record, *, horizon_s: float | None = None, threads: int = 0,
            rtol: float = RTOL, supply: np.ndarray | None | str = "auto", command: bool = False,
            noise: Mapping[str, np.ndarray] | None = None, quantum: Mapping[str, float] | None = None,
            active: np.ndarray | None = None, lockstep: bool = False,
            with_command: bool = False) -> dict[str, np.ndarray] | list[dict[str, np.ndarray]]:
    """The record's channels (those of y, v, p_a, p_b, p_s, f it has) as the model's sensors would
    read them, noise-free (unless `noise` is given), SI units.

    With a declared controller: a free-run closed-loop simulation from the reference (after a
    `PREROLL_S` hold), the controller fed by the simulated readings. Otherwise the recorded `u`
    played open loop, restarted from the measured state every `horizon_s` s (default
    `DEFAULT_HORIZON_S`). A supply switched between levels (measured `p_s`) is followed
    (`supply_schedule`) unless `supply` gives the schedule (same form; None = constant).

    `command`: play the recorded `u` open loop (with restarts) even when a controller is declared
    (a prediction error that stays well posed when the closed loop hunts on its sensor noise).
    `noise`/`quantum` per channel: added to the readings inside the loop (a synthetic record of
    the model; the returned readings include them). `active` (bool per sample; open loop or
    `command` only): simulate just those samples, the others read NaN. `lockstep` (open loop or
    `command`): the sets after the first differ from it slightly (a fit's finite-difference
    neighbours) and take its integrator step sizes: their differences to it are free of
    step-size noise (and they spend no rejected steps). `with_command`: also return the command `u`
    applied (the model's own controller's in closed loop).

    A list of Params runs in parallel in Rust with the GIL released (`threads` = 0: all cores)
    and a failed simulation gives NaN arrays; a single Params raises SolverError instead.
    """
    single = isinstance(params, Params)
    plist = [params] if single else list(params)
    args = _setup(rec, command)
    if noise is not None:
        args["noise"] = {c: np.ascontiguousarray(z, dtype=float) for c, z in noise.items()}
        args["quantum"] = dict(quantum or {})
    if isinstance(supply, str):  # "auto"
        supply = supply_schedule(rec)
    if supply is not None:
        args["supply"] = np.ascontiguousarray(supply, dtype=float)
    if active is not None and "controller" not in args:
        args["active"] = np.ascontiguousarray(active, dtype=bool)
    out = replay(plist, horizon_s=DEFAULT_HORIZON_S if horizon_s is None else float(horizon_s),
                 preroll_s=PREROLL_S, rtol=rtol, threads=threads, lockstep=lockstep and "controller" not in args, **args)
    keep = list(args["measured"]) + (["u"] if with_command else [])
    if single and isinstance(out[0], HtmError):
        raise SolverError(f"record `{rec.name}`: {out[0]}")
    # a set the solver could not carry comes back as its error: NaN readings, which the fit scores
    # as a failed set
    n = len(args["u"])
    res = [{c: np.full(n, np.nan) for c in keep} if isinstance(r, HtmError) else {c: r[c] for c in keep} for r in out]
    return res[0] if single else res
