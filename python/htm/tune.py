"""`htm tune SPEC --model MODEL.json [--out TUNED.toml]`: the force controller's settings for a test,
chosen on the rig's identified twin (`htm.twin`).

What a spec exposes of its force controller: the valve velocity gain the demodulation (or
position) controller's gains are designed from — every loop's rate scales with 1/k_v: the
amplitude loop's integral gain, the mean loop's P and I and the feed-forward of the carrier —
and the start: `[start] amplitude_cycles` (the ramp-in of the amplitude), `mean_cycles` kept.
The tuner tries loop-rate factors (k_v = the rig's own k_v / factor) and ramp-ins from the
shortest: the fastest start whose first 20 full-amplitude cycles stay within `target` (default
1 %, half the ±2 % band: the margin) of ΔF on the twin AND on the twin with each identified
parameter perturbed by ±`uncertainty` (default 20 %, the model carries no uncertainty of its
own). It writes the spec with those settings (runnable on the rig: the gain is in the rig's own
terms), reports the predicted worst |ΔF| error of the spec as given and as tuned, and the highest
frequency at which the twin holds the band with the tuned settings."""
from __future__ import annotations

import argparse
import math
import sys
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from htm import core
from htm import spec as specmod
from htm.errors import HtmError, SpecError
from htm.ident.plant import load_twin
from htm.ident.sim import effect_fields
from htm.terminal import add_json_flag, emit_json, path
from htm.twin import VELOCITY_DESIGNED, label, rig_velocity_gain, twin_config

# loop-rate factors tried (gains × factor) and ramp-ins [cycles], from the fastest start
FACTORS = (0.5, 0.7, 1.0, 1.4, 2.0)
RAMPS = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 15.0, 20.0, 25.0, 30.0, 40.0, 60.0)
JUDGED = 20  # the first full-amplitude cycles judged (the core's `worst_first_cycles_df_pct`)
# identified base parameters perturbed for the margin (with every finding's parameters)
BASE_UNCERTAIN = ("valve_rated_flow_m3_s", "bulk_modulus_pa", "moving_mass_kg", "friction_viscous_n_s_m",
                  "friction_coulomb_pos_n", "friction_coulomb_neg_n", "valve_underlap_v", "dead_volume_a_m3",
                  "dead_volume_b_m3")


@dataclass
class Candidate:
    factor: float
    amplitude_cycles: float
    worst_pct: float = math.nan  # worst |ΔF| error of the first full-amplitude cycles, over every plant
    nominal_pct: float = math.nan  # on the twin itself
    per_plant: list[float] = field(default_factory=list)


def perturbed(twin: core.Params, info: dict[str, Any], share: float) -> list[tuple[str, core.Params]]:
    """The twin with each identified parameter (base and every finding's) ×(1 ± share), one at a time."""
    names = [k for k in BASE_UNCERTAIN if twin[k] != 0.0]
    for f in info["findings"]:
        names += [fld for fld in effect_fields(f["effect"], f["channel"]).values() if twin[fld] != 0.0]
    out = []
    for k in dict.fromkeys(names):
        for sign in (-1.0, 1.0):
            p = twin.copy()
            p[k] = twin[k] * (1.0 + sign * share)
            try:
                p.validate()
            except HtmError:
                continue
            out.append((f"{k}×{1 + sign * share:g}", p))
    return out


def _variant(spec: specmod.TestSpec, amplitude_cycles: float, frequency_hz: float | None = None) -> specmod.TestSpec:
    """`spec` with a ramp-in, (a frequency), and only as many cycles as the judgement needs."""
    start = {**spec.start, "amplitude_cycles": amplitude_cycles}
    end = {**spec.end, "max_cycles": int(math.ceil(start["mean_cycles"] + amplitude_cycles)) + JUDGED + 5}
    v = replace(spec, start=start, end=end, mode="full", frequency_hz=frequency_hz or spec.frequency_hz, twin=None)
    v.config = specmod.build_config(v)
    return v


def _worst(outcomes: list[Any]) -> list[float]:
    """Each run's worst |ΔF| error [%] of its first full-amplitude cycles (inf for a failed run)."""
    out = []
    for o in outcomes:
        if isinstance(o, Exception) or o.worst_first_cycles_df_pct is None:
            out.append(math.inf)
        else:
            out.append(max(float(o.worst_first_cycles_df_pct), float(o.max_abs_df_err_pct)))
    return out


def evaluate(spec: specmod.TestSpec, plants: list[core.Params], kv_rig: float | None, factor: float,
             amplitude_cycles: float, frequency_hz: float | None = None) -> list[float]:
    """Worst first-cycles |ΔF| error [%] of the variant on each plant (run in parallel in the core)."""
    v = _variant(spec, amplitude_cycles, frequency_hz)
    kv = None if kv_rig is None else kv_rig / factor
    cfgs = [twin_config(v, p, kv) for p in plants]
    return _worst(core.run_batch(cfgs, "full"))


