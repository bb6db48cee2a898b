"""The test spec as form fields: engineering units for the operator, SI in the TOML document.

Validation is `htm.spec.parse` on the whole document (the CLI's rules); its error is routed to the
field it names.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

from htm import spec as specmod
from htm.errors import SpecError
from htm.fatigue import lifetest


@dataclass(frozen=True)
class Field:
    """One spec value: `path` in the TOML document, shown in `unit` (SI = shown × `scale`)."""

    path: tuple[str, str]
    label: str
    unit: str = ""
    scale: float = 1.0
    choices: tuple[str, ...] = ()
    integer: bool = False
    when: tuple[tuple[str, str], tuple[str, ...]] | None = None  # shown only when another field has one of these values

    @property
    def id(self) -> str:
        return f"{self.path[0]}-{self.path[1]}"


# the test modes: crack growth (E647) and the life tests (E466 force_life, E606 strain_life)
LIFE_MODES = ("force_life", "strain_life")
CRACK = (("loading", "mode"), specmod.MODES)
LIFE = (("loading", "mode"), LIFE_MODES)
# the tables and keys of a life test's spec (htm.fatigue.lifetest)
LIFE_KEYS: dict[str, set[str]] = {
    "specimen": {"diameter_m", "gauge_length_m", "a_init_m", "load_train_n_m"},
    "material": set(lifetest._MATERIAL) | {"life_scatter_log10", "seed", "life_factor"},
    "law": {"law", "c", "m"},
    "loading": {"mode", "stress_amplitude_pa", "force_amplitude_n", "strain_amplitude", "r_ratio", "frequency_hz", "control_rate_hz",
                "mean_cycles", "amplitude_cycles"},
    "end": {"drop", "modulus_ratio_drop", "separation", "runout_cycles"},
    "record": {"loops_per_decade"},
    "run": {"mode", "rtol"},
}
# the keys only a life test has
LIFE_ONLY: dict[str, set[str]] = {
    "specimen": {"diameter_m", "gauge_length_m", "a_init_m", "load_train_n_m"},
    "material": (set(lifetest._MATERIAL) | {"life_scatter_log10", "seed", "life_factor"}) - {"youngs_modulus_pa", "fracture_toughness_pa_sqrt_m"},
    "loading": {"stress_amplitude_pa", "force_amplitude_n", "strain_amplitude", "mean_cycles", "amplitude_cycles"},
    "end": {"drop", "modulus_ratio_drop", "separation", "runout_cycles"},
}

FIELDS: tuple[Field, ...] = (
    Field(("specimen", "geometry"), "geometry", choices=("ct", "mt"), when=CRACK),
    Field(("specimen", "width_m"), "width W", "mm", 1e-3, when=CRACK),
    Field(("specimen", "thickness_m"), "thickness B", "mm", 1e-3, when=CRACK),
    Field(("specimen", "a0_m"), "initial crack a0", "mm", 1e-3, when=CRACK),
    Field(("material", "youngs_modulus_pa"), "Young's modulus E", "GPa", 1e9),
    Field(("material", "poisson_ratio"), "Poisson ratio ν", when=CRACK),
    Field(("material", "yield_strength_pa"), "yield strength σys", "MPa", 1e6, when=CRACK),
    Field(("material", "fracture_toughness_pa_sqrt_m"), "toughness K_IC", "MPa·√m", 1e6),
    Field(("law", "law"), "growth law", choices=("paris", "forman", "nasgro"), when=CRACK),
    Field(("law", "c"), "law constant C", "(m/cycle)/(Pa·√m)^m"),
    Field(("law", "m"), "law exponent m"),
    Field(("loading", "mode"), "test mode", choices=specmod.MODES + LIFE_MODES),
    # a life test's round bar and its extensometer's gauge length
    Field(("specimen", "diameter_m"), "bar diameter D", "mm", 1e-3, when=LIFE),
    Field(("specimen", "gauge_length_m"), "gauge length", "mm", 1e-3, when=LIFE),
    # the virtual bar's cyclic curve (the simulation's truth; the rig's bar has its own)
    Field(("material", "cyclic_k_prime_pa"), "cyclic K′", "MPa", 1e6, when=LIFE),
    Field(("material", "cyclic_n_prime"), "cyclic n′", when=LIFE),
    Field(("loading", "delta_f_n"), "force range ΔF", "kN", 1e3, when=(("loading", "mode"), ("constant_force",))),
    Field(("loading", "delta_k_pa_sqrt_m"), "ΔK (start)", "MPa·√m", 1e6, when=(("loading", "mode"), ("constant_delta_k", "k_gradient"))),
    Field(("loading", "k_gradient_per_m"), "K-gradient C", "1/mm", 1e3, when=(("loading", "mode"), ("k_gradient",))),
    Field(("loading", "force_amplitude_n"), "force amplitude Fa", "kN", 1e3, when=(("loading", "mode"), ("force_life",))),
    Field(("loading", "strain_amplitude"), "strain amplitude εa", "%", 1e-2, when=(("loading", "mode"), ("strain_life",))),
    Field(("loading", "r_ratio"), "load ratio R"),
    Field(("loading", "waveform"), "waveform", choices=specmod.WAVEFORMS, when=CRACK),
    Field(("loading", "rise_fraction"), "rise fraction", when=(("loading", "waveform"), ("trapezoid",))),
    Field(("loading", "hold_fraction"), "hold fraction", when=(("loading", "waveform"), ("trapezoid",))),
    Field(("loading", "frequency_hz"), "frequency", "Hz"),
    Field(("loading", "control_rate_hz"), "control rate", "Hz"),
    Field(("controller", "type"), "force controller", choices=("demodulation", "force_p"), when=CRACK),
    Field(("controller", "kp_v_per_n"), "force P gain", "V/kN", 1e-3, when=(("controller", "type"), ("force_p",))),
    Field(("end", "a_over_w"), "end at a/W", when=CRACK),
    Field(("end", "max_cycles"), "cycle limit", integer=True, when=CRACK),
    Field(("end", "size_criterion"), "E647 size criterion", choices=("flag", "stop"), when=CRACK),
    # a life test's end criteria (E606): the tensile peak's drop (strain control) or the secant
    # stiffness's (force control) from its stabilised trend, the unloading-modulus ratio's, run-out
    Field(("end", "drop"), "end: peak/stiffness drop", "fraction (0 = off)", when=LIFE),
    Field(("end", "modulus_ratio_drop"), "end: modulus-ratio drop", "fraction (0 = off)", when=LIFE),
    Field(("end", "runout_cycles"), "run-out at", "cycles", integer=True, when=LIFE),
    # [measurement]: the crack the test runs on (ΔK, shedding, end) — measured on the rig, or the
    # law's own prediction (simulation only: a real rig refuses "model")
    Field(("measurement", "crack"), "crack size from", choices=("model", "compliance", "potential_drop"), when=CRACK),
    Field(("measurement", "cycles_per_reading"), "cycles per reading", integer=True,
          when=(("measurement", "crack"), ("compliance", "potential_drop"))),
)

# material presets (SI) and specimen presets (SI): what a lab keeps on a card
MATERIALS: dict[str, dict[str, float]] = {
    "structural steel": {"youngs_modulus_pa": 200e9, "poisson_ratio": 0.3, "yield_strength_pa": 350e6, "fracture_toughness_pa_sqrt_m": 100e6},
    "aluminium 2024-T3": {"youngs_modulus_pa": 73.1e9, "poisson_ratio": 0.33, "yield_strength_pa": 345e6, "fracture_toughness_pa_sqrt_m": 37e6},
    "Ti-6Al-4V": {"youngs_modulus_pa": 114e9, "poisson_ratio": 0.34, "yield_strength_pa": 880e6, "fracture_toughness_pa_sqrt_m": 75e6},
}
SPECIMENS: dict[str, dict[str, Any]] = {
    "C(T) W 50.8 B 6.35 (Table B.1)": {"geometry": "ct", "width_m": 0.0508, "thickness_m": 0.00635, "a0_m": 0.0152},
    "M(T) W 152.4 B 2.54 (Virkler)": {"geometry": "mt", "width_m": 0.1524, "thickness_m": 0.00254, "a0_m": 0.009},
}


def visible(f: Field, doc: dict[str, Any]) -> bool:
    """Shown: its condition holds and the field that condition reads is shown itself."""
    if f.when is None:
        return True
    (sec, key), values = f.when
    if str(doc.get(sec, {}).get(key, "")) not in values:
        return False
    parent = next((g for g in FIELDS if g.path == (sec, key)), None)
    return parent is None or visible(parent, doc)


def is_life(doc: dict[str, Any]) -> bool:
    """The document is a life test (force_life / strain_life)."""
    return str(doc.get("loading", {}).get("mode", "")) in LIFE_MODES


# a life test's values where the document has none yet (switching a crack test's form to a life
# mode): the example bar of examples/strain_life.toml and force_life.toml
LIFE_DEFAULTS: dict[str, dict[str, Any]] = {
    "specimen": {"diameter_m": 6.35e-3, "gauge_length_m": 0.025},
    "material": {"cyclic_k_prime_pa": 1200e6, "cyclic_n_prime": 0.14},
    "loading": {"strain_amplitude": 0.006, "force_amplitude_n": 13e3},
    "end": {"drop": 0.5, "modulus_ratio_drop": 0.0, "runout_cycles": 10_000_000},
}


def show(f: Field, doc: dict[str, Any]) -> str:
    """The document's value of `f` as the operator reads it."""
    v = doc.get(f.path[0], {}).get(f.path[1])
    if v is None:
        return ""
    if f.choices:
        return str(v)
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        x = v / f.scale
        return str(int(x)) if f.integer else f"{x:.6g}"
    return str(v)


