"""Life-test campaigns on the simulated rig: an S-N campaign (force_life specimens over stress
levels, or strain_life specimens over strain levels for an ε-N curve, each specimen with its own
life factor drawn from the material's scatter) and a staircase (ISO 12107 up-and-down: each
specimen's level follows the last outcome, one step down after a failure, one up after a run-out).

They run as every campaign does (`engine.py`): through `htm campaign` on the local cores or a Dask
cluster (`--cluster`), each test a row of the store's campaign table (SQLite or PostgreSQL), and a
re-started campaign runs only what the store does not hold. An S-N campaign's specimens are all
known in advance, so they run in chunks side by side; a staircase's next level depends on the last
outcome, so it runs one specimen at a time — one task on the cluster, its row written before the
next level is chosen — and a re-start replays the held outcomes to find where it stopped.

A campaign is TOML (``htm campaign examples/campaign_sn.toml --out DIR``)::

    [life_campaign]
    kind = "sn"                 # or "staircase"
    name = "sn-steel"           # optional (default: the file's name)
    test = "force_life.toml"    # a force_life or strain_life spec (relative to this file)
    seed = 1
    chunk_tests = 4             # sn: specimens per task
    levels_pa = [...]           # sn of force_life specimens: stress amplitudes [Pa]
    levels_strain = [...]       # sn of strain_life specimens: strain amplitudes [m/m]
    specimens_per_level = 6     # sn
    start_pa = 360e6            # staircase (force_life): first level [Pa]
    step_pa = 15e6              # staircase: step [Pa]
    specimens = 15              # staircase

Outputs in DIR: ``sn.csv`` / ``en.csv`` / ``staircase.csv`` (what ``htm sn fit``, ``htm en fit`` and
``htm sn staircase`` read), their ``fit.json`` and report (the same files those commands write from
that CSV), ``campaign.parquet`` (the store's table) and ``summary.json`` (with the virtual truth).
"""
from __future__ import annotations

import copy
import csv
import json
import math
import time
import tomllib
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from htm import core
from htm.campaign import engine
from htm.campaign.spec import DEFAULT_CHUNK_TESTS, Campaign, _hash, _slug
from htm.errors import HtmError, SpecError
from htm.fatigue import lifetest
from htm.fatigue.sn import SNData, write_sn_csv

# the campaign field of each test's level, by mode; the specimen's life factor
AMPLITUDE = {"force_life": "loading.stress_amplitude_pa", "strain_life": "loading.strain_amplitude"}
FACTOR = "material.life_factor"
LEVELS_KEY = {"force_life": "levels_pa", "strain_life": "levels_strain"}


def is_life_campaign(path: str | Path) -> bool:
    try:
        return "life_campaign" in tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return False


def life_factors(spec: lifetest.LifeSpec, n: int, seed: int) -> np.ndarray:
    """Per-specimen life factors 10^(σ·z) of `n` specimens from `seed`."""
    z = np.random.default_rng(seed).standard_normal(n)
    return 10.0 ** (spec.life_scatter_log10 * z)


def specimen_config(spec: lifetest.LifeSpec, level: float, life_factor: float) -> dict[str, Any]:
    """The core's config of one specimen at `level` (stress amplitude [Pa] under force control,
    strain amplitude under strain control) with its life factor."""
    amp = level * spec.area_m2 if spec.mode == "force_life" else level
    return {**spec.config, "amplitude": float(amp), "life_factor": float(life_factor)}


def _inputs(spec: lifetest.LifeSpec, level: float, life_factor: float) -> dict[str, float]:
    return {AMPLITUDE[spec.mode]: float(level), FACTOR: float(life_factor)}


@dataclass
class LifeCampaign:
    """A life campaign: the engine's plan (`campaign`; a staircase's grows as it runs) and what
    the sequence and the analysis need."""

    kind: str  # sn | staircase
    spec: lifetest.LifeSpec
    campaign: Campaign
    factors: np.ndarray
    seed: int
    test_path: str = ""
    levels: list[float] = field(default_factory=list)  # sn
    per_level: int = 0  # sn
    start: float = 0.0  # staircase
    step: float = 0.0
    n: int = 0

    @property
    def runout_cycles(self) -> float:
        return float(self.spec.config.get("runout_cycles", 1e7))


