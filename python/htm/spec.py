"""Fatigue test specifications: TOML in, a validated `TestSpec` and its one `core.TestConfig` out.

Every value is SI (names carry units). This module reads the document's structure (tables, unknown
keys, types, the spectrum file); the core judges every value it runs on (`core.TestConfig`, built
once per spec, naming a bad value by the spec's own path). Errors raise `SpecError` before
anything runs; a value out of range raises `SpecParameterError` with `.field`, `.value`, `.allowed`.
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from htm import core
from htm.errors import HtmError, InfeasibleTest, ParameterError, SpecError, SpecParameterError
from htm.feasibility import Feasibility, assess
from htm.inputs import close_match, missing, read_text
from htm.params import thesis_rig, with_overrides

MODES = ("constant_force", "constant_delta_k", "k_gradient")
WAVEFORMS = ("sine", "triangle", "trapezoid")
MAX_COUNT = 10**12  # cycle counts (far beyond any test, far inside the core's u64)
# every default and range below is the core's (`htm.core`): stated here only to check a spec early
DEFAULTS = core.TEST_DEFAULTS
R_LO, R_HI = core.TEST_R_RATIO_RANGE


@dataclass
class Loading:
    mode: str
    r_ratio: float
    end_a_m: float
    tolerance: float
    delta_f_n: float | None = None
    delta_k_pa_sqrt_m: float | None = None
    k_gradient_per_m: float = 0.0


@dataclass
class TestSpec:
    """A whole fatigue crack growth test, validated (see examples/ct_constant_force.toml).

    Made by `load_spec` from a TOML file (or `htm.spec.parse` from a dict); every field is SI.

    Attributes
    ----------
    name : str
        The test's name (the TOML file's stem).
    geometry : str
        Specimen type, ``"ct"`` or ``"mt"``.
    width_m, thickness_m, a0_m : float
        Specimen width W, thickness B and initial crack size a0 [m].
    material : dict of str to float
        Young's modulus [Pa], Poisson's ratio [-], yield strength [Pa], fracture toughness [Pa·√m].
    law : dict
        Crack-growth law (Paris, Forman or NASGRO) with its coefficients, SI (da/dN in m/cycle,
        ΔK in Pa·√m).
    waveform : str
        Load waveform (``"sine"``, ...); `frequency_hz` its frequency [Hz], `control_rate_hz`
        the controller's sample rate [Hz].
    phases : list of Loading
        Loading phases: constant ΔF [N] or a ΔK schedule [Pa·√m], stress ratio R, end crack size [m].
    controller, end, start : dict
        Force controller, end conditions (``max_cycles``, ...) and ramp-in (cycles).
    mode : str
        ``"full"`` (every cycle through the plant) or ``"jump"`` (cycle-jump).
    override_limits : bool
        ``[run] override_limits``: run even what the feasibility check refuses (`feasibility`);
        the summary and report then state the force error the test reached.
    """

    name: str
    geometry: str
    width_m: float
    thickness_m: float
    a0_m: float
    material: dict[str, float]
    law: dict[str, Any]
    waveform: str
    frequency_hz: float
    control_rate_hz: float
    phases: list[Loading]
    controller: dict[str, Any]
    end: dict[str, Any]
    start: dict[str, float]
    rig_overrides: dict[str, float] = field(default_factory=dict)
    rig_preset: str = "thesis"
    waveform_shape: dict[str, float] = field(default_factory=dict)
    rtol: float = DEFAULTS["rtol"]
    mode: str = "jump"
    stiffness_steps: list[tuple[int, float]] = field(default_factory=list)
    # variable-amplitude loading ([variable_amplitude]): blocks (cycles, ΔF [N], R), or a spectrum
    # of (peak, valley) [N] pairs, one cycle each; applied in turn and repeated to the end
    blocks: list[tuple[int, float, float]] = field(default_factory=list)
    spectrum: list[tuple[float, float]] = field(default_factory=list)
    override_limits: bool = False
    # the identified model the test runs on instead of the nominal rig (`htm run --model`):
    # `htm.ident.plant.describe` of its model.json, None for the spec's own rig
    twin: dict[str, Any] | None = None
    # [measurement]: where the test's crack size comes from (crack = "compliance",
    # "potential_drop" or "model") and the gauge; keys left out are the core's defaults
    measurement: dict[str, Any] = field(default_factory=lambda: {"crack": "model"})
    # the core's configuration of this test, built once by `parse` (validated)
    config: core.TestConfig = field(init=False, repr=False, compare=False)
    _feasibility: Feasibility | None = field(default=None, init=False, repr=False, compare=False)

    def feasibility(self) -> Feasibility:
        """What the rig can do with this test (`htm.feasibility`): force, flow, frequency,
        stroke and the E647 size criterion, each with its largest feasible value (assessed once)."""
        if self._feasibility is None:
            self._feasibility = assess(self.config)
        return self._feasibility

    def params(self) -> core.Params:
        """The rig the spec names (`[rig]` preset and overrides), validated."""
        return self.config.params

    @property
    def variable_amplitude(self) -> bool:
        return bool(self.blocks or self.spectrum)


# ---- parsing helpers -------------------------------------------------------------------------

def _table(d: dict, key: str, where: str, required: bool = True) -> dict:
    v = d.get(key)
    if v is None:
        if required:
            raise SpecError(f"[{where}] is missing")
        return {}
    if not isinstance(v, dict):
        raise SpecError(f"{where} must be a table, got {v!r}")
    return v


def _keys(d: dict, allowed: set[str], where: str) -> None:
    unknown = sorted(set(d) - allowed)
    if unknown:
        meant = [(k, close_match(k, allowed - set(d))) for k in unknown]
        hint = "; ".join(f"`{k}` is perhaps `{m}`" for k, m in meant if m)
        raise SpecError(f"{where}: unknown key{'s' if len(unknown) > 1 else ''} {', '.join(unknown)}"
                        + (f" ({hint})" if hint else f"; allowed: {', '.join(sorted(allowed))}"))


def _num(d: dict, key: str, where: str, lo: float | None = None, hi: float | None = None, *, default: Any = ...,
         lo_open: bool = False, hi_open: bool = False, unit: str = "") -> float:
    if key not in d:
        if default is ...:
            raise SpecError(f"{where}.{key} is missing{missing(key, d)}")
        return default
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise SpecError(f"{where}.{key} = {v!r} must be a number{f' in {unit}' if unit else ''}")
    v = float(v)
    bad = not math.isfinite(v)
    if lo is not None:
        bad |= v <= lo if lo_open else v < lo
    if hi is not None:
        bad |= v >= hi if hi_open else v > hi
    if bad:
        rng = f"{'(' if lo_open else '['}{'-inf' if lo is None else f'{lo:g}'}, {'inf' if hi is None else f'{hi:g}'}{')' if hi_open or hi is None else ']'}"
        raise SpecParameterError(f"{where}.{key}", v, f"{rng}{f' {unit}' if unit else ''}")
    return v


def _int(d: dict, key: str, where: str, lo: int, default: int, hi: int = MAX_COUNT) -> int:
    v = d.get(key, default)
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise SpecError(f"{where}.{key} = {v!r} must be an integer in [{lo}, {hi:,}]")
    return v


def _choice(d: dict, key: str, where: str, choices: tuple[str, ...], default: str | None = None) -> str:
    v = d.get(key, default)
    if v is None:
        raise SpecError(f"{where}.{key} is missing{missing(key, d)}: one of {', '.join(choices)}")
    if v not in choices:
        raise SpecError(f"{where}.{key} = {v!r} is not allowed: one of {', '.join(choices)}")
    return v


def _loading(d: dict, where: str, end_a_m: float, tolerance: float) -> Loading:
    _keys(d, {"mode", "r_ratio", "delta_f_n", "delta_k_pa_sqrt_m", "k_gradient_per_m", "end_a_m", "tolerance"}, where)
    # the ranges of these values are the core's (`core.TestConfig`): only their presence and type here
    mode = _choice(d, "mode", where, MODES)
    ph = Loading(mode=mode, r_ratio=_num(d, "r_ratio", where), end_a_m=_num(d, "end_a_m", where, default=end_a_m),
                 tolerance=_num(d, "tolerance", where, default=tolerance))
    if mode == "constant_force":
        ph.delta_f_n = _num(d, "delta_f_n", where)
        if "delta_k_pa_sqrt_m" in d or "k_gradient_per_m" in d:
            raise SpecError(f"{where}: mode constant_force takes delta_f_n, not delta_k_pa_sqrt_m / k_gradient_per_m")
    else:
        ph.delta_k_pa_sqrt_m = _num(d, "delta_k_pa_sqrt_m", where)
        if "delta_f_n" in d:
            raise SpecError(f"{where}: mode {mode} takes delta_k_pa_sqrt_m, not delta_f_n")
        if mode == "k_gradient":
            ph.k_gradient_per_m = _num(d, "k_gradient_per_m", where)
        elif "k_gradient_per_m" in d:
            raise SpecError(f"{where}: k_gradient_per_m needs mode = \"k_gradient\"")
    return ph


def read_spectrum(path: Path) -> list[tuple[float, float]]:
    """A load spectrum file: forces [N], one reversal a line (peak, valley, peak, …) or one cycle a
    line as two columns `peak, valley` (comma or blanks); `#` starts a comment. Returns the
    (peak, valley) of every cycle; a malformed file raises SpecError naming the line."""
    lines = read_text(path, "spectrum (variable_amplitude.spectrum_file)", SpecError).splitlines()
    rows: list[tuple[int, list[float]]] = []
    for i, line in enumerate(lines, 1):
        text = line.split("#", 1)[0].replace(",", " ").split()
        if not text:
            continue
        try:
            vals = [float(x) for x in text]
        except ValueError:
            raise SpecError(f"{path}:{i}: {line.strip()!r} is not one or two numbers (forces in N)") from None
        if len(vals) not in (1, 2) or not all(math.isfinite(v) for v in vals):
            raise SpecError(f"{path}:{i}: {line.strip()!r}: one force (a reversal) or two (peak, valley) a line, finite, in N")
        rows.append((i, vals))
    if not rows:
        raise SpecError(f"{path}: no forces in the spectrum file")
    widths = {len(v) for _, v in rows}
    if len(widths) > 1:
        raise SpecError(f"{path}: mixes one-column (reversals) and two-column (peak, valley) lines")
    if widths == {2}:
        cycles = [(i, v[0], v[1]) for i, v in rows]
    else:
        if len(rows) % 2:
            raise SpecError(f"{path}: {len(rows)} reversals; a spectrum of peaks and valleys needs an even number")
        cycles = [(rows[k][0], rows[k][1][0], rows[k + 1][1][0]) for k in range(0, len(rows), 2)]
    for i, p, v in cycles:
        if not p > v:
            raise SpecError(f"{path}:{i}: peak {p:g} N must exceed its valley {v:g} N")
    return [(p, v) for _, p, v in cycles]


def _variable_amplitude(va: dict, base: Path | None) -> tuple[list[tuple[int, float, float]], list[tuple[float, float]]]:
    _keys(va, {"blocks", "spectrum_file", "spectrum"}, "variable_amplitude")
    if sum(k in va for k in ("blocks", "spectrum_file", "spectrum")) != 1:
        raise SpecError("variable_amplitude: give blocks = [[cycles, delta_f_n, r_ratio], ...], spectrum_file = \"PATH\" "
                        "or spectrum = [[peak_n, valley_n], ...] (one of them)")
    if "spectrum" in va:  # inline: what the store keeps, so a stored test needs no file beside it
        pv = va["spectrum"]
        if not (isinstance(pv, list) and pv and all(isinstance(c, list) and len(c) == 2 for c in pv)):
            raise SpecError("variable_amplitude.spectrum must be a non-empty list of [peak_n, valley_n]")
        out_pv = []
        for k, c in enumerate(pv):
            where = f"variable_amplitude.spectrum[{k}]"
            d = dict(zip(("peak_n", "valley_n"), c))
            peak, valley = _num(d, "peak_n", where, unit="N"), _num(d, "valley_n", where, unit="N")
            if not peak > valley:
                raise SpecError(f"{where}: peak {peak:g} N must exceed its valley {valley:g} N")
            out_pv.append((peak, valley))
        return [], out_pv
    if "spectrum_file" in va:
        p = Path(str(va["spectrum_file"]))
        return [], read_spectrum(p if p.is_absolute() or base is None else base / p)
    blocks = va["blocks"]
    if not (isinstance(blocks, list) and blocks and all(isinstance(b, list) and len(b) == 3 for b in blocks)):
        raise SpecError("variable_amplitude.blocks must be a non-empty list of [cycles, delta_f_n, r_ratio]")
    out = []
    for k, b in enumerate(blocks):
        where = f"variable_amplitude.blocks[{k}]"
        d = dict(zip(("cycles", "delta_f_n", "r_ratio"), b))
        out.append((_int(d, "cycles", where, 1, MAX_COUNT), _num(d, "delta_f_n", where, 0.0, lo_open=True, unit="N"),
                    _num(d, "r_ratio", where, R_LO, R_HI, hi_open=True)))
    return out, []


def parse(doc: dict, name: str = "test", base: Path | None = None, *, check: bool = True) -> TestSpec:
    """Validate a parsed TOML document into a `TestSpec` (raises SpecError); a spectrum file is
    read relative to `base` (the spec's folder).

    With `check` (the default) a test the rig cannot run raises InfeasibleTest naming the limit
    and the largest feasible value, unless the spec sets ``[run] override_limits = true``."""
    _keys(doc, {"specimen", "material", "law", "loading", "precrack", "controller", "end", "start", "rig", "run", "stiffness_steps",
                "variable_amplitude", "measurement"}, "spec")
    sp = _table(doc, "specimen", "specimen")
    _keys(sp, {"geometry", "width_m", "thickness_m", "a0_m"}, "specimen")
    geometry = _choice(sp, "geometry", "specimen", ("ct", "mt"))
    width = _num(sp, "width_m", "specimen", 0.0, 2.0, lo_open=True, unit="m")  # wider: likely mm
    thickness = _num(sp, "thickness_m", "specimen", 0.0, width, lo_open=True, unit="m")
    scale = 1.0 if geometry == "ct" else 2.0  # M(T): a is the half crack, a/W of the half width
    a0 = _num(sp, "a0_m", "specimen")
    mat = _table(doc, "material", "material")
    _keys(mat, {"youngs_modulus_pa", "poisson_ratio", "yield_strength_pa", "fracture_toughness_pa_sqrt_m"}, "material")
    material = {k: _num(mat, k, "material") for k in ("youngs_modulus_pa", "poisson_ratio", "yield_strength_pa", "fracture_toughness_pa_sqrt_m")}
    law = _table(doc, "law", "law")
    _keys(law, {"law", "c", "m", "kc", "n", "p", "q", "dk_th", "k_crit", "f_open"}, "law")
    _choice(law, "law", "law", ("paris", "forman", "nasgro"))
    end = _table(doc, "end", "end")
    _keys(end, {"a_over_w", "max_cycles", "size_criterion", "tolerance_cycles", "tolerance_action"}, "end")
    a_end = _num(end, "a_over_w", "end") * width / scale
    end_d = {"max_cycles": _int(end, "max_cycles", "end", 1, DEFAULTS["max_cycles"]),
             "size_criterion": _choice(end, "size_criterion", "end", ("flag", "stop"), DEFAULTS["size_criterion_action"]),
             "tolerance_cycles": _int(end, "tolerance_cycles", "end", 0, DEFAULTS["tolerance_cycles"]),
             "tolerance_action": _choice(end, "tolerance_action", "end", ("flag", "stop"), DEFAULTS["tolerance_action"])}
    ld = _table(doc, "loading", "loading")
    wave_keys = {"waveform", "frequency_hz", "control_rate_hz", "rise_fraction", "hold_fraction"}
    ld_main = {k: v for k, v in ld.items() if k not in wave_keys}
    waveform = _choice(ld, "waveform", "loading", WAVEFORMS, "sine")
    shape: dict[str, float] = {}
    if waveform == "trapezoid":
        shape = {k: _num(ld, k, "loading") for k in ("rise_fraction", "hold_fraction")}
    elif "rise_fraction" in ld or "hold_fraction" in ld:
        raise SpecError("loading: rise_fraction / hold_fraction need waveform = \"trapezoid\"")
    freq = _num(ld, "frequency_hz", "loading")
    rate = _num(ld, "control_rate_hz", "loading", default=DEFAULTS["control_rate_hz"])
    if "end_a_m" in ld_main:
        raise SpecError("loading.end_a_m: the test ends at [end] a_over_w")
    phases = []
    pre = _table(doc, "precrack", "precrack", required=False)
    if pre:
        if "end_a_m" not in pre:
            raise SpecError("precrack.end_a_m is missing: the crack length at which precracking ends [m]")
        phases.append(_loading(pre, "precrack", math.nan, core.PRECRACK_TOLERANCE))
    phases.append(_loading(ld_main, "loading", a_end, core.TEST_TOLERANCE))
    ctrl = _table(doc, "controller", "controller", required=False) or {"type": "demodulation"}
    # demodulation: the thesis 4.2 amplitude/mean controller (default); force_p: fixed-gain force P
    # (the thesis's comparison case); position_pff: position P + velocity feed-forward (thesis 4.1)
    keys = {"demodulation": {"velocity_gain_m_s_per_v"}, "force_p": {"kp_v_per_n", "u_offset_v"},
            "position_pff": {"velocity_gain_m_s_per_v", "kp_v_per_m", "kff_v_per_m_s", "u_offset_v"}}
    ctype = _choice(ctrl, "type", "controller", tuple(keys), "demodulation")
    _keys(ctrl, {"type"} | keys[ctype], f"controller (type {ctype})")
    controller: dict[str, Any] = {"type": ctype}
    if ctype == "force_p":
        controller["kp_v_per_n"] = _num(ctrl, "kp_v_per_n", "controller", -1.0, 1.0)
    if ctype != "demodulation":
        controller["u_offset_v"] = _num(ctrl, "u_offset_v", "controller", -10.0, 10.0, default=0.0, unit="V")
    if "velocity_gain_m_s_per_v" in ctrl:
        controller["velocity_gain_m_s_per_v"] = _num(ctrl, "velocity_gain_m_s_per_v", "controller", -10.0, 10.0, unit="m/s per V")
    for k, unit in (("kp_v_per_m", "V/m"), ("kff_v_per_m_s", "V per m/s")):
        if k in ctrl:
            controller[k] = _num(ctrl, k, "controller", -1e6, 1e6, unit=unit)
    st = _table(doc, "start", "start", required=False)
    _keys(st, {"mean_cycles", "amplitude_cycles", "stop_cycles"}, "start")
    start = {"mean_cycles": _num(st, "mean_cycles", "start", 0.0, 1e4, default=DEFAULTS["start_mean_cycles"]),
             # left out: 20 cycles or 1 s, whichever is longer (the core's `Envelope::for_frequency`)
             "amplitude_cycles": _num(st, "amplitude_cycles", "start", 0.0, 1e4, default=None),
             "stop_cycles": _num(st, "stop_cycles", "start", 0.0, 1e4, default=DEFAULTS["stop_cycles"])}
    rig = _table(doc, "rig", "rig", required=False)
    _keys(rig, {"preset", "overrides"}, "rig")
    preset = _choice(rig, "preset", "rig", ("thesis", "base"), "thesis")
    overrides = rig.get("overrides", {})
    if not isinstance(overrides, dict):
        raise SpecError("rig.overrides must be a table of parameter = value (SI)")
    run = _table(doc, "run", "run", required=False)
    _keys(run, {"mode", "rtol", "override_limits"}, "run")
    override = run.get("override_limits", False)
    if not isinstance(override, bool):
        raise SpecError(f"run.override_limits = {override!r} must be true or false")
    blocks: list[tuple[int, float, float]] = []
    spectrum: list[tuple[float, float]] = []
    va = _table(doc, "variable_amplitude", "variable_amplitude", required=False)
    if va:
        blocks, spectrum = _variable_amplitude(va, base)
        if pre:
            raise SpecError("variable_amplitude: a precrack phase is not supported with variable-amplitude loading "
                            "(precrack at constant amplitude in a test of its own)")
        if phases[-1].mode != "constant_force":
            raise SpecError("variable_amplitude: [loading] mode must be constant_force (its delta_f_n and r_ratio are the "
                            "reference level of the report)")
        if run.get("mode", "full") != "full":
            raise SpecError("variable_amplitude: run.mode must be \"full\" (a cycle jump assumes constant amplitude)")
    measurement = _measurement(_table(doc, "measurement", "measurement", required=False))
    steps = doc.get("stiffness_steps", [])
    if not (isinstance(steps, list) and all(isinstance(s, list) and len(s) == 2 for s in steps)):
        raise SpecError("stiffness_steps must be a list of [cycle, factor] pairs")
    spec = TestSpec(
        name=name, geometry=geometry, width_m=width, thickness_m=thickness, a0_m=a0, material=material, law=dict(law),
        waveform=waveform, waveform_shape=shape, frequency_hz=freq, control_rate_hz=rate, phases=phases,
        controller=controller, end=end_d, start=start, rig_overrides={k: float(v) for k, v in overrides.items()},
        rig_preset=preset, rtol=_num(run, "rtol", "run", default=DEFAULTS["rtol"]),
        mode=_choice(run, "mode", "run", ("full", "jump"), "full" if va else "jump"),
        stiffness_steps=[(int(c), float(f)) for c, f in steps], blocks=blocks, spectrum=spectrum, override_limits=override,
        measurement=measurement,
    )
    # the one configuration of the test: the core reads the spec, takes its defaults and checks
    # every value (naming the spec's field), once
    spec.config = build_config(spec)
    if check and not spec.override_limits:
        feas = spec.feasibility()
        if not feas.feasible:
            raise InfeasibleTest(feas.refusal())
    return spec


MEASUREMENT_KEYS = {"crack", "gauge", "gauge_x_over_w", "gauge_y_m", "cycles_per_reading", "readings_fitted", "noise", "resolution",
                    "drift_per_cycle", "closure_opening_fraction", "seed"}


def _measurement(m: dict) -> dict[str, Any]:
    """`[measurement]`: the crack source and the gauge as given (the core checks the values and
    fills the defaults). `gauge` names a C(T) gauge location (crack_mouth, front_face_knife_edges,
    knife_edges_0.1576, load_line) in place of `gauge_x_over_w`."""
    _keys(m, MEASUREMENT_KEYS, "measurement")
    out: dict[str, Any] = {"crack": _choice(m, "crack", "measurement", ("compliance", "potential_drop", "model"), "model")}
    if "gauge" in m:
        names = {"crack_mouth": -0.25, "front_face": -0.25, "front_face_knife_edges": -0.345, "knife_edges_0.1576": -0.1576, "load_line": 0.0}
        out["gauge_x_over_w"] = names[_choice(m, "gauge", "measurement", tuple(names))]
    for k in ("gauge_x_over_w", "gauge_y_m", "noise", "resolution", "drift_per_cycle", "closure_opening_fraction"):
        if k in m:
            out[k] = _num(m, k, "measurement")
    for k, lo, hi in (("cycles_per_reading", 1, 1000), ("readings_fitted", 1, 50), ("seed", 0, 2**63)):
        if k in m:
            out[k] = _int(m, k, "measurement", lo, 1, hi)
    return out


def build_config(spec: TestSpec) -> core.TestConfig:
    """The core `TestConfig` of `spec` on its rig (preset + overrides): the core reads the spec by its
    own names, fills the defaults and checks every value once; errors name the spec field."""
    try:
        params = with_overrides(core.Params(spec.rig_preset), spec.rig_overrides, validate=False)
    except HtmError as e:
        raise SpecError(f"rig.overrides: {e}") from None
    try:
        return core.TestConfig(spec, params)
    except ParameterError as e:
        raise SpecParameterError.of(e) from None
    except HtmError as e:
        raise SpecError(str(e)) from None


def stored_text(path: str | Path, spec: TestSpec) -> str:
    """The spec text a store keeps for `spec` read from `path`: the file as written, or, when it
    names a spectrum file, the spec with that spectrum inline (`htm resume` and a later review
    then need no file beside the store, and the spectrum cannot change under the record)."""
    text = Path(path).read_text()
    doc = tomllib.loads(text)
    va = doc.get("variable_amplitude", {})
    if "spectrum_file" not in va:
        return text
    va["spectrum"] = [list(c) for c in spec.spectrum]
    del va["spectrum_file"]
    return f"# {Path(path).name} with its spectrum file inlined\n" + dumps(doc)


def load(path: str | Path, *, check: bool = True) -> TestSpec:
    """Read and validate a TOML test spec.

    Parameters
    ----------
    path : str or Path
        The spec file (e.g. ``examples/ct_constant_force.toml``); its values are SI.
    check : bool
        Refuse a test the rig cannot run (InfeasibleTest), as `parse` does.

    Returns
    -------
    TestSpec
        The validated spec; a bad file or value raises SpecError naming the field and its range.
    """
    p = Path(path)
    text = read_text(p, "spec", SpecError)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise SpecError(f"{p}: not valid TOML: {e}") from None
    if not doc:
        raise SpecError(f"{p}: the spec is empty (it needs [specimen], [material], [loading] and [end]; "
                        "see examples/ct_constant_force.toml)")
    try:
        return parse(doc, p.stem, p.parent, check=check)
    except InfeasibleTest:  # a verdict on the test, not on the file: its message says the limit
        raise
    except SpecError as e:  # a bad field: the file named in front
        raise SpecError(f"{p}: {e}") from None


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ("nan" if math.isnan(v) else ("inf" if v > 0 else "-inf"))
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise SpecError(f"cannot write {v!r} to TOML")


def dumps(doc: dict[str, Any]) -> str:
    """A spec document (as `parse` takes it) as TOML text; `loads(dumps(doc)) == doc`."""
    lines = [f"{k} = {_toml_value(v)}" for k, v in doc.items() if not isinstance(v, dict)]

    def table(name: str, d: dict[str, Any]) -> None:
        lines.append(f"\n[{name}]")
        lines.extend(f"{k} = {_toml_value(v)}" for k, v in d.items() if not isinstance(v, dict))
        for k, v in d.items():
            if isinstance(v, dict):
                table(f"{name}.{k}", v)

    for k, v in doc.items():
        if isinstance(v, dict):
            table(k, v)
    return "\n".join(lines).lstrip("\n") + "\n"


def save(doc: dict[str, Any], path: str | Path, name: str = "test") -> TestSpec:
    """Validate `doc` and write it as TOML to `path` (refuses to overwrite); returns the spec."""
    spec = parse(doc, name)
    p = Path(path)
    if p.exists():
        raise SpecError(f"{p} exists; refusing to overwrite a spec")
    p.write_text(dumps(doc))
    return spec


__all__ = ["TestSpec", "Loading", "parse", "load", "dumps", "save", "stored_text", "thesis_rig", "read_spectrum"]
