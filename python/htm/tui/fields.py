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


FIELDS: tuple[Field, ...] = (
    Field(("specimen", "geometry"), "geometry", choices=("ct", "mt")),
    Field(("specimen", "width_m"), "width W", "mm", 1e-3),
    Field(("specimen", "thickness_m"), "thickness B", "mm", 1e-3),
    Field(("specimen", "a0_m"), "initial crack a0", "mm", 1e-3),
    Field(("material", "youngs_modulus_pa"), "Young's modulus E", "GPa", 1e9),
    Field(("material", "poisson_ratio"), "Poisson ratio ν"),
    Field(("material", "yield_strength_pa"), "yield strength σys", "MPa", 1e6),
    Field(("material", "fracture_toughness_pa_sqrt_m"), "toughness K_IC", "MPa·√m", 1e6),
    Field(("law", "law"), "growth law", choices=("paris", "forman", "nasgro")),
    Field(("law", "c"), "law constant C", "(m/cycle)/(Pa·√m)^m"),
    Field(("law", "m"), "law exponent m"),
    Field(("loading", "mode"), "test mode", choices=specmod.MODES),
    Field(("loading", "delta_f_n"), "force range ΔF", "kN", 1e3, when=(("loading", "mode"), ("constant_force",))),
    Field(("loading", "delta_k_pa_sqrt_m"), "ΔK (start)", "MPa·√m", 1e6, when=(("loading", "mode"), ("constant_delta_k", "k_gradient"))),
    Field(("loading", "k_gradient_per_m"), "K-gradient C", "1/mm", 1e3, when=(("loading", "mode"), ("k_gradient",))),
    Field(("loading", "r_ratio"), "load ratio R"),
    Field(("loading", "waveform"), "waveform", choices=specmod.WAVEFORMS),
    Field(("loading", "rise_fraction"), "rise fraction", when=(("loading", "waveform"), ("trapezoid",))),
    Field(("loading", "hold_fraction"), "hold fraction", when=(("loading", "waveform"), ("trapezoid",))),
    Field(("loading", "frequency_hz"), "frequency", "Hz"),
    Field(("loading", "control_rate_hz"), "control rate", "Hz"),
    Field(("controller", "type"), "force controller", choices=("demodulation", "force_p")),
    Field(("controller", "kp_v_per_n"), "force P gain", "V/kN", 1e-3, when=(("controller", "type"), ("force_p",))),
    Field(("end", "a_over_w"), "end at a/W"),
    Field(("end", "max_cycles"), "cycle limit", integer=True),
    Field(("end", "size_criterion"), "E647 size criterion", choices=("flag", "stop")),
    # [measurement]: the crack the test runs on (ΔK, shedding, end) — measured on the rig, or the
    # law's own prediction (simulation only: a real rig refuses "model")
    Field(("measurement", "crack"), "crack size from", choices=("model", "compliance", "potential_drop")),
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
    if f.when is None:
        return True
    (sec, key), values = f.when
    return str(doc.get(sec, {}).get(key, "")) in values


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
    """The document without the values of fields that are hidden (another mode's ΔF, ...)."""
    out = {k: dict(v) if isinstance(v, dict) else v for k, v in doc.items()}
    for f in FIELDS:
        if not visible(f, doc):
            out.get(f.path[0], {}).pop(f.path[1], None)
    if out.get("controller", {}).get("type") != "force_p":
        out.get("controller", {}).pop("u_offset_v", None)
    return out


def validate(doc: dict[str, Any], name: str = "test") -> tuple[specmod.TestSpec | None, str | None, str | None]:
    """(spec, None, None) when valid, else (None, field id or None, message). What the rig can
    do is not judged here: the Setup tab shows the feasibility check beside the form."""
    try:
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
