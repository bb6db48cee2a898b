"""A rig's plant with effects switched on: the one function that builds the core `Params` of a
machine from a base model and a list of EFFECTS.md effects — the virtual rig's hidden physics
(`[virtual.effects]`, `htm.devices.rig.plant_params`) and an identified model's findings
(`model.json`, the twin that runs tests: `htm run --model`, `htm tune`)."""
from __future__ import annotations

from typing import Any, Iterable, Mapping

from htm.core import Params
from htm.errors import HtmError
from htm.ident.predict import Model, ModelError, read_model
from htm.ident.sim import EFFECT_IDS, with_effect

# what belongs to the installation, not to the machine: the test's own specimen and where it sits
INSTALLATION = ("specimen_stiffness_n_m", "specimen_zero_force_position_m")


def with_effects(base: Params, effects: Iterable[tuple[str, Mapping[str, float], str | None]],
                 rig: Params | None = None) -> Params:
    """`base` with each (effect id, its EFFECTS.md parameters, channel or None) switched on
    (`htm.ident.sim.with_effect`); with `rig`, the installation (`INSTALLATION`: the specimen's
    stiffness and zero-force position) is that rig's."""
    p = base.copy()
    if rig is not None:
        for k in INSTALLATION:
            p[k] = rig[k]
    for eid, values, channel in effects:
        p = with_effect(p, eid, values, channel)
    return p


def findings(model: Model) -> list[tuple[str, dict[str, float], str | None]]:
    """The model's findings as (effect, parameters, channel); an effect the plant cannot carry
    raises ModelError naming it."""
    out = []
    for i, e in enumerate(model.meta.get("effects") or []):
        if not isinstance(e, dict) or not isinstance(e.get("effect"), str) or not isinstance(e.get("params", {}), dict):
            raise ModelError(f"model {model.path}: effects[{i}] must be an object with `effect`, `channel` and `params`")
        if e["effect"] not in EFFECT_IDS:
            raise ModelError(f"model {model.path}: finding `{e['effect']}` is not an effect the test engine's plant "
                             f"carries (of {', '.join(EFFECT_IDS)}); it cannot drive a test")
        out.append((e["effect"], dict(e.get("params") or {}), e.get("channel")))
    return out


def describe(model: Model) -> dict[str, Any]:
    """What a summary says of the model used: path, family, the record it was identified on, the
    rig it names and its findings."""
    rig = model.meta.get("rig") or {}
    return {"path": model.path, "family": model.family, "record": model.meta.get("record"),
            "supply_pressure_pa": rig.get("supply_pressure_pa"), "moving_mass_kg": rig.get("moving_mass_kg"),
            "findings": [{"effect": e, "channel": c, "params": v} for e, v, c in findings(model)]}


def finding_text(d: dict[str, Any]) -> str:
    """One line of a model's findings, e.g. `valve_null_bias bias_v=0.12, sensor_offset@p_a offset_pa=3e+05`."""
    parts = [f"{f['effect']}{'@' + f['channel'] if f['channel'] else ''} "
             + " ".join(f"{k}={v:.3g}" for k, v in f["params"].items()) for f in d["findings"]]
    return ", ".join(parts) or "no findings (the base model)"


def load_twin(path: str, rig: Params) -> tuple[Params, dict[str, Any]]:
    """The twin of a model.json for a test on `rig` (the rig the test names): the model's
    identified base parameters with every finding switched on, the installation the rig's.
    Returns (Params, `describe` of the model). A model that cannot drive a test (a machine's
    closed displacement loop, a specimen-only record's family, an unknown finding) raises
    ModelError saying why."""
    model = read_model(path)
    if model.family != "valve" or not isinstance(model.params, Params):
        raise ModelError(f"model {model.path} is of family `{model.family}`: only a valve-level model (`htm diagnose` of a "
                         "record with the valve command `u`, e.g. `htm rig identify`'s) can run a test's plant")
    try:
        return with_effects(model.params, findings(model), rig), describe(model)
    except HtmError as e:
        if isinstance(e, ModelError):
            raise
        raise ModelError(f"model {model.path}: {e}") from None
