"""Machine parameter sets: the thesis rig by default, overrides by name, and the DATA_FORMAT
`rig` metadata block."""
from __future__ import annotations

from collections.abc import Mapping

from htm.core import Params
from htm.errors import ParameterError


def thesis_rig(**overrides: float) -> Params:
    """The machine parameters of the reference thesis's rig.

    Dias (2014), Appendix A with the errata of docs/thesis_notes.md, plus the measured valve
    characteristic of Table 3.3.

    Parameters
    ----------
    **overrides : float
        Fields to replace, by name, in SI units (e.g. ``specimen_stiffness_n_m=1.04e8`` [N/m]);
        ``htm params`` lists every name with its unit.

    Returns
    -------
    Params
        A validated copy; an unknown name or a value out of range raises ParameterError.
    """
    return with_overrides(Params(), overrides)


def with_overrides(params: Params, overrides: Mapping[str, float], *, validate: bool = True) -> Params:
    """A validated copy of `params` with fields replaced; unknown names raise ParameterError.
    Without `validate` the ranges are left to the caller (a test's `TestConfig` checks them and
    names the spec's field, ``rig.overrides.NAME``)."""
    p = params.copy()
    for name, value in overrides.items():
        if name not in p:
            raise ParameterError(f"unknown parameter `{name}`; known: {', '.join(p.keys())}")
        p[name] = float(value)
    if validate:
        p.validate()
    return p


def rig_metadata(p: Params) -> dict[str, float | str]:
    """The `rig` block of a record's metadata (DATA_FORMAT.md) for these parameters."""
    return {
        "area_a_m2": p["area_a_m2"],
        "area_b_m2": p["area_b_m2"],
        "stroke_m": p["stroke_m"],
        "supply_pressure_pa": p["supply_pressure_pa"],
        "tank_pressure_pa": p["tank_pressure_pa"],
        "valve_rated_flow_m3_s": p["valve_rated_flow_m3_s"],
        "valve_rated_dp_pa": p["valve_rated_dp_pa"],
        "valve_max_command_v": p["valve_max_command_v"],
        "moving_mass_kg": p["moving_mass_kg"],
        "orientation": "vertical" if p["gravity_m_s2"] > 0 else "horizontal",
        "bulk_modulus_pa": p["bulk_modulus_pa"],
        "dead_volume_a_m3": p["dead_volume_a_m3"],
        "dead_volume_b_m3": p["dead_volume_b_m3"],
        "oil_density_kg_m3": p["oil_density_kg_m3"],
    }


def parse_assignments(items: list[str]) -> dict[str, float]:
    """Parse CLI `NAME=VALUE` strings."""
    out: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep:
            raise ParameterError(f"expected NAME=VALUE, got `{item}`")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise ParameterError(f"parameter `{name.strip()}`: `{value}` is not a number") from None
    return out
