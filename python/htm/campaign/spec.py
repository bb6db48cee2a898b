"""Campaign files: a base test spec plus sweeps and material scatter, expanded into a plan of tests.

A campaign file (TOML, SI) names a base test spec (`examples/ct_constant_force.toml`) and changes
fields of it by their dotted path in that spec (`loading.delta_f_n`, `law.c`,
`rig.overrides.supply_pressure_pa`):

    [campaign]   name, base (path relative to this file), mode (full | jump), chunk_tests, seed
    [grid]       "FIELD" = [values...]          every combination
    [lhs]        samples = N, "FIELD" = [lo, hi]  a Latin hypercube of N points, each combined with every grid point
    [scatter]    samples = M, "FIELD" = { lognormal_sigma = s } | { normal_sd = s }
                 M Monte Carlo draws of material scatter around each point (lognormal multiplies the
                 base value by exp(N(0, s²)), normal adds N(0, s²))
    [scatter.joint]  fields = [...], mean = [...], cov = [[...]], log10 = [...]: fields drawn together
                 from one multivariate normal (a Paris law's log10 C and m, strongly correlated)

The plan is fixed by the file (and its seed): the same file gives the same tests in the same order,
which is what lets a re-started campaign skip what the store already holds. Every test's spec goes
through the test spec's own validation before anything runs, so a sweep outside a field's range is
reported naming the field.
"""
from __future__ import annotations

import copy
import hashlib
import itertools
import json
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from htm import spec as test_spec
from htm.errors import SpecError
from htm.inputs import read_text

DEFAULT_CHUNK_TESTS = 8
MAX_TESTS = 1_000_000  # a plan larger than this is a typo, not a campaign


@dataclass
class Campaign:
    """A campaign expanded into its tests: `inputs[i]` are the changed fields of test i (SI),
    `docs[i]` its whole test spec document (plain TOML data, picklable for cluster workers)."""

    id: str
    name: str
    path: Path
    text: str
    base_text: str
    mode: str
    chunk_tests: int
    swept: list[str]  # fields set by [grid] / [lhs]
    scattered: list[str]  # fields drawn by [scatter]
    inputs: list[dict[str, float]]
    docs: list[dict[str, Any]]
    # tests planned when the plan grows as it runs (a staircase: each level follows the last
    # outcome); None: the plan is `inputs`
    planned: int | None = None

    def __len__(self) -> int:
        return len(self.inputs)

    def inputs_hash(self, i: int) -> str:
        return _hash(self.inputs[i])

    def chunks(self, todo: list[int]) -> list[list[int]]:
        """The test indices `todo` cut into tasks of `chunk_tests` tests."""
        return [todo[k:k + self.chunk_tests] for k in range(0, len(todo), self.chunk_tests)]


def _hash(obj: Any) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=float).encode()).hexdigest()


def _set(doc: dict, path: str, value: float) -> None:
    """Set `doc[a][b][c] = value` for path "a.b.c" (tables created when missing: rig.overrides)."""
    keys = path.split(".")
    d = doc
    for k in keys[:-1]:
        nxt = d.setdefault(k, {})
        if not isinstance(nxt, dict):
            raise SpecError(f"campaign: field `{path}`: `{k}` is a value in the base spec, not a table")
        d = nxt
    d[keys[-1]] = value


def _get(doc: dict, path: str) -> Any:
    d: Any = doc
    for k in path.split("."):
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


