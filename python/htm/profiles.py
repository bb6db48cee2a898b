"""Command profiles: sequences of holds, ramps, sines and CSV segments sampled at a fixed rate.

A profile is written as segments `KIND:key=value,...` joined by `;` (or given one per CLI flag):

- `hold:value=1.0,duration=0.5`           constant
- `ramp:start=0,end=2,duration=1`         linear from start to end
- `sine:amplitude=1,frequency=2,offset=0,duration=3[,phase=0]`
- `csv:path=FILE[,column=u]`              samples taken as they are (one per period): the column
                                          `column`, else `u`, else the file's only column

Values are in the unit of the signal being profiled (V for a valve command, m for a position
reference, N for a force reference).
"""
from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from htm.errors import InputError
from htm.inputs import missing, read_text

# the longest profile [samples]: every sample becomes a row of ~10 float columns in memory and
# in the record (10⁷ samples ≈ 5.6 h at 500 Hz, ≈ 1 GB)
MAX_SAMPLES = 10_000_000

_KEYS = {
    "hold": ({"value", "duration"}, set()),
    "step": ({"value", "duration"}, set()),
    "ramp": ({"start", "end", "duration"}, set()),
    "sine": ({"amplitude", "frequency", "duration"}, {"offset", "phase"}),
    "csv": ({"path"}, {"column"}),
}


def _parse_segment(text: str) -> tuple[str, dict[str, str]]:
    kind, _, rest = text.strip().partition(":")
    kind = kind.strip().lower()
    if kind not in _KEYS:
        raise InputError(f"profile segment `{text}`: unknown kind `{kind}` (use {', '.join(_KEYS)})")
    args: dict[str, str] = {}
    for part in filter(None, (p.strip() for p in rest.split(","))):
        k, sep, v = part.partition("=")
        if not sep:
            raise InputError(f"profile segment `{text}`: expected key=value, got `{part}`")
        args[k.strip()] = v.strip()
    required, optional = _KEYS[kind]
    missing = required - args.keys()
    unknown = args.keys() - required - optional
    if missing:
        raise InputError(f"profile segment `{text}`: missing {', '.join(sorted(missing))}")
    if unknown:
        raise InputError(f"profile segment `{text}`: unknown key(s) {', '.join(sorted(unknown))}; "
                         f"{kind} takes {', '.join(sorted(required))}" + (f" (optional {', '.join(sorted(optional))})" if optional else ""))
    return kind, args


def _num(args: dict[str, str], key: str, text: str, positive: bool = False) -> float:
    try:
        v = float(args[key])
    except ValueError:
        raise InputError(f"profile segment `{text}`: {key} = `{args[key]}` is not a number") from None
    if not np.isfinite(v) or (positive and v <= 0):
        raise InputError(f"profile segment `{text}`: {key} = {v} must be {'> 0' if positive else 'finite'}")
    return v


def _read_csv(path: str, column: str | None, text: str) -> np.ndarray:
    p = Path(path)
    rows = list(csv.reader(io.StringIO(read_text(p, "profile CSV", InputError), newline="")))
    if len(rows) < 2:
        raise InputError(f"profile segment `{text}`: {p} has no data rows")
    header = [h.strip() for h in rows[0]]
    col = column or ("u" if "u" in header or len(header) > 1 or missing("u", header) else header[0])
    if col not in header:
        raise InputError(f"{p}: no column `{col}`{missing(col, header)} (columns: {', '.join(header)}); "
                         f"name the column with csv:path=FILE,column=NAME (profile segment `{text}`)")
    i = header.index(col)
    values = []
    for row, r in enumerate(rows[1:], start=2):
        if not r:
            continue
        try:
            values.append(float(r[i]))
        except (ValueError, IndexError):
            raise InputError(f"{p}: row {row}: `{col}` = {r[i] if i < len(r) else ''!r} is not a number "
                             f"(profile segment `{text}`)") from None
        if not math.isfinite(values[-1]):
            raise InputError(f"{p}: row {row}: `{col}` = {r[i]} is not a finite number (profile segment `{text}`)")
    return np.array(values, dtype=float)


def build(spec: str | list[str], rate_hz: float) -> np.ndarray:
    """Sample the profile at `rate_hz`; one value per control period."""
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise InputError(f"sample rate {rate_hz} Hz must be > 0")
    segments = spec.split(";") if isinstance(spec, str) else [s for item in spec for s in item.split(";")]
    segments = [s for s in segments if s.strip()]
    if not segments:
        raise InputError("empty command profile")
    dt = 1.0 / rate_hz
    parts: list[np.ndarray] = []
    total = 0
    for text in segments:
        kind, a = _parse_segment(text)
        if kind == "csv":
            parts.append(_read_csv(a["path"], a.get("column"), text))
            total += len(parts[-1])
            continue
        dur = _num(a, "duration", text, positive=True)
        if total + dur * rate_hz > MAX_SAMPLES:  # refuse before allocating
            raise InputError(f"profile segment `{text}`: the profile would hold {total + dur * rate_hz:.3g} samples at "
                             f"{rate_hz:g} Hz; at most {MAX_SAMPLES:,} ({MAX_SAMPLES / rate_hz:,.0f} s at this rate): "
                             "shorten it or lower --rate")
        n = int(round(dur / dt))
        total += n
        if n < 1:
            raise InputError(f"profile segment `{text}`: duration shorter than one sample period ({dt} s)")
        tk = np.arange(n) * dt
        if kind in ("hold", "step"):
            parts.append(np.full(n, _num(a, "value", text)))
        elif kind == "ramp":
            s0, s1 = _num(a, "start", text), _num(a, "end", text)
            parts.append(s0 + (s1 - s0) * tk / (n * dt))
        else:
            amp, freq = _num(a, "amplitude", text), _num(a, "frequency", text, positive=True)
            off = _num(a, "offset", text) if "offset" in a else 0.0
            ph = _num(a, "phase", text) if "phase" in a else 0.0
            parts.append(off + amp * np.sin(2 * np.pi * freq * tk + ph))
    if total > MAX_SAMPLES:
        raise InputError(f"the profile holds {total:,} samples; at most {MAX_SAMPLES:,}: shorten it")
    return np.concatenate(parts)