def choice(f: Field, doc: dict[str, Any]) -> str:
    """The value a choice field's selector shows: the document's, or its first choice when the
    document has none of them (a life test's round bar in the crack test's geometry field)."""
    v = show(f, doc)
    return v if v in f.choices else f.choices[0]


def parse_value(f: Field, text: str) -> Any:
    """Operator text → SI value for the document; SpecError (a ValueError) with a short reason."""
    text = text.strip()
    if f.choices:
        if text not in f.choices:
            raise SpecError(f"one of {', '.join(f.choices)}")
        return text
    if not text:
        raise SpecError("required")
    try:
        x = float(text.replace(",", "."))
    except ValueError:
        raise SpecError(f"not a number: {text!r}") from None
    if not math.isfinite(x):
        raise SpecError("must be finite")
    if f.integer:
        if x != int(x):
            raise SpecError("must be a whole number")
        return int(x)
    return x * f.scale


def with_value(doc: dict[str, Any], f: Field, value: Any) -> dict[str, Any]:
    out = {k: dict(v) if isinstance(v, dict) else v for k, v in doc.items()}
    out.setdefault(f.path[0], {})[f.path[1]] = value
    return out


def effective(doc: dict[str, Any]) -> dict[str, Any]:
    """The document without the values of fields that are hidden (another mode's ΔF, ...); a
    life test's without the crack test's tables."""
    out = {k: dict(v) if isinstance(v, dict) else v for k, v in doc.items()}
    if not is_life(doc):  # a crack test: without a life test's own keys (kept in the form's document)
        for sec, keys in LIFE_ONLY.items():
            for k in keys:
                out.get(sec, {}).pop(k, None)
        out.pop("record", None)
    if is_life(doc):  # the keys a life spec takes (a crack test's others stay in the form's document)
        out = {k: {kk: vv for kk, vv in v.items() if kk in LIFE_KEYS[k]} for k, v in out.items() if k in LIFE_KEYS and isinstance(v, dict)}
        law = out.get("law", {})
        if law.get("law") not in (None, "paris"):
            law.pop("law", None)
    for f in FIELDS:
        if not visible(f, doc):
            out.get(f.path[0], {}).pop(f.path[1], None)
    if out.get("controller", {}).get("type") != "force_p":
        out.get("controller", {}).pop("u_offset_v", None)
    return out


