"""The proving ground: closed-loop position records from the Rust simulator with any EFFECTS.md
effects switched on, rig parameters spread around the nominal rig, and realistic sensors."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from htm.core import Params, replay
from htm.errors import HtmError, InputError
from htm.ident.experiments import POSITION_LAW
from htm.ident.records import FORMAT, Record
from htm.ident.sim import CHANNELS, PREROLL_S, SENSOR_EFFECTS, effect_fields, params_from_meta, with_effect
from htm.params import rig_metadata

# Effect parameters used when a caller switches an effect on without values (SI): sizes a real
# rig shows and a diagnosis should find in a 10-20 s record.
DEFAULT_EFFECTS: dict[str, dict[str, Any]] = {
    "sensor_offset": {"channel": "p_a"},  # offset by channel below
    "sensor_gain": {"channel": "p_a", "gain": 1.15},
    "sensor_delay": {"channel": "p_a", "delay_s": 0.008},
    "valve_null_bias": {"bias_v": 0.15},
    "valve_dynamics": {"tau_s": 0.015},
    "valve_deadband": {"half_width_v": 0.2},
    "valve_hysteresis": {"half_width_v": 0.25},
    "supply_pressure_sag": {"resistance_pa_s_per_m3": 1.0e10},
    "internal_leakage": {"coeff_m3_per_s_pa": 3.0e-12},
    "friction_asymmetry": {"coulomb_pos_n": 1100.0, "coulomb_neg_n": 500.0},
    "pressure_dependent_friction": {"coeff_n_per_pa": 6.0e-5},
    "entrained_air": {"air_fraction": 0.05},
    "load_pressure_feedback": {},
    "specimen_nonlinearity": {"closure_stiffness_n_m": 2.0e6, "closure_offset_m": -0.002},
}
DEFAULT_OFFSET = {"y": 1e-3, "v": 5e-3, "p_a": 4e5, "p_b": 4e5, "p_s": 4e5, "f": 500.0}

# Rig parameters drawn around the nominal rig (the baseline's free parameters); the Coulomb pair
# moves together so the truth stays symmetric unless friction_asymmetry is on.
SPREAD_FIELDS = ("moving_mass_kg", "friction_viscous_n_s_m", "friction_coulomb_n", "friction_static_n",
                 "valve_rated_flow_m3_s", "bulk_modulus_pa", "dead_volume_a_m3", "dead_volume_b_m3")

# Sensors: white noise standard deviation and quantization step per channel (SI).
NOISE_STD = {"y": 2e-6, "v": 5e-4, "p_a": 3e4, "p_b": 3e4, "p_s": 3e4, "f": 20.0}
QUANTUM = {"y": 1e-6, "v": 1e-5, "p_a": 1.2e3, "p_b": 1.2e3, "p_s": 1.2e3, "f": 2.0}

SPECIMEN_STIFFNESS_N_M = 2.0e6
CENTRE_M = 0.1
CONTROLLER = {"type": "position_pff", "kp_v_per_m": -150.0, "kff_v_per_m_s": -14.3, "u_max_v": 10.0, "law": POSITION_LAW}
# Force control of the specimen (a loop of ~10 Hz on the 2e6 N/m specimen; negative like the
# valve's polarity), and the force the experiment holds and swings around.
FORCE_LAW = "u[k] = clip(kp*(f_ref[k]-f[k]), -u_max, u_max)"
FORCE_CONTROLLER = {"type": "force_p", "kp_v_per_n": -6e-4, "u_max_v": 10.0, "law": FORCE_LAW}
FORCE_MEAN_N, FORCE_SWING_N = 4000.0, 6000.0
# The power unit is switched from high to low pressure part-way (at the first hold after this
# share of the record, to this share of the supply, with this lag [s]): at one supply the
# chamber pressures of a symmetric actuator always sum to about p_s, so pressure-dependent seal
# friction would look like Coulomb friction; a second level tells them apart.
SUPPLY_SWITCH_AT, SUPPLY_LOW, SUPPLY_LAG_S = 0.55, 0.6, 0.1
OUTSIDE = {"friction_bump": {"friction_bump_n": 500.0, "friction_bump_width_m": 0.006},
           # a pump's ripple on the supply, between two spectral bins of any record length
           "supply_ripple": {"supply_ripple_sin_pa": 2.0e5, "supply_ripple_cos_pa": 1.0e5, "supply_ripple_hz": 37.31}}


def rich_reference(duration_s: float, rate_hz: float, *, centre_m: float = CENTRE_M, half_range_m: float = 0.06) -> np.ndarray:
    """Position reference [m]: holds, up-and-down ramps at several speeds, sines and steps,
    repeated to fill `duration_s`; excursions scale with `half_range_m` around `centre_m`."""
    dt = 1.0 / rate_hz
    s = half_range_m / 0.06

    def hold(y: float, sec: float) -> np.ndarray:
        return np.full(max(1, int(round(sec / dt))), y)

    def ramp(y0: float, y1: float, speed: float) -> np.ndarray:
        n = max(2, int(round(abs(y1 - y0) / speed / dt)))
        return y0 + (y1 - y0) * np.arange(1, n + 1) / n

    block: list[np.ndarray] = [hold(centre_m, 0.4)]
    for step in (0.01, -0.02, 0.01):  # steps
        block.append(hold(block[-1][-1] + step * s, 0.4))
    for freq, amp, cycles in ((0.5, 0.03, 1), (2.0, 0.005, 2)):  # sines
        n = int(round(cycles / freq / dt))
        block.append(centre_m + amp * s * np.sin(2 * np.pi * freq * dt * np.arange(1, n + 1)))
    block.append(hold(centre_m, 0.3))
    for speed in (0.01, 0.03, 0.08):  # constant-velocity ramps both ways at three speeds
        top, bottom = centre_m + min(speed * 0.6, 0.06) * s, centre_m - min(speed * 0.6, 0.06) * s
        block += [ramp(centre_m, top, speed * s), hold(top, 0.25), ramp(top, bottom, speed * s), hold(bottom, 0.25),
                  ramp(bottom, centre_m, speed * s), hold(centre_m, 0.25)]
    one = np.concatenate(block)
    n = int(round(duration_s * rate_hz))
    return np.resize(one, n)


def force_reference(duration_s: float, rate_hz: float, *, mean_n: float = FORCE_MEAN_N, swing_n: float = FORCE_SWING_N) -> np.ndarray:
    """Force reference [N] for a force-controlled experiment: holds, ramps at several rates, sines
    at several frequencies and steps around `mean_n`, within +-`swing_n`, repeated to fill
    `duration_s` (tension positive)."""
    dt = 1.0 / rate_hz

    def hold(f: float, sec: float) -> np.ndarray:
        return np.full(max(1, int(round(sec / dt))), f)

    def ramp(f0: float, f1: float, sec: float) -> np.ndarray:
        n = max(2, int(round(sec / dt)))
        return f0 + (f1 - f0) * np.arange(1, n + 1) / n

    top, bottom = mean_n + swing_n, mean_n - swing_n
    block: list[np.ndarray] = [hold(mean_n, 0.4)]
    for step in (0.3, -0.6, 0.3):
        block.append(hold(block[-1][-1] + step * swing_n, 0.4))
    for freq, amp, cycles in ((0.5, 0.8, 1), (2.0, 0.4, 2), (5.0, 0.2, 4)):
        n = int(round(cycles / freq / dt))
        block.append(mean_n + amp * swing_n * np.sin(2 * np.pi * freq * dt * np.arange(1, n + 1)))
    block.append(hold(mean_n, 0.3))
    for sec in (2.0, 0.8, 0.3):  # ramps between the extremes at three rates
        block += [ramp(mean_n, top, sec / 2), hold(top, 0.25), ramp(top, bottom, sec), hold(bottom, 0.25),
                  ramp(bottom, mean_n, sec / 2), hold(mean_n, 0.25)]
    one = np.concatenate(block)
    return np.resize(one, int(round(duration_s * rate_hz)))


def supply_profile(ref: np.ndarray, rate_hz: float) -> np.ndarray:
    """The supply (read at rest) per sample as a factor of nominal: high, then low from the first
    hold of the reference after `SUPPLY_SWITCH_AT` of the record (an operator switches the power
    unit with the actuator at rest), with a first-order lag `SUPPLY_LAG_S`."""
    n = len(ref)
    t = np.arange(n) / rate_hz
    still = np.r_[np.diff(ref) == 0, False]
    k = int(SUPPLY_SWITCH_AT * n)
    run = max(2, int(0.2 * rate_hz))  # a hold at least this long
    starts = [i for i in range(k, n - run) if still[i:i + run].all() and (i == 0 or not still[i - 1])]
    t0 = (starts[0] if starts else k) / rate_hz + 0.05
    return 1.0 - (1.0 - SUPPLY_LOW) * np.where(t < t0, 0.0, 1.0 - np.exp(-(t - t0) / SUPPLY_LAG_S))


def make_record(effects: Mapping[str, Mapping[str, Any]] | None = None, *, seed: int, rate_hz: float = 500,
                duration_s: float = 20, rig_spread: float = 0.3, noise: bool = True, experiment: str = "rich",
                specimen: bool | None = None, effect_outside_table: str | None = None,
                supply_pa: float | None = None, tank_pa: float = 0.0, spool_hz: float | None = None,
                sensors: Mapping[str, Mapping[str, float]] | None = None) -> tuple[Record, dict[str, Any]]:
    """A closed-loop position record of the simulated rig with `effects` on (EFFECTS.md ids ->
    parameter dicts in EFFECTS.md names; sensor effects carry `channel`; empty dicts take
    `DEFAULT_EFFECTS`). The experiment is position control (`rich_reference`, "rich") or force
    control of the specimen (`force_reference`, "force"); either switches the power unit from high
    to low supply pressure part-way (`supply_profile`). The rig's free parameters are drawn uniformly within +-`rig_spread` of the
    nominal thesis rig while the metadata states the nominal values; readings get white noise
    and quantization (`NOISE_STD`, `QUANTUM`) inside the loop. A specimen (2e6 N/m, with an `f`
    column) is fitted when asked, or when an effect needs one. `effect_outside_table`:
    "friction_bump" adds a position-dependent friction bump, "supply_ripple" a pump's ripple on the
    supply: structure that no EFFECTS.md id describes. `supply_pa` sets the power unit's nominal
    pressure (default: the thesis rig's), declared in the metadata like any rig's. `tank_pa` adds a
    back-pressure in the return line that the metadata does not state (rigs' usually go undeclared).
    `spool_hz` gives the valve's spool a second-order response of that natural frequency (damping
    0.7; default: a static valve), which the metadata does not state either (a servo-valve's
    data sheet value rarely reaches a record). `sensors` sets a channel's `resolution` (its
    quantum) and `noise_std` in place of `QUANTUM` and `NOISE_STD` (a finer or coarser reading),
    both applied and declared as given.

    Returns (record, truth) with truth = {"effects": {id: {"channel", "params"}}, "params": the
    true Params as a dict, "spread": {field: factor}, "outside": name or None}.
    """
    effects = dict(effects or {})
    if experiment not in ("rich", "force"):
        raise InputError(f"experiment = {experiment!r}: use \"rich\" (position control) or \"force\" (force control of a specimen)")
    wanted: dict[str, Any] = dict(sensors or {})
    for ch, spec in wanted.items():
        if ch not in CHANNELS or not isinstance(spec, Mapping) or set(spec) - {"resolution", "noise_std"} or not all(
                isinstance(x, (int, float)) and np.isfinite(x) and x > 0 for x in spec.values()):
            raise InputError(f"sensors[{ch!r}] = {spec!r}: give a channel of {', '.join(CHANNELS)} a positive "
                             "`resolution` and/or `noise_std` in its unit")
    quantum = {ch: float(wanted.get(ch, {}).get("resolution", QUANTUM[ch])) for ch in CHANNELS}
    noise_std = {ch: float(wanted.get(ch, {}).get("noise_std", NOISE_STD[ch])) for ch in CHANNELS}
    if not (100 <= rate_hz <= 10000):
        raise InputError(f"rate_hz = {rate_hz}: allowed [100, 10000] Hz")
    if not (1.0 <= duration_s <= 3600):
        raise InputError(f"duration_s = {duration_s}: allowed [1, 3600] s")
    if not (0 <= tank_pa <= 1e6):
        raise InputError(f"tank_pa = {tank_pa}: allowed [0, 1e6] Pa")
    if spool_hz is not None and not (20.0 <= spool_hz <= 5000.0):
        raise InputError(f"spool_hz = {spool_hz}: allowed [20, 5000] Hz")
    if not (0 <= rig_spread < 1):
        raise InputError(f"rig_spread = {rig_spread}: allowed [0, 1)")
    if effect_outside_table not in (None, *OUTSIDE):
        raise InputError(f"effect_outside_table = {effect_outside_table!r}: use one of {', '.join(OUTSIDE)} or None")
    resolved: dict[str, dict[str, Any]] = {}
    for eid, given in effects.items():
        if eid not in DEFAULT_EFFECTS:
            raise InputError(f"unknown effect `{eid}`; EFFECTS.md ids: {', '.join(DEFAULT_EFFECTS)}")
        vals = dict(given) if given else dict(DEFAULT_EFFECTS[eid])
        channel = vals.pop("channel", DEFAULT_EFFECTS[eid].get("channel")) if eid in SENSOR_EFFECTS else None
        if eid == "sensor_offset" and not vals:
            vals = {next(iter(effect_fields(eid, channel))): DEFAULT_OFFSET[channel]}
        effect_fields(eid, channel)  # validates the channel
        resolved[eid] = {"channel": channel, "params": {k: float(v) for k, v in vals.items()}}
    needs_f = "specimen_nonlinearity" in resolved or any(e["channel"] == "f" for e in resolved.values()) or experiment == "force"
    with_specimen = needs_f if specimen is None else bool(specimen)
    if needs_f and not with_specimen:
        raise InputError("force control and effects on the force channel need a specimen (specimen=True)")

    rng = np.random.default_rng(seed)
    nominal = Params("base")
    if supply_pa is not None:
        if not (2e6 <= supply_pa <= 5e7):
            raise InputError(f"supply_pa = {supply_pa}: allowed [2e6, 5e7] Pa")
        nominal["supply_pressure_pa"] = float(supply_pa)
    meta: dict[str, Any] = {
        "format": FORMAT,
        "sample_rate_hz": rate_hz,
        "rig": rig_metadata(nominal),
        "specimen": {"stiffness_n_m": SPECIMEN_STIFFNESS_N_M, "zero_force_position_m": CENTRE_M} if with_specimen else None,
        "controller": dict(FORCE_CONTROLLER if experiment == "force" else CONTROLLER),
    }
    if "load_pressure_feedback" in resolved:
        meta["rig"]["valve_flow_law"] = "linear"
    truth = params_from_meta(meta)
    truth["tank_pressure_pa"] = truth["tank_pressure_pa"] + float(tank_pa)
    if spool_hz is not None:
        truth["valve_natural_hz"] = float(spool_hz)
    spread = {f: float(rng.uniform(1 - rig_spread, 1 + rig_spread)) for f in SPREAD_FIELDS}
    for f, k in spread.items():
        if f == "friction_coulomb_n":
            for side in ("friction_coulomb_pos_n", "friction_coulomb_neg_n"):
                truth[side] = truth[side] * k
        else:
            truth[f] = truth[f] * k
    for eid, e in resolved.items():
        truth = with_effect(truth, eid, e["params"], e["channel"])
    for k, v in OUTSIDE.get(effect_outside_table or "", {}).items():
        truth[k] = v
    if effect_outside_table == "friction_bump":
        truth["friction_bump_position_m"] = CENTRE_M + (0.004 if with_specimen else 0.03)

    dt = 1.0 / rate_hz
    half = 0.008 if with_specimen else 0.06
    if experiment == "force":
        ref = force_reference(duration_s, rate_hz)
    else:
        ref = rich_reference(duration_s, rate_hz, centre_m=CENTRE_M, half_range_m=half)
    n = len(ref)
    chans = [c for c in CHANNELS if c != "f" or with_specimen]
    kw: dict[str, Any] = {}
    meta["sensors"] = {}
    if noise:
        kw["noise"] = {c: rng.normal(0.0, noise_std[c], n) for c in chans}
        kw["quantum"] = {c: quantum[c] for c in chans}
        meta["sensors"] = {c: {"resolution": quantum[c], "noise_std": noise_std[c]} for c in chans}
    out = replay([truth], dt, np.zeros(n), controller=meta["controller"], reference=ref, preroll_s=PREROLL_S, rtol=1e-6,
                 supply=supply_profile(ref, rate_hz), threads=1, **kw)[0]
    if isinstance(out, HtmError):
        raise InputError(f"the simulated rig failed (seed {seed}, effects {sorted(resolved)}): {out}")
    cols = {"t": dt * np.arange(n), "u": out["u"], **{c: out[c] for c in chans}, ("f_ref" if experiment == "force" else "y_ref"): ref}
    name = ("proving_" + ("force_" if experiment == "force" else "") + ("_".join(sorted(resolved)) or "clean")
            + (f"_{effect_outside_table}" if effect_outside_table else "") + f"_s{seed}")
    rec = Record(cols, meta, name)
    return rec, {"effects": resolved, "params": truth.to_dict(), "spread": spread, "outside": effect_outside_table}


# --------------------------------------------------------------------------- the effect matrix
# Every EFFECTS.md id on its own (sensor effects on two channels each), pairs, clean records,
# force control and an effect outside the table: (id, effects, make_record keywords). A seed set
# is a shift added to each case's seed (its index), so that a second set no constant was
# adjusted against runs the same cases on other rigs and noise.
MATRIX: list[tuple[str, dict[str, Any], dict[str, Any]]] = [
    ("sensor_offset-p_a", {"sensor_offset": {"channel": "p_a", "offset_pa": 4e5}}, {}),  # the thesis's own finding
    ("sensor_offset-f", {"sensor_offset": {"channel": "f", "offset_n": 500.0}}, {}),
    ("sensor_gain-p_b", {"sensor_gain": {"channel": "p_b", "gain": 1.15}}, {}),
    ("sensor_gain-v", {"sensor_gain": {"channel": "v", "gain": 0.85}}, {}),
    ("sensor_delay-y", {"sensor_delay": {"channel": "y", "delay_s": 0.01}}, {}),
    ("sensor_delay-p_a", {"sensor_delay": {"channel": "p_a", "delay_s": 0.008}}, {}),
    ("valve_null_bias", {"valve_null_bias": {}}, {}),
    ("valve_dynamics", {"valve_dynamics": {}}, {}),
    ("valve_deadband", {"valve_deadband": {}}, {}),
    ("valve_hysteresis", {"valve_hysteresis": {}}, {}),
    ("supply_pressure_sag", {"supply_pressure_sag": {}}, {}),
    ("internal_leakage", {"internal_leakage": {}}, {}),
    ("friction_asymmetry", {"friction_asymmetry": {}}, {}),
    ("pressure_dependent_friction", {"pressure_dependent_friction": {}}, {}),
    # free air softens the oil only where the chambers run at low pressure (at 5 % it takes about
    # 40 % of the oil's stiffness at 30 bar, 6 % at 95 bar): this case runs its power unit at
    # 70 bar, as a lab would to see air, so the record carries the effect's signature
    ("entrained_air", {"entrained_air": {}}, {"supply_pa": 7.0e6}),
    ("load_pressure_feedback", {"load_pressure_feedback": {}}, {}),
    ("specimen_nonlinearity", {"specimen_nonlinearity": {}}, {}),
    ("pair:valve_null_bias+sensor_offset", {"valve_null_bias": {}, "sensor_offset": {"channel": "p_a", "offset_pa": 4e5}}, {}),
    ("pair:valve_dynamics+internal_leakage", {"valve_dynamics": {}, "internal_leakage": {}}, {}),
    ("pair:friction_asymmetry+sensor_gain", {"friction_asymmetry": {}, "sensor_gain": {"channel": "p_b", "gain": 1.15}}, {}),
    ("force:clean", {}, {"experiment": "force"}),
    ("force:sensor_offset-f", {"sensor_offset": {"channel": "f", "offset_n": 400.0}}, {"experiment": "force"}),
    ("force:valve_null_bias", {"valve_null_bias": {}}, {"experiment": "force"}),
    ("clean-500Hz", {}, {}),
    ("clean-1kHz", {}, {"rate_hz": 1000}),
    ("clean-specimen", {}, {"specimen": True}),
    ("outside:friction_bump", {}, {"effect_outside_table": "friction_bump"}),
    ("outside:supply_ripple", {}, {"effect_outside_table": "supply_ripple"}),
]
# seed set -> shift. B was never looked at while tuning, until its entrained_air case showed that
# case carried no signature at the thesis supply; C was drawn after that change and showed the
# `explained` share counting channels at their noise; D was drawn after that fix, and run once;
# E was drawn with the close-decision rule (issue 31), after every constant was set, and run once.
MATRIX_SEED = {"A": 100, "B": 7100, "C": 14100, "D": 21100, "E": 28100}
MATRIX_DURATION_S = 10.0


def matrix_record(case: str, seed_set: str = "A", **overrides: Any) -> tuple[Record, dict[str, Any]]:
    """The record and truth of one effect-matrix case in one seed set; `overrides`: `make_record`
    keywords over the case's own (a variant of the case on the same rig and noise)."""
    names = [c[0] for c in MATRIX]
    if case not in names:
        raise InputError(f"unknown matrix case {case!r}; cases: {', '.join(names)}")
    if seed_set not in MATRIX_SEED:
        raise InputError(f"unknown seed set {seed_set!r}; use one of {', '.join(MATRIX_SEED)}")
    i = names.index(case)
    _, effects, kw = MATRIX[i]
    return make_record(effects, seed=MATRIX_SEED[seed_set] + i, duration_s=MATRIX_DURATION_S, **{**kw, **overrides})