def _check_level(spec: lifetest.LifeSpec, level: float, where: str) -> None:
    sf = spec.config.get("sigma_f_pa")
    if spec.mode == "force_life" and sf and level >= sf:
        raise SpecError(f"{where} = {level:g}: at or above the material's σf′ = {sf / 1e6:.0f} MPa (fatigue_strength_coefficient_pa): "
                        "no fatigue life there; give stress amplitudes in Pa")
    try:  # the core judges the whole test at this level (its validation runs before the first cycle)
        core.run_life({**specimen_config(spec, level, 1.0), "runout_cycles": 1})
    except core.ParameterError as e:
        raise SpecError(f"{where} = {level:g}: the test's {e.field} = {e.value:g} is outside {e.allowed}") from None


def sn_plan(spec: lifetest.LifeSpec, levels: list[float], per_level: int, seed: int, name: str = "sn",
            chunk_tests: int = DEFAULT_CHUNK_TESTS, path: Path = Path("."), text: str = "", base_text: str = "") -> LifeCampaign:
    """`per_level` specimens at each level, life factors drawn from `seed` in plan order."""
    for x in levels:
        _check_level(spec, x, f"life_campaign.{LEVELS_KEY[spec.mode]}")
    s = np.repeat(np.asarray(levels, float), per_level)
    lf = life_factors(spec, len(s), seed)
    ident = {"kind": "sn", "levels": [float(x) for x in levels], "per_level": per_level, "seed": seed, "config": spec.config}
    c = Campaign(id=f"{_slug(name)}-{_hash(ident)[:10]}", name=name, path=path, text=text, base_text=base_text, mode=spec.mode,
                 chunk_tests=chunk_tests, swept=[AMPLITUDE[spec.mode]], scattered=[FACTOR],
                 inputs=[_inputs(spec, x, f) for x, f in zip(s, lf)], docs=[specimen_config(spec, x, f) for x, f in zip(s, lf)])
    return LifeCampaign("sn", spec, c, lf, seed, levels=[float(x) for x in levels], per_level=per_level)


def staircase_plan(spec: lifetest.LifeSpec, start: float, step: float, n: int, seed: int, name: str = "staircase",
                   path: Path = Path("."), text: str = "", base_text: str = "") -> LifeCampaign:
    """A staircase of `n` specimens from `start` by `step`: its tests are planned one at a time."""
    if spec.mode != "force_life":
        raise SpecError(f"{spec.name}: a staircase runs force_life specimens (stress levels), not {spec.mode}")
    if not 0 < step < start:
        raise SpecError(f"life_campaign.step_pa = {step:g} must be positive and below start_pa = {start:g}")
    _check_level(spec, start, "life_campaign.start_pa")
    ident = {"kind": "staircase", "start": start, "step": step, "n": n, "seed": seed, "config": spec.config}
    c = Campaign(id=f"{_slug(name)}-{_hash(ident)[:10]}", name=name, path=path, text=text, base_text=base_text, mode=spec.mode,
                 chunk_tests=1, swept=[AMPLITUDE[spec.mode]], scattered=[FACTOR], inputs=[], docs=[], planned=n)
    return LifeCampaign("staircase", spec, c, life_factors(spec, n, seed), seed, start=start, step=step, n=n)


def _outcome(row: dict[str, Any], where: str) -> tuple[float, bool]:
    """(cycles, run-out) of a test's row, or an HtmError naming the specimen."""
    if row.get("error"):
        raise HtmError(f"{where}: {row['error']}")
    if not row["valid"]:
        raise HtmError(f"{where}: the test ended by {row['end_reason']}, neither a failure nor a run-out")
    return float(row["life_cycles"]), row["end_reason"] == "runout"


def _where(lc: LifeCampaign, i: int) -> str:
    x = lc.campaign.inputs[i][AMPLITUDE[lc.spec.mode]]
    return f"specimen {i + 1} at {x / 1e6:.1f} MPa" if lc.spec.mode == "force_life" else f"specimen {i + 1} at ε_a {x:.4g}"


