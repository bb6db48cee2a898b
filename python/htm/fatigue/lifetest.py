"""Life tests on the simulated rig: ``mode = "force_life"`` (constant force amplitude to failure,
ASTM E466 / ISO 1099) and ``mode = "strain_life"`` (strain control with an extensometer, ASTM
E606 / ISO 12106), run by the core's life engine (`core.run_life`) on the virtual round bar.

A spec is TOML, SI throughout (``htm run examples/strain_life.toml --out DIR``)::

    [specimen]  geometry = "round_bar", diameter_m, gauge_length_m, a_init_m, load_train_n_m
    [material]  the virtual specimen's hidden truth: youngs_modulus_pa, cyclic_k_prime_pa,
                cyclic_n_prime, fatigue_strength_coefficient_pa (σf′), fatigue_strength_exponent (b),
                fatigue_ductility_coefficient (εf′), fatigue_ductility_exponent (c),
                cyclic_transient (h: K′ starts at (1+h)K′), cyclic_transient_cycles,
                fracture_toughness_pa_sqrt_m, life_scatter_log10 (σ of log10 N), seed
    [law]       the short crack's Paris law: c [(m/cycle)/(Pa·√m)^m], m
    [loading]   mode, stress_amplitude_pa or force_amplitude_n (force_life) / strain_amplitude
                (strain_life), r_ratio, frequency_hz, control_rate_hz
    [end]       drop (0.5 / 0.1: the tensile peak's drop from its stabilised trend under strain
                control, the secant stiffness's under force control; 0 = off),
                modulus_ratio_drop (0 = off), separation, runout_cycles
    [record]    loops_per_decade
    [run]       mode = "jump" | "full"

Outputs: ``cycles.parquet`` (the per-cycle table), ``loops.parquet`` (hysteresis loops kept at
logarithmic intervals, every sample), ``summary.json`` and ``summary.txt``.
"""
from __future__ import annotations

import json
import math
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from htm import core
from htm.errors import HtmError, SpecError, SpecParameterError

LIFE_MODES = ("force_life", "strain_life")

# spec key -> core key, per table
_MATERIAL = {
    "youngs_modulus_pa": "e_pa", "cyclic_k_prime_pa": "k_prime_pa", "cyclic_n_prime": "n_prime",
    "fatigue_strength_coefficient_pa": "sigma_f_pa", "fatigue_strength_exponent": "b",
    "fatigue_ductility_coefficient": "eps_f", "fatigue_ductility_exponent": "c", "cyclic_transient": "transient",
    "cyclic_transient_cycles": "transient_cycles", "fracture_toughness_pa_sqrt_m": "fracture_toughness_pa_sqrt_m",
}
_SPECIMEN = {"diameter_m": "diameter_m", "gauge_length_m": "gauge_length_m", "a_init_m": "a_init_m", "load_train_n_m": "load_train_n_m"}
_END = {"drop": "drop", "modulus_ratio_drop": "modulus_ratio_drop", "separation": "separation", "runout_cycles": "runout_cycles"}


@dataclass
class LifeSpec:
    """A validated life test: `config` is the core's dict (SI)."""

    name: str
    mode: str
    config: dict[str, Any]
    life_scatter_log10: float
    seed: int | None

    @property
    def area_m2(self) -> float:
        return math.pi / 4 * self.config.get("diameter_m", 6.35e-3) ** 2

    def with_(self, **changes: Any) -> LifeSpec:
        """A copy with core keys changed (amplitude, life_factor, ...)."""
        return LifeSpec(self.name, self.mode, {**self.config, **changes}, self.life_scatter_log10, self.seed)


def is_life(doc: dict) -> bool:
    """The document is a life test (its ``[loading] mode`` is force_life or strain_life)."""
    ld = doc.get("loading")
    return isinstance(ld, dict) and ld.get("mode") in LIFE_MODES


def _num(d: dict, key: str, where: str, lo: float | None = None, hi: float | None = None) -> float:
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
        raise SpecError(f"{where}.{key} = {v!r} must be a finite number")
    v = float(v)
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise SpecParameterError(f"{where}.{key}", v, f"[{lo if lo is not None else '-inf'}, {hi if hi is not None else 'inf'}]")
    return v