def _number(v: Any, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
        raise SpecError(f"campaign: {where} = {v!r} must be a finite number (SI)")
    return float(v)


def _table(doc: dict, key: str) -> dict:
    v = doc.get(key, {})
    if not isinstance(v, dict):
        raise SpecError(f"campaign: [{key}] must be a table")
    return v


def _grid(doc: dict) -> dict[str, list[float]]:
    out = {}
    for f, vals in _table(doc, "grid").items():
        if not isinstance(vals, list) or not vals:
            raise SpecError(f"campaign: grid `{f}` must be a non-empty list of values")
        out[f] = [_number(v, f"grid `{f}`") for v in vals]
    return out


def _lhs(doc: dict) -> tuple[int, dict[str, tuple[float, float]]]:
    t = dict(_table(doc, "lhs"))
    if not t:
        return 1, {}
    n = t.pop("samples", None)
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise SpecError(f"campaign: lhs.samples = {n!r} must be a positive integer")
    ranges = {}
    for f, r in t.items():
        if not (isinstance(r, list) and len(r) == 2):
            raise SpecError(f"campaign: lhs `{f}` must be a range [lo, hi], got {r!r}")
        lo, hi = (_number(v, f"lhs `{f}`") for v in r)
        if not lo < hi:
            raise SpecError(f"campaign: lhs `{f}` = [{lo:g}, {hi:g}] needs lo < hi")
        ranges[f] = (lo, hi)
    if not ranges:
        raise SpecError("campaign: [lhs] names no field to sample")
    return n, ranges


def _scatter(doc: dict) -> tuple[int, dict[str, tuple[str, float]], dict[str, Any] | None]:
    t = dict(_table(doc, "scatter"))
    if not t:
        return 1, {}, None
    n = t.pop("samples", None)
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise SpecError(f"campaign: scatter.samples = {n!r} must be a positive integer")
    joint = _joint(t.pop("joint")) if "joint" in t else None
    laws = {}
    for f, d in t.items():
        if not (isinstance(d, dict) and len(d) == 1 and next(iter(d)) in ("lognormal_sigma", "normal_sd")):
            raise SpecError(f"campaign: scatter `{f}` must be {{ lognormal_sigma = s }} or {{ normal_sd = s }}, got {d!r}")
        kind, s = next(iter(d.items()))
        s = _number(s, f"scatter `{f}`.{kind}")
        if s < 0:
            raise SpecError(f"campaign: scatter `{f}`.{kind} = {s:g} must be ≥ 0")
        laws[f] = (kind, s)
    if not laws and joint is None:
        raise SpecError("campaign: [scatter] names no field to draw")
    return n, laws, joint


def _joint(t: Any) -> dict[str, Any]:
    """[scatter.joint]: fields drawn together from a multivariate normal (their correlation kept,
    e.g. a Paris law's log10 C and m): `fields`, `mean`, `cov`, optional `log10` flags (the normal
    is then of log10 of that field)."""
    where = "campaign: [scatter.joint]"
    if not isinstance(t, dict) or set(t) - {"fields", "mean", "cov", "log10"} or not {"fields", "mean", "cov"} <= set(t):
        raise SpecError(f"{where} needs fields, mean, cov (and optionally log10)")
    fields = t["fields"]
    k = len(fields) if isinstance(fields, list) else 0
    if k == 0 or not all(isinstance(f, str) for f in fields):
        raise SpecError(f"{where}.fields must be a list of field names")
    mean = np.array([_number(v, f"{where}.mean") for v in t["mean"]]) if isinstance(t["mean"], list) else np.zeros(0)
    cov_rows = t["cov"] if isinstance(t["cov"], list) else []
    cov = np.array([[_number(v, f"{where}.cov") for v in row] for row in cov_rows if isinstance(row, list)])
    log10 = t.get("log10", [False] * k)
    if len(mean) != k or cov.shape != (k, k) or not (isinstance(log10, list) and len(log10) == k):
        raise SpecError(f"{where}: mean needs {k} values, cov {k}×{k}, log10 {k} flags (one per field)")
    try:
        chol = np.linalg.cholesky(cov) if np.allclose(cov, cov.T) else None
    except np.linalg.LinAlgError:
        chol = None
    if chol is None:
        raise SpecError(f"{where}.cov must be symmetric positive definite")
    return {"fields": list(fields), "mean": mean, "chol": chol, "log10": [bool(x) for x in log10]}


def latin_hypercube(n: int, ranges: dict[str, tuple[float, float]], rng: np.random.Generator) -> list[dict[str, float]]:
    """`n` points with each field's range cut into n equal strata, each stratum used once."""
    cols = {}
    for f, (lo, hi) in ranges.items():
        u = (rng.permutation(n) + rng.random(n)) / n
        cols[f] = lo + u * (hi - lo)
    return [{f: float(cols[f][i]) for f in ranges} for i in range(n)]


def _check(doc: dict, name: str, where: str) -> None:
    try:
        test_spec.parse(doc, name).params()
    except SpecError as e:
        raise SpecError(f"campaign: {where}: {e}") from None


def parse(text: str, path: Path) -> Campaign:
    """Expand a campaign file's text into its tests (raises SpecError naming the problem)."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise SpecError(f"campaign file {path}: not valid TOML ({e})") from None
    unknown = sorted(set(doc) - {"campaign", "grid", "lhs", "scatter"})
    if unknown:
        raise SpecError(f"campaign file {path}: unknown table(s) {', '.join(unknown)}; allowed: campaign, grid, lhs, scatter")
    head = _table(doc, "campaign")
    bad = sorted(set(head) - {"name", "base", "mode", "chunk_tests", "seed"})
    if bad:
        raise SpecError(f"campaign: unknown key(s) {', '.join(bad)} in [campaign]; allowed: name, base, mode, chunk_tests, seed")
    name = head.get("name")
    if not isinstance(name, str) or not name.strip():
        raise SpecError("campaign: [campaign] name is missing (a short name for the table)")
    if not isinstance(head.get("base"), str):
        raise SpecError("campaign: [campaign] base is missing (the test spec TOML it varies)")
    base_path = (path.parent / head["base"]).resolve()
    base_text = read_text(base_path, "base spec ([campaign] base)", SpecError)
    try:
        base = tomllib.loads(base_text)
    except tomllib.TOMLDecodeError as e:
        raise SpecError(f"campaign: base spec {base_path}: not valid TOML ({e})") from None
    _check(base, name, f"base spec {base_path.name}")
    base_spec = test_spec.parse(base, name)
    mode = head.get("mode", base_spec.mode)
    if mode not in ("full", "jump"):
        raise SpecError(f"campaign: mode = {mode!r}: use \"full\" or \"jump\"")
    chunk = head.get("chunk_tests", DEFAULT_CHUNK_TESTS)
    if isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
        raise SpecError(f"campaign: chunk_tests = {chunk!r} must be a positive integer")
    seed = head.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise SpecError(f"campaign: seed = {seed!r} must be a non-negative integer")

    grid = _grid(doc)
    n_lhs, ranges = _lhs(doc)
    n_mc, laws, joint = _scatter(doc)
    drawn = set(laws) | set(joint["fields"] if joint else [])
    twice = (set(grid) & set(ranges)) | ((set(grid) | set(ranges)) & drawn) | (set(laws) & set(joint["fields"] if joint else []))
    if twice:
        raise SpecError(f"campaign: field(s) {', '.join(sorted(twice))} appear in more than one of [grid], [lhs], [scatter]")
    n_grid = int(np.prod([len(v) for v in grid.values()])) if grid else 1
    total = n_grid * n_lhs * n_mc
    if total > MAX_TESTS:
        raise SpecError(f"campaign: {total:,} tests planned ({n_grid} grid × {n_lhs} lhs × {n_mc} scatter); at most {MAX_TESTS:,}")

    # each swept value alone first: an out-of-range sweep is reported naming its field and value
    for f, vals in grid.items():
        for v in (min(vals), max(vals)):
            d = copy.deepcopy(base)
            _set(d, f, v)
            _check(d, name, f"grid `{f}` = {v:g}")
    for f, (lo, hi) in ranges.items():
        for v in (lo, hi):
            d = copy.deepcopy(base)
            _set(d, f, v)
            _check(d, name, f"lhs `{f}` = {v:g}")
    for f in laws:
        if not isinstance(_get(base, f), (int, float)):
            raise SpecError(f"campaign: scatter `{f}`: the base spec has no number there to scatter around")

    rng = np.random.default_rng(seed)
    lhs_points = latin_hypercube(n_lhs, ranges, rng) if ranges else [{}]
    grid_points = [dict(zip(grid, combo)) for combo in itertools.product(*grid.values())] if grid else [{}]
    inputs, docs = [], []
    for g in grid_points:
        for h in lhs_points:
            point = {**g, **h}
            for _ in range(n_mc):
                inp = dict(point)
                for f, (kind, s) in laws.items():
                    z = float(rng.standard_normal())
                    b = float(_get(base, f))
                    inp[f] = b * float(np.exp(s * z)) if kind == "lognormal_sigma" else b + s * z
                if joint:
                    x = joint["mean"] + joint["chol"] @ rng.standard_normal(len(joint["fields"]))
                    for f, v, lg in zip(joint["fields"], x, joint["log10"]):
                        inp[f] = float(10.0 ** v) if lg else float(v)
                d = copy.deepcopy(base)
                for f, v in inp.items():
                    _set(d, f, v)
                inputs.append(inp)
                docs.append(d)
    # every test as it will run: combinations can be invalid where each value alone is not
    for i, d in enumerate(docs):
        _check(d, f"{name}[{i}]", f"test {i} ({', '.join(f'{k} = {v:g}' for k, v in inputs[i].items())})")

    ident = {k: v for k, v in doc.items() if k != "campaign"} | {"seed": seed, "name": name}
    cid = f"{_slug(name)}-{_hash({'campaign': ident, 'base': base, 'mode': mode})[:10]}"
    return Campaign(id=cid, name=name, path=path, text=text, base_text=base_text, mode=mode, chunk_tests=chunk,
                    swept=list(grid) + list(ranges), scattered=list(laws) + (joint["fields"] if joint else []), inputs=inputs, docs=docs)


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "-" for c in name.strip())[:40]


def load(path: str | Path) -> Campaign:
    """Read and expand a campaign file (raises SpecError naming the problem)."""
    p = Path(path)
    text = read_text(p, "campaign", SpecError)
    try:
        return parse(text, p)
    except SpecError as e:  # the file named in front, once
        raise type(e)(str(e) if str(p) in str(e) else f"{p}: {e}") from None


def on_model(c: Campaign, model: str | Path) -> Campaign:
    """The campaign on the twin of `model` (`htm campaign --model`): every test's document runs on
    the identified plant — the model's base parameters and findings as the `base` preset's
    overrides, with what the test itself overrides of its rig (a swept supply pressure) on top —
    and with the controller the rig would run (`htm.twin.twin_config`'s velocity gain). Its id
    names the model, so the store keeps it apart from the campaign on the nominal rig."""
    import dataclasses

    from htm import spec as test_spec
    from htm.ident.plant import load_twin
    from htm.ident.predict import ModelError
    from htm.params import with_overrides
    from htm.twin import keff_ratio, rig_velocity_gain

    docs = []
    twin_hash = None
    for i, d in enumerate(c.docs):
        spec = test_spec.parse(d, f"{c.name}[{i}]", c.path.parent, check=False)
        twin, info = load_twin(str(model), test_spec.build_config(dataclasses.replace(spec, rig_overrides={})).params)
        if twin.valve_map[0]:
            raise ModelError(f"model {info['path']} has a valve map (knots): a campaign's test documents carry scalar "
                             "parameters only; run its tests one by one with `htm run --model`")
        twin = with_overrides(twin, spec.rig_overrides)
        doc = copy.deepcopy(d)
        doc["rig"] = {"preset": "base", "overrides": twin.to_dict()}
        kv = rig_velocity_gain(spec)
        if kv is not None:
            doc.setdefault("controller", {"type": spec.controller["type"]})["velocity_gain_m_s_per_v"] = kv * keff_ratio(spec, twin)
        docs.append(doc)
        twin_hash = twin_hash or _hash(info)[:8]
    return dataclasses.replace(c, id=f"{c.id}-twin-{twin_hash}", docs=docs)
