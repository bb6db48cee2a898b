"""Life tests on the simulated rig (issue 33 items 1-3): prints JSON.

- runout: a 10⁷-cycle force_life run-out with the cycle jump, wall seconds, against the same test
  at full fidelity (every cycle through the plant) extrapolated from 300 cycles of the same run;
- strain_life --rig: the same through htm.Session on the virtual rig (device layer, extensometer);
- strain_life: at three strain amplitudes per material (the example's steel, and a 7075-T6-like
  aluminium with cyclic softening nobody tuned for), the stabilised stress amplitude against the
  virtual material's cyclic curve, K′ and n′ fitted by htm.fatigue.strainlife against the truth,
  and the 50 % load-drop life against the virtual specimen's hidden one;
- staircase: 15-specimen ISO 12107 staircases over several seeds, the estimate against the virtual
  fatigue strength at 10⁷ cycles, in steps;
- sn_campaign: 5 levels × 6 specimens fitted by htm sn fit's E739/ML.

    .venv/bin/python benchmarks/life_tests.py [--quick]
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from htm import core
from htm.campaign import life as life_campaign
from htm.fatigue import lifetest
from htm.fatigue.sn import sn_fit
from htm.fatigue.staircase import dixon_mood
from htm.fatigue.strainlife import ENData, en_fit

ROOT = Path(__file__).resolve().parents[1]
ALUMINIUM = dict(e_pa=71e9, k_prime_pa=977e6, n_prime=0.106, sigma_f_pa=1466e6, b=-0.143, eps_f=0.262, c=-0.619,
                 fracture_toughness_pa_sqrt_m=29e6, transient=0.2, transient_cycles=30.0)


def runout() -> dict:
    spec = lifetest.load(ROOT / "examples" / "force_life.toml").with_(life_factor=1.0)
    cfg = {**spec.config, "amplitude": 250e6 * spec.area_m2}
    t0 = time.perf_counter()
    o = core.run_life(cfg)
    jump_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    f = core.run_life({**cfg, "jump": False, "runout_cycles": 300})
    full_s = time.perf_counter() - t0
    return {"cycles": o["cycles"], "end_reason": o["end_reason"], "cycles_simulated": o["cycles_simulated"], "wall_s": jump_s,
            "goal_s": 10.0, "met": jump_s <= 10.0 and o["end_reason"] == "runout",
            "peer_full_fidelity_s_extrapolated": full_s / f["cycles"] * o["cycles"], "peer_full_fidelity_cycles_per_s": f["cycles"] / full_s}


def strain(name: str, material: dict, amps: list[float]) -> dict:
    spec = lifetest.load(ROOT / "examples" / "strain_life.toml").with_(life_factor=1.0, **material)
    c = spec.config
    t0 = time.perf_counter()
    outs = core.run_life_batch([{**c, "amplitude": a} for a in amps])
    wall = time.perf_counter() - t0
    rows, sa, ep, n = [], [], [], []
    for a, o in zip(amps, outs, strict=True):
        st = lifetest.stabilised(o)
        truth = core.cyclic_stress(a, c["e_pa"], c["k_prime_pa"], c["n_prime"])
        rows.append({"strain_amplitude": a, "stress_amplitude_pa": st["stress_amplitude_pa"], "cyclic_curve_pa": truth,
                     "stress_err_pct": 100 * (st["stress_amplitude_pa"] / truth - 1), "end_reason": o["end_reason"],
                     "n_drop50": o["n_drop50"], "true_n50": o["truth"]["n_phi50"],
                     "life_err_pct": 100 * (o["n_drop50"] / o["truth"]["n_phi50"] - 1) if o["n_drop50"] else None,
                     "cycles_simulated": o["cycles_simulated"]})
        sa.append(st["stress_amplitude_pa"])
        ep.append(st["plastic_strain_amplitude"])
        n.append(o["cycles"])
    fit = en_fit(ENData(np.array(amps), np.array(n, float), np.array(sa), np.array(ep), c["e_pa"], np.zeros(len(amps), bool), name))
    k_err = 100 * (10 ** fit.cyclic.p / c["k_prime_pa"] - 1)
    n_err = 100 * (fit.cyclic.q / c["n_prime"] - 1)
    ok = all(abs(r["stress_err_pct"]) < 3 and r["life_err_pct"] is not None and abs(r["life_err_pct"]) < 2 for r in rows)
    return {"material": name, "levels": rows, "k_prime_err_pct": k_err, "n_prime_err_pct": n_err, "wall_s": wall,
            "met": ok and abs(k_err) < 10 and abs(n_err) < 10}


def strain_on_rig(amps: list[float]) -> dict:
    """The strain-life acceptance on the rig path: each amplitude a strain_life test through
    `htm.Session` on the virtual rig (python-can's virtual bus, the simulated DAQ, the extensometer
    an analog channel), the controller the core's LifeMachine one control period at a time, the
    end by the 50 % load-drop criterion on the measured rows. The rig's bar keeps its own truth
    the spec does not know (K′ × 1.1, its own life factor and crack law: `[virtual.specimen]`);
    the stabilised loops are judged against that bar's cyclic curve, K′ and n′ fitted by
    htm.fatigue.strainlife against it, the detected life against the bar's own N50 (its
    stiffness halved by its crack, in the cycles it counted). A short-life bar (a_init 0.3 mm,
    a fast short-crack law) so every cycle is resolved in minutes."""
    from htm.control.session import Session
    from htm.devices.config import virtual_config
    from htm.devices.rig import true_bar

    doc = {
        "specimen": {"geometry": "round_bar", "diameter_m": 6.35e-3, "gauge_length_m": 0.025, "a_init_m": 0.3e-3, "load_train_n_m": 5e8},
        "material": {"youngs_modulus_pa": 200e9, "cyclic_k_prime_pa": 1200e6, "cyclic_n_prime": 0.14,
                     "fatigue_strength_coefficient_pa": 1000e6, "fatigue_strength_exponent": -0.09,
                     "fatigue_ductility_coefficient": 0.1, "fatigue_ductility_exponent": -0.6, "cyclic_transient": 0.0,
                     "fracture_toughness_pa_sqrt_m": 150e6, "life_scatter_log10": 0.0},
        "law": {"law": "paris", "c": 1e-20, "m": 2.0},
        "loading": {"mode": "strain_life", "strain_amplitude": amps[0], "r_ratio": -1.0, "frequency_hz": 5.0, "control_rate_hz": 500.0},
        "end": {"drop": 0.5, "separation": 0.1, "runout_cycles": 100_000},
        "record": {"loops_per_decade": 5},
    }
    rows, sa, ep, n = [], [], [], []
    truth_cfg: dict = {}
    t0 = time.perf_counter()
    for k, a in enumerate(amps):
        doc["loading"]["strain_amplitude"] = a
        spec = lifetest.parse(doc, f"en_rig_{a}")
        cfg = virtual_config("lockstep", 500.0, analog={"channels": {"extensometer": "ai7"}},
                             virtual={"specimen": {"k_prime_factor": 1.1, "life_scatter_log10": 0.2, "seed": 21 + k, "c_factor": 1.3}})
        s = Session().open(cfg, virtual=True, specimen=spec, thread=False)
        try:
            truth_cfg = true_bar(cfg, spec.config)
            s.step(5)
            s.start(spec, record=False)
            lp = s.loop
            per = lp.ctrl.info()["samples_per_cycle"]
            while lp.ctrl.state != "stopped" and lp.powered and lp.ctrl.cycle < 20_000:
                s.step(50 * per)
            life = lp.ctrl.cycle
            end = lp.ctrl.end_reason
            table = s.cycles_since(0)
            n50_true = s.rig.bar.truth()["n_phi50"]
            events = [e["message"] for e in s.events_since(0) if e["kind"] in ("trip", "fault", "stop")]
        finally:
            s.close()
        mid = min(table, key=lambda r: abs(r["cycle"] - life / 2))
        e_a = 0.5 * (mid["strain_max"] - mid["strain_min"])
        s_a = 0.5 * (mid["stress_max_pa"] - mid["stress_min_pa"])
        curve = core.cyclic_stress(e_a, truth_cfg["e_pa"], truth_cfg["k_prime_pa"], truth_cfg["n_prime"])
        rows.append({"strain_amplitude_set": a, "strain_amplitude_measured": e_a, "stress_amplitude_pa": s_a,
                     "rig_cyclic_curve_pa": curve, "stress_err_pct": 100 * (s_a / curve - 1), "end_reason": end, "cycles": life,
                     "rig_true_n50": n50_true, "life_err_pct": 100 * (life / n50_true - 1), "events": events[-3:]})
        sa.append(s_a)
        ep.append(0.5 * mid["plastic_strain_range"])
        n.append(life)
    fit = en_fit(ENData(np.array(amps), np.array(n, float), np.array(sa), np.array(ep), truth_cfg["e_pa"], np.zeros(len(amps), bool), "rig"))
    k_err = 100 * (10 ** fit.cyclic.p / truth_cfg["k_prime_pa"] - 1)
    n_err = 100 * (fit.cyclic.q / truth_cfg["n_prime"] - 1)
    ok = all(abs(r["stress_err_pct"]) < 3 and r["end_reason"] == "load_drop" and abs(r["life_err_pct"]) < 2 for r in rows)
    return {"path": "htm.Session on the virtual rig (device layer, extensometer channel)", "levels": rows,
            "rig_true_k_prime_pa": truth_cfg["k_prime_pa"], "k_prime_fitted_pa": 10 ** fit.cyclic.p, "k_prime_err_pct": k_err,
            "rig_true_n_prime": truth_cfg["n_prime"], "n_prime_fitted": fit.cyclic.q, "n_prime_err_pct": n_err,
            "wall_s": time.perf_counter() - t0, "met": ok and abs(k_err) < 10 and abs(n_err) < 10}


def strain_on_core_loop(amps: list[float]) -> dict:
    """The strain-life acceptance on the rig's control loop without the device layer: the core's
    LifeController stepped one control period at a time against `core.LifeRig`'s sensors
    (`lifetest.run_on_rig`; tests/test_life.py runs it), every cycle resolved (a rig
    cannot jump), so on a bar whose short crack grows fast enough to finish in minutes (a_init
    0.3 mm, Paris C 1e-28, no scatter)."""
    spec = lifetest.load(ROOT / "examples" / "strain_life.toml").with_(life_factor=1.0, transient=0.0, a_init_m=0.3e-3, paris_c=1e-28)
    c = spec.config
    rows, sa, ep, n = [], [], [], []
    t0 = time.perf_counter()
    for a in amps:
        sp = spec.with_(amplitude=a)
        rig = core.LifeRig(sp.config)
        r = lifetest.run_on_rig(sp, rig)
        t = r["table"]
        i = int(np.argmin(np.abs(t["cycle"] - 0.5 * r["cycles"])))
        s_a = 0.5 * (t["fmax_n"][i] - t["fmin_n"][i]) / sp.area_m2
        truth = core.cyclic_stress(a, c["e_pa"], c["k_prime_pa"], c["n_prime"])
        n50 = int(t["cycle"][np.flatnonzero(t["events"] & 2048)[0]]) if (t["events"] & 2048).any() else None
        true50 = core.virtual_life(sp.config)[1]
        rows.append({"strain_amplitude": a, "end_reason": r["end_reason"], "cycles": r["cycles"], "stress_err_pct": 100 * (s_a / truth - 1),
                     "n_drop50": n50, "virtual_n50": true50, "life_err_pct": 100 * (n50 / true50 - 1) if n50 else None})
        sa.append(s_a)
        ep.append(0.5 * t["plastic_strain_range"][i])
        n.append(r["cycles"])
    fit = en_fit(ENData(np.array(amps), np.array(n, float), np.array(sa), np.array(ep), c["e_pa"], np.zeros(len(amps), bool), "rig"))
    return {"levels": rows, "k_prime_err_pct": 100 * (10 ** fit.cyclic.p / c["k_prime_pa"] - 1),
            "n_prime_err_pct": 100 * (fit.cyclic.q / c["n_prime"] - 1), "wall_s": time.perf_counter() - t0,
            "truth_note": "virtual_n50: the virtual specimen's life at the cyclic curve's loop without a controller"}



def staircase(seeds: list[int]) -> dict:
    spec = lifetest.load(ROOT / "examples" / "force_life.toml")
    step = 15e6
    truth = life_campaign.true_strength(spec, 1e7)
    runs = []
    for s in seeds:
        d = life_campaign.staircase_campaign(spec, 380e6, step, 15, s)
        est = dixon_mood(d.stress_pa, d.runout, step)
        runs.append({"seed": s, "strength_pa": est.strength_pa, "error_steps": (est.strength_pa - truth) / step})
    within = sum(abs(r["error_steps"]) <= 1 for r in runs)
    return {"true_strength_pa": truth, "step_pa": step, "specimens": 15, "runs": runs, "within_one_step": within, "of": len(runs)}


def sn_campaign() -> dict:
    spec = lifetest.load(ROOT / "examples" / "force_life.toml")
    t0 = time.perf_counter()
    d = life_campaign.sn_campaign(spec, [330e6, 350e6, 380e6, 420e6, 460e6], 6, seed=1)
    wall = time.perf_counter() - t0
    f = sn_fit(d).to_json()
    return {"specimens": len(d.stress_pa), "failures": d.n_failures, "runouts": d.n_runouts, "wall_s": wall,
            "fit": {k: f[k] for k in ("method", "a", "b", "sigma_log10_n") if k in f}}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="one staircase seed")
    ap.add_argument("--rig", action="store_true", help="only the strain-life acceptance through htm.Session on the virtual rig (≈ 1-2 min)")
    a = ap.parse_args()
    if a.rig:
        print(json.dumps({"strain_life_on_rig": strain_on_rig([0.004, 0.006, 0.008])}, indent=2))
        return
    out = {"runout": runout(),
           "strain_life": [strain("steel (example)", {}, [0.004, 0.006, 0.01]),
                           strain("aluminium 7075-T6-like, softening (not tuned)", ALUMINIUM, [0.005, 0.007, 0.01])],
           "staircase": staircase([1] if a.quick else [1, 2, 3, 4, 5]),
           "sn_campaign": sn_campaign()}
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
