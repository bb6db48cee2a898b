"""Life-test campaigns on the simulated rig: an S-N campaign (force_life specimens over stress
levels, each with its own life factor drawn from the material's scatter) and a staircase
(ISO 12107 up-and-down: each specimen's level follows the last outcome, one step down after a
failure, one up after a run-out — one specimen at a time, as on the rig).

A campaign is TOML (``htm campaign examples/campaign_sn.toml --out DIR``)::

    [life_campaign]
    kind = "sn"                 # or "staircase"
    test = "force_life.toml"    # a force_life spec (relative to this file): material, specimen, end
    seed = 1
    levels_pa = [...]           # sn: stress amplitudes [Pa]
    specimens_per_level = 6     # sn
    start_pa = 360e6            # staircase: first level [Pa]
    step_pa = 15e6              # staircase: step [Pa]
    specimens = 15              # staircase

Outputs: ``sn.csv`` / ``staircase.csv`` (``stress_amplitude_pa, cycles, runout``: what ``htm sn
fit`` and ``htm sn staircase`` read) and ``summary.json`` (with the virtual truth).
"""
from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from htm import core
from htm.errors import HtmError, SpecError
from htm.fatigue import lifetest
from htm.fatigue.sn import SNData, write_sn_csv
from htm.fatigue.staircase import dixon_mood


def is_life_campaign(path: str | Path) -> bool:
    try:
        return "life_campaign" in tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return False


def life_factors(spec: lifetest.LifeSpec, n: int, seed: int) -> np.ndarray:
    """Per-specimen life factors 10^(σ·z) of `n` specimens from `seed`."""
    z = np.random.default_rng(seed).standard_normal(n)
    return 10.0 ** (spec.life_scatter_log10 * z)


def _stress_spec(spec: lifetest.LifeSpec, stress_pa: float, life_factor: float) -> dict[str, Any]:
    if spec.mode != "force_life":
        raise SpecError(f"{spec.name}: an S-N or staircase campaign runs force_life specimens, not {spec.mode}")
    return {**spec.config, "amplitude": stress_pa * spec.area_m2, "life_factor": float(life_factor)}


def _outcome(res: Any, where: str) -> tuple[float, bool]:
    if isinstance(res, BaseException):
        raise HtmError(f"{where}: {res}")
    if res["end_reason"] not in ("runout", "separation", "load_drop", "modulus_ratio"):
        raise HtmError(f"{where}: the test ended by {res['end_reason']}, neither a failure nor a run-out")
    return float(res["cycles"]), res["end_reason"] == "runout"


def sn_campaign(spec: lifetest.LifeSpec, levels_pa: list[float], per_level: int, seed: int, threads: int = 0) -> SNData:
    """Run `per_level` specimens at each level on the local cores: the S-N data set."""
    s = np.repeat(np.asarray(levels_pa, float), per_level)
    lf = life_factors(spec, len(s), seed)
    outs = core.run_life_batch([_stress_spec(spec, x, f) for x, f in zip(s, lf)], None, threads)
    cyc, ro = zip(*(_outcome(o, f"specimen {i + 1} at {x / 1e6:.1f} MPa") for i, (o, x) in enumerate(zip(outs, s))))
    return SNData(s, np.array(cyc), np.array(ro, bool), f"S-N campaign of {spec.name}")


def staircase_campaign(spec: lifetest.LifeSpec, start_pa: float, step_pa: float, n: int, seed: int) -> SNData:
    """ISO 12107 up-and-down: each specimen at the level the last outcome set."""
    lf = life_factors(spec, n, seed)
    s, cyc, ro = [], [], []
    level = start_pa
    for i in range(n):
        c, r = _outcome(core.run_life(_stress_spec(spec, level, lf[i])), f"specimen {i + 1} at {level / 1e6:.1f} MPa")
        s.append(level)
        cyc.append(c)
        ro.append(r)
        level = level + step_pa if r else level - step_pa
    return SNData(np.array(s), np.array(cyc), np.array(ro, bool), f"staircase of {spec.name}")