def tune(spec: specmod.TestSpec, model: str, *, target_pct: float = 1.0, uncertainty: float = 0.2) -> dict[str, Any]:
    """Choose the settings (see the module docstring); returns what `htm tune` reports, SI/%."""
    if spec.variable_amplitude:
        raise SpecError("htm tune: a variable-amplitude spec has no single full amplitude to tune the start for")
    twin, info = load_twin(model, spec.params())
    kv_rig = rig_velocity_gain(spec)
    factors = FACTORS if spec.controller["type"] in VELOCITY_DESIGNED else (1.0,)
    given_ramp = spec.config.start_amplitude_cycles
    plants = perturbed(twin, info, uncertainty)
    given = evaluate(spec, [twin] + [p for _, p in plants], kv_rig, 1.0, given_ramp)
    chosen: Candidate | None = None
    tried = 0
    for ramp in sorted({*RAMPS, given_ramp}):
        ok = []
        for fct in factors:
            tried += 1
            w = evaluate(spec, [twin], kv_rig, fct, ramp)[0]
            if w <= target_pct:
                ok.append(Candidate(fct, ramp, nominal_pct=w))
        for c in ok:  # the margin: every perturbed twin within the target too
            c.per_plant = evaluate(spec, [p for _, p in plants], kv_rig, c.factor, ramp)
            c.worst_pct = max([c.nominal_pct, *c.per_plant])
        ok = [c for c in ok if c.worst_pct <= target_pct]
        if ok:
            chosen = min(ok, key=lambda c: (c.worst_pct, abs(math.log(c.factor))))
            break
    result: dict[str, Any] = {
        "spec": spec.name, "model": info, "frequency_hz": spec.frequency_hz, "target_pct": target_pct,
        "tolerance_pct": 100 * spec.phases[-1].tolerance, "uncertainty": uncertainty,
        "perturbed_plants": [n for n, _ in plants], "candidates_tried": tried,
        "given": {"velocity_gain_m_s_per_v": kv_rig, "amplitude_cycles": given_ramp,
                  "predicted_worst_df_pct": given[0], "predicted_worst_df_pct_perturbed": max(given)},
        "tuned": None, "highest_frequency_hz": None,
    }
    if chosen is None:
        return result
    kv = None if kv_rig is None else kv_rig / chosen.factor
    result["tuned"] = {"velocity_gain_m_s_per_v": kv, "loop_rate_factor": chosen.factor,
                       "amplitude_cycles": chosen.amplitude_cycles, "mean_cycles": spec.start["mean_cycles"],
                       "predicted_worst_df_pct": chosen.nominal_pct, "predicted_worst_df_pct_perturbed": chosen.worst_pct}
    result["highest_frequency_hz"] = highest_frequency(spec, twin, chosen)
    return result


def highest_frequency(spec: specmod.TestSpec, twin: core.Params, c: Candidate) -> float | None:
    """The highest frequency [Hz] (on a grid of ×1.25 steps from the spec's, up to 16 samples a
    cycle) at which the twin, with the tuned loop-rate factor and ramp-in, holds the band (every
    first full-amplitude cycle within the test's tolerance) and the feasibility check passes."""
    tol = 100 * spec.phases[-1].tolerance
    best = None
    f = spec.frequency_hz
    while f <= spec.control_rate_hz / 16.0 + 1e-9:
        try:
            v = _variant(spec, c.amplitude_cycles, f)
            feasible = specmod.build_config(v).with_params(twin) is not None and \
                all(ch.status != "refused" for ch in _feas(v, twin))
            kv = rig_velocity_gain(v)
            w = evaluate(v, [twin], kv, c.factor, c.amplitude_cycles)[0] if feasible else math.inf
        except HtmError:
            w = math.inf
        if w > tol:
            break
        best = f
        f = round(f * 1.25, 3)
    return best


def _feas(v: specmod.TestSpec, twin: core.Params) -> list[Any]:
    from htm.feasibility import assess

    return [c for c in assess(specmod.build_config(v).with_params(twin)).checks if c.name in ("force_tension", "force_compression",
                                                                                           "valve_flow", "frequency", "stroke")]


def tuned_doc(doc: dict[str, Any], result: dict[str, Any]) -> dict[str, Any]:
    """The spec document with the tuned settings."""
    t = result["tuned"]
    out = {k: (dict(v) if isinstance(v, dict) else v) for k, v in doc.items()}
    out.setdefault("start", {})["amplitude_cycles"] = t["amplitude_cycles"]
    ctrl = out.setdefault("controller", {"type": "demodulation"})
    if t["velocity_gain_m_s_per_v"] is not None:
        ctrl["velocity_gain_m_s_per_v"] = t["velocity_gain_m_s_per_v"]
    return out