def _copy(src: dict, names: dict[str, str], where: str, out: dict[str, Any]) -> None:
    unknown = sorted(set(src) - set(names))
    if unknown:
        raise SpecError(f"{where}: unknown key{'s' if len(unknown) > 1 else ''} {', '.join(unknown)}; allowed: {', '.join(sorted(names))}")
    for k, ck in names.items():
        if k in src:
            out[ck] = _num(src, k, where)


def parse(doc: dict, name: str = "test") -> LifeSpec:
    """Validate a parsed TOML document of a life test (raises SpecError naming the field)."""
    unknown = sorted(set(doc) - {"specimen", "material", "law", "loading", "end", "record", "run"})
    if unknown:
        raise SpecError(f"spec: unknown table{'s' if len(unknown) > 1 else ''} {', '.join(unknown)} for a life test")
    cfg: dict[str, Any] = {}
    sp = dict(doc.get("specimen", {}))
    geometry = sp.pop("geometry", "round_bar")
    if geometry != "round_bar":
        raise SpecError(f"specimen.geometry = {geometry!r}: a life test runs a round_bar")
    _copy(sp, _SPECIMEN, "specimen", cfg)
    mat = dict(doc.get("material", {}))
    sigma = _num(mat, "life_scatter_log10", "material", 0.0, 2.0) if "life_scatter_log10" in mat else 0.0
    mat.pop("life_scatter_log10", None)
    seed = mat.pop("seed", None)
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or seed < 0):
        raise SpecError(f"material.seed = {seed!r} must be a non-negative integer")
    life_factor = mat.pop("life_factor", None)
    _copy(mat, _MATERIAL, "material", cfg)
    law = dict(doc.get("law", {}))
    kind = law.pop("law", "paris")
    if kind != "paris":
        raise SpecError(f"law.law = {kind!r}: the virtual specimen's short crack grows by a paris law")
    _copy(law, {"c": "paris_c", "m": "paris_m"}, "law", cfg)
    ld = dict(doc.get("loading", {}))
    mode = ld.pop("mode", None)
    if mode not in LIFE_MODES:
        raise SpecError(f"loading.mode = {mode!r}: one of {', '.join(LIFE_MODES)}")
    cfg["mode"] = mode
    amp_keys = ("stress_amplitude_pa", "force_amplitude_n") if mode == "force_life" else ("strain_amplitude",)
    given = [k for k in amp_keys if k in ld]
    if len(given) != 1:
        raise SpecError(f"loading: mode {mode} takes one of {', '.join(amp_keys)}")
    amp = _num(ld, given[0], "loading", 0.0)
    ld.pop(given[0])
    area = math.pi / 4 * cfg.get("diameter_m", 6.35e-3) ** 2
    cfg["amplitude"] = amp * area if given[0] == "stress_amplitude_pa" else amp
    _copy(ld, {"r_ratio": "r_ratio", "frequency_hz": "frequency_hz", "control_rate_hz": "control_rate_hz",
               "mean_cycles": "mean_cycles", "amplitude_cycles": "amplitude_cycles"}, "loading", cfg)
    end = dict(doc.get("end", {}))
    _copy(end, _END, "end", cfg)
    rec = dict(doc.get("record", {}))
    _copy(rec, {"loops_per_decade": "loops_per_decade"}, "record", cfg)
    run = dict(doc.get("run", {}))
    rmode = run.pop("mode", "jump")
    if rmode not in ("jump", "full"):
        raise SpecError(f"run.mode = {rmode!r}: one of jump, full")
    _copy(run, {"rtol": "rtol"}, "run", cfg)
    cfg["jump"] = rmode == "jump"
    if life_factor is not None:
        cfg["life_factor"] = _num({"life_factor": life_factor}, "life_factor", "material", 1e-6, 1e6)
    else:
        cfg["life_factor"] = specimen_life_factor(sigma, seed)
    spec = LifeSpec(name, mode, cfg, sigma, seed)
    try:
        core.virtual_life(spec.config)  # the core judges every value (ParameterError names the field)
    except core.ParameterError as e:
        raise SpecParameterError(_spec_field(str(e.field)), float(e.value), str(e.allowed)) from None
    return spec


