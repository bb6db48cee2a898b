"""Per-channel calibration (engineering value = gain·volts + offset, SI) read from a TOML file."""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

from htm.errors import DeviceError

BUILTIN = Path(__file__).with_name("thesis_calibration.toml")


@dataclass(frozen=True)
class Channel:
    """value [SI] = gain [SI/V] · volts + offset [SI]; outputs invert it."""

    gain: float
    offset: float = 0.0

    def to_value(self, volts: float) -> float:
        return self.gain * volts + self.offset

    def to_volts(self, value: float) -> float:
        return (value - self.offset) / self.gain


def load_calibration(path: str | Path | None) -> dict[str, Channel]:
    """Read `[signal] gain = …, offset = …` tables; None or "builtin" is the thesis rig's file."""
    p = BUILTIN if path in (None, "builtin") else Path(path)
    try:
        doc = tomllib.loads(p.read_text())
    except FileNotFoundError:
        raise DeviceError(f"calibration file {p} does not exist") from None
    except tomllib.TOMLDecodeError as e:
        raise DeviceError(f"calibration file {p}: not valid TOML: {e}") from None
    out: dict[str, Channel] = {}
    for name, t in doc.items():
        if not isinstance(t, dict) or set(t) - {"gain", "offset", "unit", "note"} or "gain" not in t:
            raise DeviceError(f"calibration {p}: [{name}] needs gain (and optional offset, unit, note)")
        gain, offset = float(t["gain"]), float(t.get("offset", 0.0))
        if not (math.isfinite(gain) and gain != 0.0 and math.isfinite(offset)):
            raise DeviceError(f"calibration {p}: [{name}] gain = {gain}, offset = {offset}: gain must be finite and non-zero")
        out[name] = Channel(gain, offset)
    return out
