"""The proving ground of the machine-loop family: `machine_position` records made by the
valve-level plant inside a position loop (the core's `replay` with a P + feed-forward
controller), with `u`, velocity and pressures dropped, and each loop effect injected at the
level where it physically lives (docs/effects.md states how each effect's parameters follow
from the injected physics):

* `valve_dynamics`: the valve's first-order spool lag, `tau_s` = `valve_tau_s`.
* `direction_asymmetry`: a single-rod cylinder on an orifice-law valve. With equal metering
  edges, no load, the steady speeds out and in are in the ratio sqrt(A_a/A_b), so
  `asymmetry` = (r − 1)/(r + 1), r = sqrt(A_a/A_b).
* `actuator_friction`: Coulomb friction F_c of the actuator's seals with internal leakage c_L
  behind a pressure-compensated (linear-flow) valve: holding F_c takes the load pressure F_c/A,
  which leaks c_L·F_c/A past the piston, so `velocity_loss_m_s` = c_L·F_c/A².
* `backlash`: the valve's play h [V] before the spool; the loop's valve command is u/kp, so
  `half_width_m` = h/|kp|.
* `load_dependent_velocity`: a specimen on an orifice-law valve: the velocity falls as
  sqrt(1 − F/(A·(p_s − p_T))), so `stall_force_n` = A·(p_s − p_T).
* `command_quantisation`: the reference quantised to `step_m` and updated every
  `update_period_s` before the controller; the record holds the smooth reference. Its rig's
  controller has no feed-forward (with one, every update's jump would reach the valve within a
  sample) and its actuator a short, well-damped oil column (`STIFF_ACTUATOR`): each update
  steps the valve command, and the thesis rig's lightly damped 200 Hz oil column would ring
  at every step, a resonance far above the loop model's reach.
* `sensor_offset` on f (`offset_n`) and `specimen_nonlinearity` (crack closure): the plant's own.

The rig is the thesis rig laid horizontal, its valve critically lapped and pressure-compensated
(linear flow) unless an effect needs the orifice law: the base loop model describes it exactly.
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from htm.core import Params, replay
from htm.errors import HtmError, InputError
from htm.ident.experiments import POSITION_LAW
from htm.ident.records import FORMAT, MACHINE_POSITION, Record
from htm.ident.sim import PREROLL_S, params_from_meta
from htm.params import rig_metadata

KP_V_PER_M, KFF_V_PER_M_S = -150.0, -14.3
CONTROLLER = {"type": "position_pff", "kp_v_per_m": KP_V_PER_M, "kff_v_per_m_s": KFF_V_PER_M_S, "u_max_v": 10.0,
              "law": POSITION_LAW}
CENTRE_M = 0.1
SPECIMEN_STIFFNESS_N_M = 2.0e6
# Internal leakage that turns actuator friction into a loss of velocity [m^3/(s Pa)].
LEAKAGE = 2.0e-11
# The actuator's own Coulomb friction when none is injected [N] (hydrostatic bearings: a
# testing machine's actuator barely rubs; the thesis rig's 800 N of seal friction would bend
# its oil column by ~20 um at every reversal, an effect of the valve-level model).
LOW_FRICTION_N = 30.0
# Corners of the command are rounded over this time [s] (a function generator's ramps): a
# velocity step would ring the oil column at its ~200 Hz resonance.
CORNER_S = 0.04
# Sensors: white noise and quantization (SI), inside the loop.
NOISE_STD = {"y": 2e-6, "f": 20.0}
QUANTUM = {"y": 1e-6, "f": 2.0}
# Rig parameters drawn around the nominal rig (they move the loop's gain and feed-forward).
SPREAD_FIELDS = ("moving_mass_kg", "friction_viscous_n_s_m", "valve_rated_flow_m3_s", "bulk_modulus_pa",
                 "dead_volume_a_m3", "dead_volume_b_m3")

# A light piston with damped seals: an oil column near 500 Hz, damping ratio ~0.5.
STIFF_ACTUATOR = {"moving_mass_kg": 10.0, "friction_viscous_n_s_m": 3.0e4}

# Effect parameters used when a caller switches an effect on without values (SI).
DEFAULT_EFFECTS: dict[str, dict[str, float]] = {
    "valve_dynamics": {"tau_s": 0.015},
    "direction_asymmetry": {"asymmetry": 0.1},
    "actuator_friction": {"velocity_loss_m_s": 1.0e-3},
    "backlash": {"half_width_m": 3.0e-4},
    "load_dependent_velocity": {"stall_force_n": 4.0e4},
    "command_quantisation": {"step_m": 5.0e-5, "update_period_s": 0.02},
    "sensor_offset": {"offset_n": 500.0},
    "specimen_nonlinearity": {"closure_stiffness_n_m": 2.0e6, "closure_offset_m": -0.002},
}
NEEDS_SPECIMEN = ("load_dependent_velocity", "sensor_offset", "specimen_nonlinearity")


def loop_reference(duration_s: float, rate_hz: float, *, centre_m: float = CENTRE_M, half_range_m: float = 0.02,
                   variant: int = 0) -> np.ndarray:
    """Position command [m]: a hold, ramps both ways at three speeds, sines of 0.5-4 Hz and a
    0.5 -> 8 Hz chirp around `centre_m`, excursions up to `half_range_m`; `variant` shuffles the
    blocks and scales the speeds (another experiment on the same rig). Starts at rest."""
    dt = 1.0 / rate_hz
    rng = np.random.default_rng(variant)
    a = half_range_m
    speed = (1.0 if variant == 0 else float(rng.uniform(0.6, 1.4))) * a

    def hold(y: float, sec: float) -> np.ndarray:
        return np.full(max(1, int(round(sec / dt))), y)

    def ramp(y0: float, y1: float, v: float) -> np.ndarray:
        n = max(2, int(round(abs(y1 - y0) / v / dt)))
        return y0 + (y1 - y0) * np.arange(1, n + 1) / n

    def ramps(v: float) -> list[np.ndarray]:
        return [ramp(centre_m, centre_m + a, v), hold(centre_m + a, 0.2), ramp(centre_m + a, centre_m - a, v),
                hold(centre_m - a, 0.2), ramp(centre_m - a, centre_m, v), hold(centre_m, 0.2)]

    def sine(freq: float, amp: float, cycles: int) -> np.ndarray:
        n = int(round(cycles / freq / dt))
        return centre_m + amp * np.sin(2 * np.pi * freq * dt * np.arange(1, n + 1))

    def chirp(f0: float, f1: float, sec: float, amp: float) -> np.ndarray:
        t = dt * np.arange(1, int(round(sec / dt)) + 1)
        return centre_m + amp * np.sin(2 * np.pi * (f0 * t + (f1 - f0) / (2 * sec) * t**2))

    blocks = [ramps(0.5 * speed) + ramps(1.5 * speed) + ramps(4.0 * speed),
              [sine(0.5, a, 1), sine(1.0, 0.5 * a, 2), sine(2.0, 0.25 * a, 3), sine(4.0, 0.12 * a, 4), hold(centre_m, 0.2)],
              [chirp(0.5, 8.0, 4.0, 0.1 * a), hold(centre_m, 0.2)]]
    if variant:
        rng.shuffle(blocks)
    one = np.concatenate([hold(centre_m, 0.8)] + [b for blk in blocks for b in blk])
    n = int(round(duration_s * rate_hz))
    reps = int(np.ceil(n / len(one)))
    raw = np.tile(one, reps)[:n]
    # two moving averages round every corner (bounded acceleration)
    w = max(1, int(round(CORNER_S * rate_hz)))
    for _ in range(2):
        raw = np.convolve(np.pad(raw, (w // 2, w - 1 - w // 2), mode="edge"), np.ones(w) / w, mode="valid")
    return raw


def command_seen(reference: np.ndarray, rate_hz: float, step_m: float, update_period_s: float) -> np.ndarray:
    """The reference as a controller sees it when quantised to `step_m` and updated every
    `update_period_s` (whole samples from the first; 0 = every sample)."""
    every = max(1, int(round(update_period_s * rate_hz))) if update_period_s > 0 else 1
    held = np.repeat(reference[::every], every)[: len(reference)]
    return step_m * np.round(held / step_m) if step_m > 0 else held


def make_loop_record(effects: Mapping[str, Mapping[str, Any]] | None = None, *, seed: int, rate_hz: float = 1000,
                     duration_s: float = 20, rig_spread: float = 0.2, noise: bool = True, specimen: bool | None = None,
                     variant: int = 0, half_range_m: float | None = None, feedforward: bool | None = None,
                     name: str | None = None) -> tuple[Record, dict[str, Any]]:
    """A `machine_position` record of the valve-level plant in a position loop with loop
    `effects` on (ids of docs/effects.md -> their parameters; empty dicts take
    `DEFAULT_EFFECTS`). Rig parameters are drawn within +-`rig_spread` (seeded); `variant`
    chooses the experiment (`loop_reference`). A specimen (2e6 N/m at the command's centre)
    and its load cell `f` are fitted when asked or when an effect needs them. The controller
    passes the command's velocity forward (`feedforward`) unless told otherwise or
    `command_quantisation` is on.

    The rig is drawn from `seed` alone: records of one seed and other `variant`s are runs of
    the same rig (their sensor noise differs).

    Returns (record, truth): truth = {"effects": {id: {"channel", "params"}}, "params": the
    valve-level Params as a dict}."""
    effects = {k: dict(v) or dict(DEFAULT_EFFECTS.get(k, {})) for k, v in (effects or {}).items()}
    for eid in effects:
        if eid not in DEFAULT_EFFECTS:
            raise InputError(f"effect `{eid}` cannot be injected into the valve-level plant; injectable: {', '.join(DEFAULT_EFFECTS)}")
    needs = any(e in NEEDS_SPECIMEN for e in effects)
    with_specimen = needs if specimen is None else bool(specimen)
    if needs and not with_specimen:
        raise InputError(f"effects {', '.join(e for e in effects if e in NEEDS_SPECIMEN)} need a specimen (specimen=True)")
    ff = ("command_quantisation" not in effects) if feedforward is None else bool(feedforward)
    controller = dict(CONTROLLER, kff_v_per_m_s=KFF_V_PER_M_S if ff else 0.0)
    rng = np.random.default_rng(seed)
    nominal = Params("base")
    nominal["gravity_m_s2"] = 0.0
    rig = rig_metadata(nominal)
    orifice = "direction_asymmetry" in effects or "load_dependent_velocity" in effects
    rig["valve_flow_law"] = "orifice" if orifice else "linear"
    rig["valve_underlap_v"] = 0.0
    spec = {"stiffness_n_m": SPECIMEN_STIFFNESS_N_M, "zero_force_position_m": CENTRE_M} if with_specimen else None
    truth = params_from_meta({"rig": rig, "specimen": spec, "controller": controller})
    truth["friction_coulomb_pos_n"] = truth["friction_coulomb_neg_n"] = LOW_FRICTION_N
    truth["friction_static_n"] = 0.0
    for f in SPREAD_FIELDS:
        truth[f] = truth[f] * float(rng.uniform(1 - rig_spread, 1 + rig_spread))
    area = truth["area_a_m2"]
    resolved: dict[str, dict[str, Any]] = {}
    cmd_step, cmd_period = 0.0, 0.0
    for eid, vals in effects.items():
        vals = {k: float(v) for k, v in vals.items()}
        if eid == "valve_dynamics":
            truth["valve_tau_s"] = vals["tau_s"]
        elif eid == "direction_asymmetry":
            alpha = vals["asymmetry"]
            if not -0.5 < alpha < 0.5:
                raise InputError(f"direction_asymmetry {alpha}: allowed (-0.5, 0.5)")
            truth["area_b_m2"] = area * ((1 - alpha) / (1 + alpha)) ** 2  # sqrt(A_a/A_b) = (1+a)/(1-a)
        elif eid == "actuator_friction":
            fc = vals["velocity_loss_m_s"] * area**2 / LEAKAGE
            truth["leakage_coeff_m3_per_s_pa"] = LEAKAGE
            truth["friction_coulomb_pos_n"] = truth["friction_coulomb_neg_n"] = fc
        elif eid == "backlash":
            truth["valve_hysteresis_half_width_v"] = vals["half_width_m"] * abs(KP_V_PER_M)
        elif eid == "load_dependent_velocity":
            truth["supply_pressure_pa"] = vals["stall_force_n"] / area + truth["tank_pressure_pa"]
        elif eid == "command_quantisation":
            cmd_step, cmd_period = vals["step_m"], vals["update_period_s"]
            for k, v in STIFF_ACTUATOR.items():
                truth[k] = v
        elif eid == "sensor_offset":
            truth["sensor_offset_f"] = vals["offset_n"]
        elif eid == "specimen_nonlinearity":
            truth["specimen_closure_stiffness_n_m"] = vals["closure_stiffness_n_m"]
            truth["specimen_closure_offset_m"] = vals["closure_offset_m"]
        resolved[eid] = {"channel": "f" if eid in ("sensor_offset", "specimen_nonlinearity") else None, "params": vals}
    truth.validate()

    dt = 1.0 / rate_hz
    half = half_range_m if half_range_m is not None else (0.006 if with_specimen else 0.02)
    ref = loop_reference(duration_s, rate_hz, centre_m=CENTRE_M, half_range_m=half, variant=variant)
    seen = command_seen(ref, rate_hz, cmd_step, cmd_period)
    n = len(ref)
    chans = ["y", "f"] if with_specimen else ["y"]
    kw: dict[str, Any] = {}
    sensors: dict[str, Any] = {}
    if noise:
        noise_rng = np.random.default_rng([seed, variant])
        kw["noise"] = {c: noise_rng.normal(0.0, NOISE_STD[c], n) for c in chans}
        kw["quantum"] = {c: QUANTUM[c] for c in chans}
        sensors = {c: {"resolution": QUANTUM[c], "noise_std": NOISE_STD[c]} for c in chans}
    out = replay([truth], dt, np.zeros(n), controller=controller, reference=seen, preroll_s=PREROLL_S, rtol=1e-6,
                 threads=1, **kw)[0]
    if isinstance(out, HtmError):
        raise InputError(f"the simulated rig failed (seed {seed}, effects {sorted(resolved)}): {out}")
    cols = {"t": dt * np.arange(n), "y_ref": ref, **{c: out[c] for c in chans}}
    meta = {"format": FORMAT, "sample_rate_hz": rate_hz, "rig": {"stroke_m": nominal["stroke_m"]},
            "specimen": {"stiffness_n_m": SPECIMEN_STIFFNESS_N_M, "zero_force_position_m": CENTRE_M} if with_specimen else None,
            "controller": {"type": MACHINE_POSITION}, "sensors": sensors,
            "source": "htm loop proving ground: the valve-level plant in a position loop, u and pressures dropped"}
    label = name or "loop_" + ("_".join(sorted(resolved)) or "clean") + f"_s{seed}" + (f"_v{variant}" if variant else "")
    return Record(cols, meta, label), {"effects": resolved, "params": truth.to_dict()}
