"""The twin runs the tests: a test spec on an identified rig model (`model.json` of
`htm diagnose` / `htm rig identify`) instead of the nominal rig the spec names — `htm run
--model`, `htm run --check --model`, `htm campaign --model`, the console's Setup simulation and
`htm tune`.

The twin is the model's identified base parameters with every finding switched on
(`htm.ident.plant.load_twin`, the function that builds the virtual rig's hidden physics). The
controller is the one the rig would run: designed on the rig the spec names (its valve velocity
gain measured there, as `Session.start` does on the real machine), so the twin predicts what that
controller does on the machine the lab really has; a spec that states its gains keeps them."""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from htm import core
from htm import spec as specmod
from htm.errors import InfeasibleTest
from htm.ident.plant import finding_text, load_twin

# controller types whose gains come from the valve's velocity gain
VELOCITY_DESIGNED = ("demodulation", "position_pff")


def _design_kp2(spec: specmod.TestSpec, params: core.Params, kv: float | None) -> tuple[float, float]:
    """(velocity gain, the demodulation design's inner gain kp2 = ω_c/(K_eff·k_v)) of `spec`'s
    first cycles on `params` (`kv` None: measured there)."""
    probe = dataclasses.replace(spec, controller={"type": "demodulation", **({} if kv is None else {"velocity_gain_m_s_per_v": kv})})
    probe.config = specmod.build_config(probe).with_params(params)
    c = core.CyclicController(spec.control_rate_hz, None)
    c.start_test(probe.config, 0.0)
    info = c.info()
    return info["velocity_gain_m_s_per_v"], info["demod_kp2"]


def keff_ratio(spec: specmod.TestSpec, plant: core.Params) -> float:
    """K_eff of the spec's nominal rig over K_eff of `plant` (the specimen at a0 in series with
    the oil column): the rig's controller, designed on the nominal rig with a velocity gain k_v,
    has on `plant` the gains a design there with k_v times this ratio would have."""
    _, kp2_rig = _design_kp2(spec, spec.params(), 1.0)
    _, kp2_plant = _design_kp2(spec, plant, 1.0)
    return kp2_plant / kp2_rig


def rig_velocity_gain(spec: specmod.TestSpec) -> float | None:
    """The velocity gain the rig's controller uses for `spec`: the spec's, else measured on the
    rig the spec names (as `Session.start` does); None for a controller without one."""
    if spec.controller["type"] not in VELOCITY_DESIGNED:
        return None
    kv = spec.controller.get("velocity_gain_m_s_per_v")
    return kv if kv is not None else _design_kp2(spec, spec.params(), None)[0]


def twin_config(spec: specmod.TestSpec, plant: core.Params, kv_rig: float | None = None) -> core.TestConfig:
    """The core configuration of `spec` on `plant` with the controller the rig would run:
    its velocity gain `kv_rig` (default `rig_velocity_gain`) carried over to `plant`'s K_eff."""
    kv = rig_velocity_gain(spec) if kv_rig is None else kv_rig
    if kv is None:
        return specmod.build_config(spec).with_params(plant)
    ctrl = {**spec.controller, "velocity_gain_m_s_per_v": kv * keff_ratio(spec, plant)}
    return specmod.build_config(dataclasses.replace(spec, controller=ctrl)).with_params(plant)


def on_model(spec: specmod.TestSpec, model: str | Path, *, check: bool = True) -> specmod.TestSpec:
    """`spec` on the twin of `model` (a model.json path): its config's plant is the twin, its
    controller the rig's design (`twin_config`), `spec.twin` says which model. With `check` a
    test the twin cannot run raises InfeasibleTest (unless the spec overrides its limits).
    ModelError for a model that cannot drive a test."""
    twin, info = load_twin(str(model), spec.params())
    out = dataclasses.replace(spec, twin=info)
    out.config = twin_config(spec, twin)
    if check and not out.override_limits:
        feas = out.feasibility()
        if not feas.feasible:
            raise InfeasibleTest(f"on the twin {info['path']}: " + feas.refusal())
    return out


def label(twin: dict[str, Any] | None) -> str:
    """One line naming the model a test ran on (or the nominal rig)."""
    if not twin:
        return "nominal rig (the spec's [rig])"
    return f"twin {twin['path']} (identified on `{twin['record']}`; {finding_text(twin)})"