def staircase_steps(lc: LifeCampaign, run_one: Callable[[int], dict[str, Any]]) -> list[dict[str, Any]]:
    """ISO 12107's sequence: specimen i at the level the outcome of specimen i − 1 set (one step up
    after a run-out, one down after a failure); `run_one(i)` gives specimen i's row. The plan grows
    by each specimen as its level is known."""
    c, rows, level = lc.campaign, [], lc.start
    for i in range(lc.n):
        if level <= 0:
            raise SpecError(f"life_campaign: the staircase stepped down to {level / 1e6:.1f} MPa after {i} failures; "
                            "start_pa or step_pa is wrong")
        if i == len(c.inputs):
            c.inputs.append(_inputs(lc.spec, level, lc.factors[i]))
            c.docs.append(specimen_config(lc.spec, level, lc.factors[i]))
        row = run_one(i)
        _, runout = _outcome(row, _where(lc, i))
        rows.append(row)
        level = level + lc.step if runout else level - lc.step
    return rows


# ---- in memory (benchmarks, tests): the same tests through the same chunk runner -----------------

def _run_local(lc: LifeCampaign, threads: int = 0) -> list[dict[str, Any]]:
    c = lc.campaign
    if lc.kind == "sn":
        return engine.run_chunk(list(enumerate(c.docs)), c.mode, threads)
    return staircase_steps(lc, lambda i: engine.run_chunk([(i, c.docs[i])], c.mode, 1)[0])


def sn_campaign(spec: lifetest.LifeSpec, levels_pa: list[float], per_level: int, seed: int, threads: int = 0) -> SNData:
    """Run `per_level` specimens at each level on the local cores: the S-N data set."""
    lc = sn_plan(spec, levels_pa, per_level, seed)
    return sn_data(lc, _run_local(lc, threads))


def staircase_campaign(spec: lifetest.LifeSpec, start_pa: float, step_pa: float, n: int, seed: int) -> SNData:
    """ISO 12107 up-and-down: each specimen at the level the last outcome set."""
    lc = staircase_plan(spec, start_pa, step_pa, n, seed)
    return sn_data(lc, _run_local(lc))


# ---- on the store, here or on the cluster ----------------------------------------------------------

def run(lc: LifeCampaign, store: Any, runner: Callable[[list[engine.Chunk], str], Iterable[list[dict[str, Any]]]],
        progress: bool = True) -> dict[str, Any]:
    """Run what the store does not hold yet with `runner` (`engine.local_runner` or
    `cluster.runner`); returns the session's counts as `engine.run` does."""
    if lc.kind == "sn":
        return engine.run(lc.campaign, store, runner, progress)
    from htm.terminal import Progress

    c = lc.campaign
    engine.register(store, c)
    have = engine.held(store, c.id)
    stored = {r["idx"]: r for r in engine.table(store, c.id)} if have else {}
    bar = Progress(lc.n, "specimens", f"staircase {c.id}", start=len(have)) if progress else None
    t0, ran = time.perf_counter(), 0

    def run_one(i: int) -> dict[str, Any]:
        nonlocal ran
        if i in have:  # held: the outcome replayed, after checking it is this specimen's
            engine.check_held(c, i, have[i])
            return stored[i]
        rows = [r for chunk in runner([[(i, c.docs[i])]], c.mode) for r in chunk]  # one specimen, one task
        ran += engine.write(store, c, rows)
        if bar:
            bar.update(i + 1)
        return rows[0]

    try:
        staircase_steps(lc, run_one)
    finally:
        if bar:
            bar.close()
    wall = time.perf_counter() - t0
    return {"campaign": c.id, "tests": lc.n, "skipped": len(have), "ran": ran, "wall_s": wall,
            "tests_per_s": ran / wall if wall > 0 and ran else 0.0}


def sn_data(lc: LifeCampaign, rows: list[dict[str, Any]]) -> SNData:
    """The S-N (or staircase) data of a campaign's rows in plan order."""
    key = AMPLITUDE[lc.spec.mode]
    out = [_outcome(r, _where(lc, i)) for i, r in enumerate(rows)]
    what = "staircase" if lc.kind == "staircase" else "S-N campaign"
    return SNData(np.array([lc.campaign.inputs[i][key] for i in range(len(rows))]), np.array([o[0] for o in out]),
                  np.array([o[1] for o in out], bool), f"{what} of {lc.spec.name}")