def judge(report: Mapping[str, Any], truth: Mapping[str, Any]) -> list[str]:
    """What is wrong with a diagnosis of a proving-ground record (empty: it passes): the findings
    must be the true effects (id, and channel for sensor effects and the specimen's force), every
    true parameter within 30 %, some channel's error above its sensor noise at least halved by
    them, and `unexplained` false — except for an effect outside the table, which must leave no
    finding and be unexplained."""
    found = [(f["effect"], f["channel"]) for f in report["findings"]]
    chan = {"specimen_nonlinearity": "f"}
    want = {(e, t["channel"] or chan.get(e)) for e, t in truth["effects"].items()}
    problems = []
    if truth.get("outside"):
        if found:
            problems.append(f"claimed {found} for an effect outside the table")
        if not report["unexplained"]:
            problems.append("an effect outside the table left unexplained = false")
        return problems
    if sorted(found) != sorted(want):
        problems.append(f"findings {sorted(found)}, truth {sorted(want)}")
    if report["unexplained"]:
        problems.append("unexplained = true")
    by_id = {f["effect"]: f for f in report["findings"]}
    for eid, t in truth["effects"].items():
        for name, true in t["params"].items():
            est = by_id.get(eid, {}).get("params", {}).get(name)
            if est is None or abs(est - true) > 0.3 * abs(true):
                problems.append(f"{eid}.{name}: estimated {est}, true {true:.4g}")
    if want and not any(0.0 < 0.5 * _above_noise(report["baseline"]["rmse"][c], c) >= _above_noise(report["final"]["rmse"][c], c)
                        for c in report["final"]["rmse"]):
        problems.append("no channel's error above its sensor noise halved")
    return problems


def _above_noise(rmse: float, channel: str) -> float:
    """The part of a channel's error that a model can remove: its rms less the sensor's white
    noise and quantization (which no model predicts: a weak effect near the noise could never
    halve the whole error)."""
    floor2 = NOISE_STD.get(channel, 0.0) ** 2 + QUANTUM.get(channel, 0.0) ** 2 / 12.0
    return float(np.sqrt(max(rmse * rmse - floor2, 0.0)))