def true_life(spec: lifetest.LifeSpec, stress_pa: float) -> float:
    """The virtual material's median life [cycles] at `stress_pa` (to separation, life factor 1)."""
    return core.virtual_life(_stress_spec(spec, stress_pa, 1.0))[2]


def true_strength(spec: lifetest.LifeSpec, cycles: float) -> float:
    """The virtual material's median fatigue strength [Pa] at `cycles` (bisection in log stress)."""
    lo, hi = 10e6, spec.config.get("sigma_f_pa", 1600e6)
    for _ in range(60):
        mid = math.sqrt(lo * hi)
        if true_life(spec, mid) > cycles:
            lo = mid
        else:
            hi = mid
    return math.sqrt(lo * hi)


def _num(d: dict, k: str, where: str) -> float:
    v = d.get(k)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
        raise SpecError(f"{where}.{k} = {v!r} must be a positive number")
    return float(v)


def run_file(path: str | Path, out: Path, threads: int = 0) -> dict[str, Any]:
    p = Path(path)
    try:
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
        raise SpecError(f"{p}: not a campaign file ({str(e).splitlines()[0]})") from None
    c = doc["life_campaign"]
    where = "life_campaign"
    kind = c.get("kind")
    if kind not in ("sn", "staircase"):
        raise SpecError(f"{where}.kind = {kind!r}: one of sn, staircase")
    test = c.get("test")
    if not isinstance(test, str):
        raise SpecError(f"{where}.test is missing: the force_life spec the specimens run")
    spec = lifetest.load(p.parent / test)
    seed = int(c.get("seed", 0))
    runout = float(spec.config.get("runout_cycles", 1e7))
    out.mkdir(parents=True, exist_ok=True)
    s: dict[str, Any] = {"kind": kind, "test": str(p.parent / test), "seed": seed, "runout_cycles": runout}
    if kind == "sn":
        levels = c.get("levels_pa")
        if not isinstance(levels, list) or len(levels) < 2 or not all(isinstance(x, (int, float)) and x > 0 for x in levels):
            raise SpecError(f"{where}.levels_pa must list at least two positive stresses [Pa]")
        per = int(c.get("specimens_per_level", 6))
        d = sn_campaign(spec, [float(x) for x in levels], per, seed, threads)
        csv = write_sn_csv(out / "sn.csv", d)
        s.update(specimens=len(d.stress_pa), failures=d.n_failures, runouts=d.n_runouts, data=str(csv),
                 truth={"life_at_levels": {f"{x:.6g}": true_life(spec, float(x)) for x in levels}})
    else:
        start, step = _num(c, "start_pa", where), _num(c, "step_pa", where)
        n = int(c.get("specimens", 15))
        d = staircase_campaign(spec, start, step, n, seed)
        csv = write_sn_csv(out / "staircase.csv", d)
        est = dixon_mood(d.stress_pa, d.runout, step)
        truth = true_strength(spec, runout)
        s.update(specimens=n, data=str(csv), estimate=est.to_json(), true_strength_pa=truth,
                 error_steps=(est.strength_pa - truth) / step)
    (out / "summary.json").write_text(json.dumps(s, indent=2) + "\n", encoding="utf-8")
    return s


def cmd(args: Any) -> int:
    """`htm campaign FILE --out DIR` for a life campaign."""
    from htm.terminal import emit_json

    out = Path(args.out or f"out/{Path(args.campaign).stem}")
    s = run_file(args.campaign, out, getattr(args, "threads", 0))
    if getattr(args, "json", False):
        emit_json(s)
        return 0
    if s["kind"] == "sn":
        print(f"S-N campaign: {s['specimens']} specimens, {s['failures']} failures, {s['runouts']} run-outs -> {s['data']}"
              f"  (fit: htm sn fit {s['data']} --out DIR)")
    else:
        e = s["estimate"]
        print(f"staircase: {s['specimens']} specimens, fatigue strength {e['fatigue_strength_pa'] / 1e6:.1f} MPa "
              f"(sd {e['sd_pa'] / 1e6:.1f} MPa); virtual truth {s['true_strength_pa'] / 1e6:.1f} MPa "
              f"({s['error_steps']:+.2f} steps) -> {s['data']}")
    return 0