def _spec_field(field: str) -> str:
    """The spec's path of a core field (`material.n_prime` → `material.cyclic_n_prime`)."""
    section, _, key = field.partition(".")
    names = {"material": _MATERIAL, "specimen": _SPECIMEN, "end": _END}.get(section, {})
    back = {v: k for k, v in names.items()}
    if section == "law":
        back = {"c": "c", "m": "m"}
    return f"{section}.{back.get(key, key)}" if key else field


def specimen_life_factor(sigma_log10: float, seed: int | None) -> float:
    """The specimen's life factor 10^(σ·z), z a standard normal draw from `seed` (1 without scatter)."""
    if sigma_log10 <= 0.0:
        return 1.0
    z = float(np.random.default_rng(seed).standard_normal())
    return float(10.0 ** (sigma_log10 * z))


def load(path: str | Path) -> LifeSpec:
    p = Path(path)
    try:
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
        raise SpecError(f"{p}: not a TOML spec ({str(e).splitlines()[0]})") from None
    except OSError as e:
        raise SpecError(f"{p}: {e.strerror}") from None
    return parse(doc, p.stem)


def run(spec: LifeSpec, params: core.Params | None = None) -> tuple[dict[str, Any], float]:
    """Run the test (the GIL released); returns (the core's result, wall seconds)."""
    t0 = time.perf_counter()
    out = core.run_life(spec.config, params)
    return out, time.perf_counter() - t0


def stabilised(out: dict[str, Any]) -> dict[str, float]:
    """The loop at half the life (the E606 stabilised loop): stress and strain amplitudes, plastic
    strain range, from the resolved cycle nearest N/2 (jump rows excluded)."""
    t = out["table"]
    ok = (t["events"] & 16) == 0
    cyc = t["cycle"][ok]
    if len(cyc) == 0:
        return {}
    i = int(np.argmin(np.abs(cyc - 0.5 * out["cycles"])))
    g = {k: t[k][ok][i] for k in ("stress_max_pa", "stress_min_pa", "strain_max", "strain_min", "plastic_strain_range")}
    return {"cycle": int(cyc[i]), "stress_amplitude_pa": float(0.5 * (g["stress_max_pa"] - g["stress_min_pa"])),
            # (no extensometer: the strain columns hold their empty sentinels, the amplitude is unknown)
            "strain_amplitude": float(0.5 * (g["strain_max"] - g["strain_min"])) if g["strain_max"] >= g["strain_min"] else math.nan,
            "plastic_strain_amplitude": float(0.5 * g["plastic_strain_range"])}


def summary(spec: LifeSpec, out: dict[str, Any], wall: float) -> dict[str, Any]:
    tr = out["truth"]
    return {
        "name": spec.name, "mode": spec.mode, "end_reason": out["end_reason"], "failed": bool(out["failed"]),
        "cycles": int(out["cycles"]), "n_drop10": out["n_drop10"], "n_drop50": out["n_drop50"], "n_modulus": out["n_modulus"],
        "cycles_simulated": int(out["cycles_simulated"]), "wall_s": wall, "stabilised": stabilised(out),
        "amplitude": spec.config["amplitude"], "stress_amplitude_pa": spec.config["amplitude"] / spec.area_m2 if spec.mode == "force_life" else None,
        "strain_amplitude": spec.config["amplitude"] if spec.mode == "strain_life" else None,
        "truth": {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in tr.items()},
        "loops_kept": sorted({int(c) for c in out["loops"]["cycle"]}),
    }


