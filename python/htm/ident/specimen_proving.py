"""The proving ground of the specimen family: simulated `displacement_input` records (a
specimen and its load train driven through a displacement history, the force read by a load
cell) with any of EFFECTS.md's specimen and load-train effects on, and the effect matrix on them.

The force is the core's specimen model (`specimen_force.rs`, the model the diagnosis fits) on the
true displacement; the record then holds the displacement and the force as sensors read them
(white noise, quantization). The specimen's stiffness and damping are drawn per seed around the
nominal specimen the metadata declares, each effect's size is drawn within
`EFFECT_SPREAD` of its default, and the displacement history (`history`) differs per variant:
records of one seed and other variants are tests of the same specimen.
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from htm.core import SpecimenParams, specimen_force
from htm.errors import HtmError, InputError
from htm.ident.records import DISPLACEMENT_INPUT, FORMAT, Record
from htm.ident.specimen import EFFECT_FIELDS, REPORTED_AS, VELOCITY_WINDOW_S

STIFFNESS_N_M = 4.0e6  # nominal (declared): a C(T) and its grips seen by a clip gauge, about
ZERO_FORCE_M = 0.0  # the gauge zeroed at installation, unloaded (declared, trusted)
CENTRE_M = 0.25e-3  # the history's mean displacement
DAMPING_N_S_M = (200.0, 2000.0)  # drawn per seed (a base parameter)
STIFFNESS_SPREAD = 0.3
EFFECT_SPREAD = (0.75, 1.35)
# Sensors: white noise and quantization (SI).
NOISE_STD = {"y": 0.3e-6, "f": 8.0}
QUANTUM = {"y": 0.1e-6, "f": 1.0}
# Effect sizes (SI) a lab sees on such a specimen and a diagnosis should find in ~12 s.
DEFAULT_EFFECTS: dict[str, dict[str, float]] = {
    "specimen_friction": {"friction_n": 300.0, "velocity_m_s": 1.5e-3},
    "load_train_backlash": {"gap_m": 1.5e-4},
    "specimen_nonlinearity": {"closure_stiffness_n_m": 4.0e6, "closure_offset_m": -2.0e-4},
    "sensor_offset": {"offset_n": 150.0},
    "presliding_friction": {"friction_n": 300.0, "presliding_m": 6.0e-5},
}
# Corners of the history are rounded over this time [s] (a function generator's ramps).
CORNER_S = 0.04


def history(duration_s: float, rate_hz: float, *, variant: int = 0) -> np.ndarray:
    """Displacement [m]: holds, ramps both ways at three speeds (0.5-6 mm/s) and sines of
    0.5-4 Hz around `CENTRE_M`, from -0.75 to +1.25 mm, corners rounded; `variant` shuffles the
    blocks and scales speeds and amplitudes (another test of the same specimen)."""
    dt = 1.0 / rate_hz
    rng = np.random.default_rng(variant)
    s = 1.0 if variant == 0 else float(rng.uniform(0.7, 1.0))
    c, lo, hi = CENTRE_M, CENTRE_M - 1.0e-3 * s, CENTRE_M + 1.0e-3 * s

    def hold(y: float, sec: float) -> np.ndarray:
        return np.full(max(1, int(round(sec / dt))), y)

    def ramp(y0: float, y1: float, v: float) -> np.ndarray:
        n = max(2, int(round(abs(y1 - y0) / v / dt)))
        return y0 + (y1 - y0) * np.arange(1, n + 1) / n

    def ramps(v: float) -> list[np.ndarray]:
        return [ramp(c, hi, v), hold(hi, 0.15), ramp(hi, lo, v), hold(lo, 0.15), ramp(lo, c, v), hold(c, 0.15)]

    def sine(freq: float, amp: float, cycles: int) -> np.ndarray:
        n = int(round(cycles / freq / dt))
        return c + amp * s * np.sin(2 * np.pi * freq * dt * np.arange(1, n + 1))

    speed = 1.0 if variant == 0 else float(rng.uniform(0.7, 1.4))
    blocks = [ramps(0.5e-3 * speed) + ramps(2e-3 * speed) + ramps(6e-3 * speed),
              [sine(0.5, 1.0e-3, 1), sine(1.0, 0.6e-3, 2), sine(2.0, 0.3e-3, 3), sine(4.0, 0.15e-3, 4), hold(c, 0.2)]]
    if variant:
        rng.shuffle(blocks)
    one = np.concatenate([hold(c, 0.4)] + [b for blk in blocks for b in blk])
    n = int(round(duration_s * rate_hz))
    raw = np.tile(one, int(np.ceil(n / len(one))))[:n]
    w = max(1, int(round(CORNER_S * rate_hz)))
    for _ in range(2):
        raw = np.convolve(np.pad(raw, (w // 2, w - 1 - w // 2), mode="edge"), np.ones(w) / w, mode="valid")
    return raw


def make_specimen_record(effects: Mapping[str, Mapping[str, Any]] | None = None, *, seed: int, rate_hz: float = 1000,
                         duration_s: float = 12, noise: bool = True, variant: int = 0, declare_zero: bool = True,
                         column: str = "y", name: str | None = None,
                         sizes: Mapping[str, Mapping[str, float]] | None = None) -> tuple[Record, dict[str, Any]]:
    """A `displacement_input` record of a simulated specimen with `effects` on (EFFECTS.md ids ->
    their parameters; empty dicts take `DEFAULT_EFFECTS` scaled by a factor drawn in
    `EFFECT_SPREAD`). The specimen (stiffness, damping) is drawn from `seed` alone; `variant`
    chooses the displacement history and the sensor noise. `declare_zero`: the metadata states
    the zero-force position (DATA_FORMAT.md: then a load-cell offset is a finding). `column`: the
    displacement as `y` or as a clip gauge's `cod`. `sizes`: other nominal sizes than
    `DEFAULT_EFFECTS` for some effects (still drawn within `EFFECT_SPREAD`).

    Returns (record, truth): truth = {"effects": {id: {"channel", "params"}}, "params": the
    SpecimenParams as a dict}."""
    if column not in ("y", "cod"):
        raise InputError(f"column = {column!r}: use \"y\" or \"cod\"")
    rng = np.random.default_rng(seed)
    truth = SpecimenParams()
    truth["specimen_stiffness_n_m"] = STIFFNESS_N_M * float(rng.uniform(1 - STIFFNESS_SPREAD, 1 + STIFFNESS_SPREAD))
    truth["specimen_zero_force_position_m"] = ZERO_FORCE_M
    truth["specimen_damping_n_s_m"] = float(rng.uniform(*DAMPING_N_S_M))
    truth["velocity_window_s"] = VELOCITY_WINDOW_S
    resolved: dict[str, dict[str, Any]] = {}
    for eid, given in (effects or {}).items():
        if eid not in DEFAULT_EFFECTS:
            raise InputError(f"effect `{eid}` is not a specimen or load-train effect; known: {', '.join(DEFAULT_EFFECTS)}")
        factor = float(rng.uniform(*EFFECT_SPREAD))
        nominal = {**DEFAULT_EFFECTS[eid], **((sizes or {}).get(eid) or {})}
        vals = {k: float(v) for k, v in given.items()} if given else {k: v * factor for k, v in nominal.items()}
        for k, v in vals.items():
            truth[EFFECT_FIELDS[eid][k]] = v
        resolved[eid] = {"channel": "f", "params": vals}
    truth.validate()
    dt = 1.0 / rate_hz
    y = history(duration_s, rate_hz, variant=variant)
    f = specimen_force([truth], dt, y, threads=1)[0]
    if isinstance(f, HtmError):
        raise InputError(f"the simulated specimen failed (seed {seed}): {f}")
    cols = {"y": y, "f": np.asarray(f)}
    sensors: dict[str, Any] = {}
    if noise:
        nrng = np.random.default_rng([seed, variant, 7])
        for c in cols:
            cols[c] = np.round((cols[c] + nrng.normal(0.0, NOISE_STD[c], len(y))) / QUANTUM[c]) * QUANTUM[c]
        sensors = {column: {"resolution": QUANTUM["y"], "noise_std": NOISE_STD["y"]},
                   "f": {"resolution_n": QUANTUM["f"], "noise_std": NOISE_STD["f"]}}
    spec: dict[str, Any] = {"stiffness_n_m": STIFFNESS_N_M}
    if declare_zero:
        spec["zero_force_position_m"] = ZERO_FORCE_M
    if column == "cod":
        spec.update({"geometry": "CT", "cod_at": "crack_mouth"})
    meta = {"format": FORMAT, "sample_rate_hz": rate_hz, "rig": {}, "specimen": spec,
            "controller": {"type": DISPLACEMENT_INPUT}, "sensors": sensors,
            "source": "htm specimen proving ground: specimen_force.rs on a displacement history, sensors added"}
    label = name or ("specimen_" + ("_".join(sorted(resolved)) or "clean") + f"_s{seed}" + (f"_v{variant}" if variant else ""))
    return Record({"t": dt * np.arange(len(y)), column: cols["y"], "f": cols["f"]}, meta, label), \
        {"effects": resolved, "params": truth.to_dict()}


# --------------------------------------------------------------------------- the effect matrix
# (case, effects, make_specimen_record keywords). A seed set is a shift added to each case's seed.
SPECIMEN_MATRIX: list[tuple[str, dict[str, Any], dict[str, Any]]] = [
    ("specimen:clean", {}, {}),
    ("specimen:clean-zero-undeclared", {}, {"declare_zero": False}),
    ("specimen:specimen_friction", {"specimen_friction": {}}, {}),
    ("specimen:load_train_backlash", {"load_train_backlash": {}}, {}),
    ("specimen:specimen_nonlinearity", {"specimen_nonlinearity": {}}, {}),
    ("specimen:sensor_offset-f", {"sensor_offset": {}}, {}),
    ("specimen:friction+backlash", {"specimen_friction": {}, "load_train_backlash": {}}, {}),
    ("specimen:closure-cod", {"specimen_nonlinearity": {}}, {"column": "cod"}),
    ("specimen:presliding_friction", {"presliding_friction": {}}, {}),
    # a dry friction damper with play (as the ARTS damper): friction about the size of the spring's
    # force over the travel, the play a seventh of the travel (larger than the small sines' swing)
    ("specimen:friction+backlash-large-gap", {"specimen_friction": {}, "load_train_backlash": {}},
     {"sizes": {"specimen_friction": {"friction_n": 2000.0, "velocity_m_s": 1.5e-3}, "load_train_backlash": {"gap_m": 3.0e-4}}}),
    ("specimen:presliding+backlash-large-gap", {"presliding_friction": {}, "load_train_backlash": {}},
     {"sizes": {"presliding_friction": {"friction_n": 2000.0, "presliding_m": 3.0e-4}, "load_train_backlash": {"gap_m": 3.0e-4}}}),
]
# seed set -> shift. A was used while building the family; B and C were run once afterwards, and
# again after `presliding_friction` joined the vocabulary (the real friction damper lacked it);
# D was drawn last and run once. `friction+backlash-large-gap` joined later (the ARTS damper's
# play with its dry friction: neither pays off alone) and was run on all four sets.
SPECIMEN_SEED = {"A": 500, "B": 8500, "C": 16500, "D": 24500}


def specimen_matrix_record(case: str, seed_set: str = "A", **overrides: Any) -> tuple[Record, dict[str, Any]]:
    """The record and truth of one specimen-matrix case in one seed set."""
    names = [c[0] for c in SPECIMEN_MATRIX]
    if case not in names:
        raise InputError(f"unknown specimen matrix case {case!r}; cases: {', '.join(names)}")
    if seed_set not in SPECIMEN_SEED:
        raise InputError(f"unknown seed set {seed_set!r}; use one of {', '.join(SPECIMEN_SEED)}")
    i = names.index(case)
    _, effects, kw = SPECIMEN_MATRIX[i]
    return make_specimen_record(effects, seed=SPECIMEN_SEED[seed_set] + i, **{**kw, **overrides})


def judge(report: Mapping[str, Any], truth: Mapping[str, Any]) -> list[str]:
    """What is wrong with a diagnosis of a specimen record (empty: it passes): the findings must be
    the true effects on `f`, every true parameter within 30 % in the final model (what model.json
    carries; a finding's own `params` are its values when it was added, and the later refits
    with the other findings move them), and `unexplained` false."""
    found = sorted((f["effect"], f["channel"]) for f in report["findings"])
    want = sorted((REPORTED_AS.get(e, e), "f") for e in truth["effects"])
    problems = []
    if found != want:
        problems.append(f"findings {found}, truth {want}")
    if report["unexplained"]:
        problems.append("unexplained = true")
    final = report["final"]["params"]
    for eid, t in truth["effects"].items():
        for name, true in t["params"].items():
            est = final.get(EFFECT_FIELDS[eid][name]) if (REPORTED_AS.get(eid, eid), "f") in found else None
            if est is None or abs(est - true) > 0.3 * abs(true):
                problems.append(f"{eid}.{name}: estimated {est}, true {true:.4g}")
    return problems