def validate(doc: dict[str, Any], name: str = "test") -> tuple[Any, str | None, str | None]:
    """(spec, None, None) when valid, else (None, field id or None, message). What the rig can
    do is not judged here: the Setup tab shows the feasibility check beside the form. A life
    test's spec is `htm.fatigue.lifetest.LifeSpec` (its rules: `lifetest.parse`)."""
    try:
        if is_life(doc):
            from htm.fatigue import lifetest

            return lifetest.parse(effective(doc), name), None, None
        return specmod.parse(effective(doc), name, check=False), None, None
    except SpecError as e:
        msg = str(e)
        return None, field_of(msg), msg


def field_of(msg: str) -> str | None:
    """The form field a SpecError message is about (it names `section.key`)."""
    for f in FIELDS:
        if re.search(rf"\b{f.path[0]}\.{f.path[1]}\b", msg):
            return f.id
    if "first loading phase" in msg or "Kmax" in msg:
        return "loading-delta_f_n" if "delta_f" in msg or "force" in msg else "loading-delta_k_pa_sqrt_m"
    return None


def field_of_check(name: str, doc: dict[str, Any]) -> str:
    """The form field a refused feasibility check asks to change: the frequency for the rate
    limits, the load (ΔF or ΔK) for the others."""
    if name in ("frequency", "valve_flow"):
        return "loading-frequency_hz"
    return "loading-delta_f_n" if doc.get("loading", {}).get("mode", "constant_force") == "constant_force" else "loading-delta_k_pa_sqrt_m"