EN_COLUMNS = ("strain_amplitude", "cycles", "stress_amplitude_pa", "plastic_strain_amplitude", "runout")


def write_en_csv(path: Path, lc: LifeCampaign, rows: list[dict[str, Any]]) -> Path:
    """A strain_life campaign's rows as `htm en fit`'s CSV: the strain amplitude, the life, the
    stabilised loop's stress and plastic strain amplitudes (measured at half the life), run-out."""
    d = sn_data(lc, rows)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(EN_COLUMNS)
        for ea, n, ro, r in zip(d.stress_pa, d.cycles, d.runout, rows):
            st = r["results"]["stabilised"]
            w.writerow([f"{ea:.6g}", f"{n:.6g}", f"{st['stress_amplitude_pa']:.6g}", f"{st['plastic_strain_amplitude']:.6g}", int(ro)])
    return path


def true_life(spec: lifetest.LifeSpec, level: float) -> float:
    """The virtual material's median life [cycles] at `level` (life factor 1): to separation under
    force control, to the 50 % drop under strain control."""
    n_init, n50, n_sep = core.virtual_life(specimen_config(spec, level, 1.0))
    return n_sep if spec.mode == "force_life" else n50


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


def outputs(lc: LifeCampaign, rows: list[dict[str, Any]], out: Path) -> dict[str, Any]:
    """The data CSV, its fit.json and report (as `htm sn fit` / `htm en fit` / `htm sn staircase`
    write them from that CSV) and summary.json, from the store's rows of the campaign."""
    from htm.fatigue.sn_cli import en_fit_files, sn_fit_files, staircase_files

    spec, c = lc.spec, lc.campaign
    out.mkdir(parents=True, exist_ok=True)
    d = sn_data(lc, rows)
    s: dict[str, Any] = {"kind": lc.kind, "mode": spec.mode, "campaign": c.id, "test": lc.test_path, "seed": lc.seed,
                         "runout_cycles": lc.runout_cycles, "specimens": len(rows), "failures": d.n_failures, "runouts": d.n_runouts}
    fit_doc: dict[str, Any] | None = None
    try:
        if lc.kind == "staircase":
            data = write_sn_csv(out / "staircase.csv", d)
            fit_doc, est, _, _ = staircase_files(data, out, lc.step)
            truth = true_strength(spec, lc.runout_cycles)
            s.update(estimate=est.to_json(), true_strength_pa=truth, error_steps=(est.strength_pa - truth) / lc.step)
        elif spec.mode == "force_life":
            data = write_sn_csv(out / "sn.csv", d)
            fit_doc = sn_fit_files(data, out)[0]
        else:
            data = write_en_csv(out / "en.csv", lc, rows)
            fit_doc = en_fit_files(data, out)[0]
    except SpecError as e:  # too few failures for a curve: the data stay, the reason is said
        s["fit_error"] = str(e)
    s["data"] = str(data)
    s["fit"] = str(out / "fit.json") if fit_doc is not None else None
    if lc.kind == "sn":
        s["truth"] = {"life_at_levels": {f"{x:.6g}": true_life(spec, x) for x in lc.levels}}
    (out / "summary.json").write_text(json.dumps(s, indent=2) + "\n", encoding="utf-8")
    return s


def summary_lines(s: dict[str, Any]) -> list[str]:
    if s["kind"] == "staircase":
        e = s["estimate"]
        return [f"staircase: {s['specimens']} specimens, fatigue strength {e['fatigue_strength_pa'] / 1e6:.1f} MPa "
                f"(sd {e['sd_pa'] / 1e6:.1f} MPa); virtual truth {s['true_strength_pa'] / 1e6:.1f} MPa "
                f"({s['error_steps']:+.2f} steps) -> {s['data']}, {s['fit']}"]
    what = "S-N" if s["mode"] == "force_life" else "ε-N"
    lines = [f"{what} campaign: {s['specimens']} specimens, {s['failures']} failures, {s['runouts']} run-outs -> {s['data']}"]
    lines.append(f"fit: {s['fit']}" if s["fit"] else f"no fit: {s['fit_error']}")
    return lines