def summary_text(s: dict[str, Any]) -> str:
    st = s["stabilised"]
    lines = [f"{s['name']}: {s['mode']}, ended by {s['end_reason']} at {s['cycles']:,} cycles"
             f" ({s['cycles_simulated']:,} simulated, {s['wall_s']:.2f} s)"]
    if st:
        lines.append(f"stabilised loop (cycle {st['cycle']:,}):  stress amplitude {st['stress_amplitude_pa'] / 1e6:8.1f} MPa"
                     f"   strain amplitude {st['strain_amplitude'] * 100:7.4f} %   plastic {st['plastic_strain_amplitude'] * 100:7.4f} %")
    for k, label in (("n_drop10", "10 % drop"), ("n_drop50", "50 % drop")):
        if s[k] is not None:
            lines.append(f"{label:>10} at {s[k]:>12,} cycles")
    return "\n".join(lines)


def write_outputs(out_dir: Path, spec: LifeSpec, out: dict[str, Any], wall: float) -> dict[str, Any]:
    import pyarrow as pa
    import pyarrow.parquet as pq

    out_dir.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.table(out["table"]), out_dir / "cycles.parquet")
    pq.write_table(pa.table(out["loops"]), out_dir / "loops.parquet")
    s = summary(spec, out, wall)
    (out_dir / "summary.json").write_text(json.dumps(s, indent=2) + "\n", encoding="utf-8")
    (out_dir / "summary.txt").write_text(summary_text(s) + "\n", encoding="utf-8")
    return s


def cmd_run(spec_path: str, out: str | None, as_json: bool, check: bool = False, store: Any = None) -> int:
    """`htm run SPEC --out DIR` for a life test (`out` None with `check`: check the spec only);
    `store(spec, result, wall)`, when given, records the test and returns its id."""
    from htm.terminal import emit_json

    if check:
        spec = load(spec_path)
        n = core.virtual_life(spec.config)
        if as_json:
            emit_json({"name": spec.name, "mode": spec.mode, "ok": True})
        else:
            print(f"{spec.name}: {spec.mode} spec ok (the virtual specimen, life factor {spec.config['life_factor']:.3g}: "
                  f"initiation at {n[0]:,.0f} cycles, separation at {n[2]:,.0f})")
        return 0
    if not out:
        raise HtmError("--out DIR is required")
    spec = load(spec_path)
    out_dir = Path(out)
    if (out_dir / "summary.json").exists():
        raise HtmError(f"{out_dir} already holds a test (summary.json); choose another --out")
    res, wall = run(spec)
    s = write_outputs(out_dir, spec, res, wall)
    if store is not None:
        s["test_id"] = store(spec, res, wall)
    if as_json:
        emit_json(dict(s, out=str(out_dir)))
    else:
        print(summary_text(s))
        if "test_id" in s:
            print(f"store: test {s['test_id']}")
        print(f"outputs: {out_dir}/summary.json, cycles.parquet, loops.parquet, summary.txt")
    return 0


def is_life_file(path: str | Path) -> bool:
    """The spec file is a life test (unreadable files are left to the crack-growth path's errors)."""
    try:
        return is_life(tomllib.loads(Path(path).read_text(encoding="utf-8")))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return False


def run_on_rig(spec: LifeSpec, rig: Any, max_cycles: int | None = None) -> dict[str, Any]:
    """A life test on a rig, one control period at a time: `rig` offers ``measure()`` and
    ``step(u, dt)`` → (force [N], extensometer strain, piston position [m]) (the virtual rig
    `core.LifeRig`, or a device layer with the same two calls). The controller is the core's
    `LifeController`, the code `run_life` runs; every cycle is resolved (no jump on a rig).
    Returns the per-cycle rows as columns, the end reason and the cycle count."""
    f, e, _ = rig.measure()
    ctl = core.LifeController(spec.config, f, e)
    rows: list[dict[str, Any]] = []
    limit = max_cycles if max_cycles is not None else int(spec.config.get("runout_cycles", 1e7))
    while ctl.end_reason is None and ctl.cycle < limit:
        while not ctl.at_end():
            f, e, y = rig.measure()
            rig.step(ctl.command(f, e, y), ctl.dt)
        rows.append(ctl.close())
        ctl.next_cycle()
    cols = {k: np.array([r[k] for r in rows]) for k in rows[0]} if rows else {}
    return {"table": cols, "end_reason": ctl.end_reason, "cycles": ctl.cycle}