def cmd_tune(args: argparse.Namespace) -> int:
    src = Path(args.spec)
    spec = specmod.load(src)
    tol = 100 * spec.phases[-1].tolerance
    if not (math.isfinite(args.target) and 0.0 < args.target <= tol):
        raise HtmError(f"--target {args.target!r}: a worst |ΔF| error in % within the test's band, (0, {tol:g}]")
    if not (math.isfinite(args.uncertainty) and 0.0 <= args.uncertainty < 0.9):
        raise HtmError(f"--uncertainty {args.uncertainty!r}: a share in [0, 0.9) (0.2 = ±20 % on each identified parameter)")
    out = Path(args.out) if args.out else src.with_name(f"{src.stem}_tuned.toml")
    if out.exists():
        raise HtmError(f"--out {out} exists; refusing to overwrite a spec (choose another --out)")
    res = tune(spec, args.model, target_pct=args.target, uncertainty=args.uncertainty)
    if res["tuned"] is not None:
        doc = tuned_doc(tomllib.loads(src.read_text()), res)
        text = (f"# {src.name} tuned by `htm tune` on the twin {res['model']['path']}: predicted worst |ΔF| error of the "
                f"first {JUDGED} full-amplitude cycles {res['tuned']['predicted_worst_df_pct']:.2f} % "
                f"(≤ {res['tuned']['predicted_worst_df_pct_perturbed']:.2f} % with ±{args.uncertainty:.0%} on the model)\n")
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text + specmod.dumps(doc))
        specmod.load(out)  # what was written runs
        res["out"] = str(out)
    if args.json:
        emit_json(res)
        return 0 if res["tuned"] else 1
    g, t = res["given"], res["tuned"]
    print(f"{spec.name} at {spec.frequency_hz:g} Hz on the {label(spec.twin or res['model'])}")
    print(f"margin: the twin and {len(res['perturbed_plants'])} perturbed twins (±{args.uncertainty:.0%} on each identified "
          f"parameter); target worst |ΔF| of the first {JUDGED} full-amplitude cycles ≤ {args.target:g} %")
    rows = [("", "velocity gain", "ramp-in", "worst |ΔF| twin", "worst, perturbed")]
    rows.append(("as given", _kv(g["velocity_gain_m_s_per_v"]), f"{g['amplitude_cycles']:g} cycles",
                 f"{g['predicted_worst_df_pct']:.2f} %", f"{g['predicted_worst_df_pct_perturbed']:.2f} %"))
    if t:
        rows.append(("tuned", _kv(t["velocity_gain_m_s_per_v"]) + f" (loops ×{t['loop_rate_factor']:g})",
                     f"{t['amplitude_cycles']:g} cycles", f"{t['predicted_worst_df_pct']:.2f} %",
                     f"{t['predicted_worst_df_pct_perturbed']:.2f} %"))
    w = [max(len(r[i]) for r in rows) for i in range(5)]
    for r in rows:
        print("  ".join(x.ljust(w[i]) if i == 0 else x.rjust(w[i]) for i, x in enumerate(r)))
    if not t:
        print(f"no setting tried holds the target on every perturbed twin ({res['candidates_tried']} tried); nothing written",
              file=sys.stderr)
        return 1
    hf = res["highest_frequency_hz"]
    print(f"highest frequency holding the ±{res['tolerance_pct']:g} % band with these settings: "
          + (f"{hf:g} Hz" if hf else f"below {spec.frequency_hz:g} Hz"))
    print(f"written: {path(out)}  (run it: htm run {path(out)} --model {res['model']['path']})")
    return 0


def _kv(kv: float | None) -> str:
    return "—" if kv is None else f"{kv * 1e3:.2f} mm/s per V"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("tune", help="choose a test's force-controller settings on the rig's identified twin",
                       description=__doc__.split("\n\n")[0] + " " + " ".join(__doc__.split("\n\n")[1].split()))
    p.add_argument("spec", help="test spec (TOML)")
    p.add_argument("--model", required=True, metavar="MODEL.json", help="the rig's identified model (`htm rig identify`)")
    p.add_argument("--out", metavar="TUNED.toml", help="the tuned spec (default SPEC_tuned.toml beside the spec)")
    p.add_argument("--target", type=float, default=1.0, help="worst |ΔF| error [%%] of the first 20 full-amplitude cycles (default 1)")
    p.add_argument("--uncertainty", type=float, default=0.2, help="share each identified parameter is perturbed by (default 0.2)")
    add_json_flag(p)
    p.set_defaults(func=cmd_tune)
