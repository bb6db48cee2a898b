"""What the operator reads: the loop's SI values in engineering units, with their labels.

Inside htm every value is SI (`htm.devices.config.CHANNELS`: metres, newtons, pascals, seconds);
the console shows each channel in the unit a test engineer reads it in, aligned, with the unit
in its own column.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

from rich.text import Text


@dataclass(frozen=True)
class Unit:
    label: str        # what the quantity is, in words
    unit: str         # the unit shown
    scale: float      # shown = SI × scale
    fmt: str          # format of the shown number


# every watched channel of the loop (htm.devices.config.CHANNELS)
CHANNEL_UNITS: dict[str, Unit] = {
    "position_m": Unit("position", "mm", 1e3, ".2f"),
    "velocity_m_s": Unit("velocity", "mm/s", 1e3, ".1f"),
    "force_n": Unit("force", "kN", 1e-3, ".2f"),
    "p_a_pa": Unit("pressure A", "bar", 1e-5, ".1f"),
    "p_b_pa": Unit("pressure B", "bar", 1e-5, ".1f"),
    "p_s_pa": Unit("supply pressure", "bar", 1e-5, ".1f"),
    "following_error_m": Unit("following error", "mm", 1e3, ".3f"),
    "amplitude_error_pct": Unit("ΔF error", "%", 1.0, ".2f"),
    "force_band": Unit("force outside band", "% of ΔF", 100.0, ".1f"),
    "transducer_age_periods": Unit("transducer age", "periods", 1.0, ".0f"),
    "transducer_fault": Unit("transducer fault", "1 = fault", 1.0, ".0f"),
    "heartbeat_age_s": Unit("heartbeat age", "ms", 1e3, ".0f"),
    "can_error_frames": Unit("CAN error frames", "frames", 1.0, ".0f"),
    "bus_off": Unit("CAN bus off", "1 = off", 1.0, ".0f"),
    "position_plausibility_m": Unit("position vs speed", "µm", 1e6, ".1f"),
    "load_plausibility_n": Unit("load vs pressures", "kN", 1e-3, ".2f"),
    "force_unexplained": Unit("force unexplained", "% of ΔF", 100.0, ".1f"),
    "gauge_v": Unit("clip gauge signal", "V", 1.0, ".2f"),
    "gauge_jump_m": Unit("clip gauge jump", "µm", 1e6, ".1f"),
    "dcpd_current_a": Unit("potential-drop current", "A", 1.0, ".2f"),
}


def unit_of(channel: str) -> Unit:
    return CHANNEL_UNITS.get(channel, Unit(channel, "SI", 1.0, ".4g"))


def shown(channel: str, v: float | None, *, limit: bool = False) -> str:
    """`v` [SI] of `channel` as the operator reads it; an infinite limit is "none", a missing
    value a dash."""
    u = unit_of(channel)
    if v is None or math.isnan(v):
        return "–"
    if math.isinf(v):
        return "none" if limit else ("+∞" if v > 0 else "−∞")
    text = format(v * u.scale, u.fmt)
    if float(text) == 0.0:  # no "-0.0"
        text = format(0.0, u.fmt)
    return text.replace("-", "−")


def right(text: str) -> Text:
    """A right-aligned table cell, never read as markup (`[mm]` would vanish as a tag)."""
    return Text(text, justify="right")


def plain(text: str) -> Text:
    return Text(text)


# a stored result's SI suffix -> (unit shown, scale): the longest suffix that matches wins
SUFFIXES = (("_m_s_per_v", "mm/s per V", 1e3), ("_pa_sqrt_m", "MPa·√m", 1e-6), ("_m_per_cycle", "mm/cycle", 1e3), ("_n_m", "kN/mm", 1e-6), ("_pa", "MPa", 1e-6),
            ("_n", "kN", 1e-3), ("_m", "mm", 1e3), ("_pct", "%", 1.0), ("_s", "s", 1.0), ("_hz", "Hz", 1.0), ("_v", "V", 1.0))


def eng(key: str, v: float, pressures_in_bar: bool = False) -> tuple[str, str, str]:
    """(name, value, unit) of an SI value named with its unit suffix (`final_a_m` → final a,
    30.4803, mm); pressures in bar where a hydraulic pressure is meant, else MPa (a stress)."""
    unit, scale, name = "", 1.0, key.replace("a_over_w", "a/W")
    for suffix, u, sc in SUFFIXES:
        if key.endswith(suffix):
            unit, scale, name = u, sc, name[: -len(suffix)]
            break
    if unit == "MPa" and pressures_in_bar:
        unit, scale = "bar", 1e-5
    x = v * scale
    if isinstance(v, int) or (unit == "" and float(x).is_integer()):
        text = f"{int(x):,}"
    elif not math.isfinite(x):
        text = "–"
    elif x != 0 and (abs(x) < 1e-3 or abs(x) >= 1e7):
        text = f"{x:.3e}"
    else:
        text = f"{x:,.4f}" if abs(x) < 1e4 else f"{x:,.0f}"
    name = re.sub(r"(\d+)pct$", r"\1 %", re.sub(r"(\d+)p(\d+)pct$", r"\1.\2 %", name))  # cycles_to_0p5pct: cycles to 0.5 %
    return name.replace("_", " "), text, unit


def result_lines(results: dict[str, object]) -> list[str]:
    """A test's numeric results, one a line: name, value in its engineering unit, unit; aligned."""
    rows = [eng(k, v) for k, v in sorted(results.items()) if isinstance(v, (int, float)) and not isinstance(v, bool)]
    if not rows:
        return []
    w0, w1 = max(len(r[0]) for r in rows), max(len(r[1]) for r in rows)
    return [f"{n:<{w0}}  {t:>{w1}} {u}".rstrip() for n, t, u in rows]