# ---- the campaign file ---------------------------------------------------------------------------

def _num(d: dict, k: str, where: str) -> float:
    v = d.get(k)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
        raise SpecError(f"{where}.{k} = {v!r} must be a positive number")
    return float(v)


def _int(d: dict, k: str, where: str, default: int, lo: int = 1) -> int:
    v = d.get(k, default)
    if isinstance(v, bool) or not isinstance(v, int) or v < lo:
        raise SpecError(f"{where}.{k} = {v!r} must be an integer ≥ {lo}")
    return v


def load(path: str | Path) -> LifeCampaign:
    """Read a life campaign file (raises SpecError naming the file and field)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
        doc = tomllib.loads(text)
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
        raise SpecError(f"{p}: not a campaign file ({str(e).splitlines()[0]})") from None
    where = "life_campaign"
    c = doc.get("life_campaign")
    if not isinstance(c, dict):
        raise SpecError(f"{p}: [{where}] must be a table")
    allowed = {"kind", "name", "test", "seed", "chunk_tests", "levels_pa", "levels_strain", "specimens_per_level",
               "start_pa", "step_pa", "specimens"}
    bad = sorted(set(c) - allowed)
    if bad:
        raise SpecError(f"{p}: unknown key(s) {', '.join(bad)} in [{where}]; allowed: {', '.join(sorted(allowed))}")
    kind = c.get("kind")
    if kind not in ("sn", "staircase"):
        raise SpecError(f"{p}: {where}.kind = {kind!r}: one of sn, staircase")
    test = c.get("test")
    if not isinstance(test, str):
        raise SpecError(f"{p}: {where}.test is missing: the force_life or strain_life spec the specimens run")
    test_path = p.parent / test
    spec = lifetest.load(test_path)
    base_text = test_path.read_text(encoding="utf-8")
    name = c.get("name", p.stem)
    if not isinstance(name, str) or not name.strip():
        raise SpecError(f"{p}: {where}.name = {name!r} must be a short name")
    try:
        seed = _int(c, "seed", where, 0, 0)
        if kind == "sn":
            key = LEVELS_KEY[spec.mode]
            other = LEVELS_KEY["strain_life" if spec.mode == "force_life" else "force_life"]
            if other in c:
                raise SpecError(f"{where}.{other}: the test {test} is {spec.mode}; give its levels as {key}")
            levels = c.get(key)
            if (not isinstance(levels, list) or len(levels) < 2
                    or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and x > 0 for x in levels)):
                unit = "stresses [Pa]" if spec.mode == "force_life" else "strain amplitudes [m/m]"
                raise SpecError(f"{where}.{key} must list at least two positive {unit}")
            return _with_file(sn_plan(spec, [float(x) for x in levels], _int(c, "specimens_per_level", where, 6), seed, name,
                                      _int(c, "chunk_tests", where, DEFAULT_CHUNK_TESTS), p, text, base_text), test_path)
        lc = staircase_plan(spec, _num(c, "start_pa", where), _num(c, "step_pa", where), _int(c, "specimens", where, 15, 2),
                            seed, name, p, text, base_text)
        return _with_file(lc, test_path)
    except SpecError as e:
        raise SpecError(f"{p}: {e}") from None


def _with_file(lc: LifeCampaign, test_path: Path) -> LifeCampaign:
    lc.test_path = str(test_path)
    return lc


def parquet_rows(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The rows flattened for campaign.parquet (the life results' scalars as columns)."""
    flat = []
    for r in rows:
        d = {k: v for k, v in r.items() if k != "results"}
        res = copy.deepcopy(r.get("results") or {})
        for k, v in res.pop("stabilised", {}).items():
            d[f"stabilised_{k}"] = v
        for k, v in res.pop("truth", {}).items():
            d[f"truth_{k}"] = v
        d.update(res)
        flat.append(d)
    return flat
