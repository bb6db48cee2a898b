"""What a person reads on a terminal: SI values in engineering units (mm, kN, MPa·√m, bar),
aligned label/value tables, `--json` output for scripts, and the one progress line every long
command (`htm run`, `htm campaign`, `htm life-band`) draws.

Everything inside htm is SI; this module only converts for display."""
from __future__ import annotations

import json
import math
import os
import shutil
import sys
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import IO, Any

# an SI name's suffix → (factor to the display unit, display unit); the longest suffix wins
SUFFIX_UNITS: dict[str, tuple[float, str]] = {
    "_pa_sqrt_m": (1e-6, "MPa·√m"),
    "_m_s_per_v": (1e3, "mm/s per V"),
    "_n_per_s_v": (1e-3, "kN/s per V"),
    "_n_s_m": (1.0, "N·s/m"),
    "_m_s": (1e3, "mm/s"),
    "_m": (1e3, "mm"),
    "_n": (1e-3, "kN"),
    "_pa": (1e-5, "bar"),
    "_hz": (1.0, "Hz"),
    "_s": (1.0, "s"),
    "_pct": (1.0, "%"),
    "_v": (1.0, "V"),
    "_kg": (1.0, "kg"),
}


def eng(value: float | None, unit: str = "", digits: int = 4) -> str:
    """`value` with `digits` significant figures, thousands grouped, no e-notation for 1e-3..1e9."""
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    v = float(value)
    if not math.isfinite(v):
        s = "∞" if v > 0 else "−∞" if v < 0 else "NaN"
    elif v == 0:
        s = "0"
    elif 1e-3 <= abs(v) < 1e9:
        decimals = max(0, digits - 1 - int(math.floor(math.log10(abs(v)))))
        s = f"{v:,.{decimals}f}"
    else:
        s = f"{v:.{digits - 1}e}"
    return f"{s} {unit}".rstrip()


def si(key: str, value: Any, digits: int = 4) -> str:
    """A value named by its SI key (``final_a_m``, ``delta_k_pa_sqrt_m``…) in engineering units;
    other values (text, counts, lists) plainly, never as a Python repr."""
    if isinstance(value, bool) or value is None:
        return eng(value)
    if isinstance(value, int) and not key.endswith(tuple(SUFFIX_UNITS)):
        return f"{value:,}"
    if isinstance(value, (int, float)):
        for suffix, (factor, unit) in sorted(SUFFIX_UNITS.items(), key=lambda kv: -len(kv[0])):
            if key.endswith(suffix):
                if "_per_" in key and "per" not in suffix:
                    break  # a compound unit this table does not know: the plain number, no wrong unit
                return eng(value * factor, unit, digits)
        return eng(value, "", digits)
    if isinstance(value, dict):
        return ", ".join(f"{k} {si(k, v, digits)}" for k, v in value.items())
    if isinstance(value, (list, tuple)):
        return ", ".join(si(key, v, digits) for v in value) if value else "–"
    return str(value)


def label(key: str) -> str:
    """An SI key as a label: `final_a_over_w` → `final a over w`, the unit suffix dropped."""
    for suffix in sorted(SUFFIX_UNITS, key=len, reverse=True):
        if key.endswith(suffix) and len(key) > len(suffix):
            key = key[: -len(suffix)]
            break
    return key.replace("_", " ")


def table(rows: Iterable[tuple[str, str]], indent: str = "") -> str:
    """Label/value rows aligned on the labels."""
    rows = list(rows)
    if not rows:
        return ""
    w = max(len(k) for k, _ in rows)
    return "\n".join(f"{indent}{k:<{w}}  {v}" for k, v in rows)


def grid(headers: Sequence[str], rows: Sequence[Sequence[str]], right: Sequence[bool] | None = None, indent: str = "") -> str:
    """Columns with headers, numbers (``right``) aligned right."""
    right = right or [False] * len(headers)
    cells = [list(headers)] + [[str(c) for c in r] for r in rows]
    ws = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    out = []
    for r in cells:
        out.append(indent + "  ".join(c.rjust(w) if rt else c.ljust(w) for c, w, rt in zip(r, ws, right)).rstrip())
    return "\n".join(out)


def size(n_bytes: float | None) -> str:
    """A file size: ``812 B``, ``3.4 kB``, ``10.1 MB``."""
    n = float(n_bytes or 0)
    for unit, f in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= f:
            return f"{n / f:.1f} {unit}"
    return f"{n:.0f} B"


def path(p: str | Path) -> str:
    """A path as a person wants it: relative to the working folder when inside it, no `..`."""
    q = Path(os.path.abspath(p))
    try:
        return str(q.relative_to(Path.cwd()))
    except ValueError:
        return str(q)


def _plain(o: Any) -> Any:
    if isinstance(o, Path):
        return str(o)
    if hasattr(o, "tolist"):
        return o.tolist()
    if hasattr(o, "item"):
        return o.item()
    return str(o)


def dumps(obj: Any) -> str:
    """JSON for `--json`: SI values under their SI names; NaN/inf as null (strict JSON)."""

    def clean(o: Any) -> Any:
        if isinstance(o, float) and not math.isfinite(o):
            return None
        if isinstance(o, dict):
            return {str(k): clean(v) for k, v in o.items()}
        if isinstance(o, (list, tuple)):
            return [clean(v) for v in o]
        return o

    return json.dumps(clean(json.loads(json.dumps(obj, default=_plain))), indent=2, allow_nan=False, ensure_ascii=False)


def emit_json(obj: Any) -> None:
    """Print `obj` as JSON on stdout (the whole of stdout under `--json`)."""
    print(dumps(obj))


def add_json_flag(p: Any) -> None:
    """The `--json` option of a command that prints results."""
    p.add_argument("--json", action="store_true", help="print the results as JSON (SI units, for scripts) instead of text")


def duration(s: float) -> str:
    """Seconds as ``42 s``, ``3:07`` or ``2:03:07`` (h:mm:ss)."""
    if not math.isfinite(s):
        return "?"
    s = max(0, int(round(s)))
    if s < 60:
        return f"{s} s"
    h, rem = divmod(s, 3600)
    m, sec = divmod(rem, 60)
    return f"{h}:{m:02d}:{sec:02d}" if h else f"{m}:{sec:02d}"


class Progress:
    """The progress of a long job toward its end: done/total (or a fraction of the end
    condition, e.g. a/W), rate and time left.

    On a terminal it is one line redrawn in place, never wider than the terminal (so it never
    wraps) and drawn complete when the job ends. When the stream is not a terminal (a pipe, a
    log, CI) it writes a plain line every `interval_s` seconds (default 10 s, or
    ``$HTM_PROGRESS_S``) and one at the end, nothing else: no carriage returns, no escape codes.
    The time left comes from the recent pace (the last fifth of the run), as a crack speeds up.

    Parameters
    ----------
    total : float or None
        The job's size in `unit` (tests, cycles); None when only a fraction is known.
    unit : str
        What is counted (``"tests"``, ``"cycles"``); the rate is in `unit` per second.
    what : str
        A label in front of the line (the plain lines' only way to say what they are).
    start : float
        Units already done when this session began (a resumed test, a continued campaign):
        the rate and time left count only this session's.
    """

    def __init__(self, total: float | None, unit: str, what: str = "", *, start: float = 0.0,
                 stream: IO[str] | None = None, interval_s: float | None = None) -> None:
        self.total, self.unit, self.what = total, unit, what
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        env = os.environ.get("HTM_PROGRESS_S")
        self.interval_s = interval_s if interval_s is not None else float(env) if env else (0.1 if self.tty else 10.0)
        self.t0 = time.perf_counter()
        self.start = self.done = float(start)
        self.fraction: float | None = None
        self.detail = ""
        self.last = -math.inf
        self.closed = False
        self.history: list[tuple[float, float]] = []  # (time, fraction) of recent updates, for the time left

    def _fraction(self, done: float, fraction: float | None) -> float | None:
        if fraction is None and self.total:
            fraction = done / self.total
        return None if fraction is None else min(max(fraction, 0.0), 1.0)

    def update(self, done: float, fraction: float | None = None, detail: str = "") -> None:
        """`done` units so far (cumulative); `fraction` of the end condition when it is not
        done/total (e.g. a crack's progress toward its end size); `detail` what else to show."""
        self.done, self.detail = float(done), detail
        self.fraction = self._fraction(done, fraction)
        now = time.perf_counter()
        if self.fraction is not None:
            self.history.append((now, self.fraction))
            # the recent pace (the last fifth of the run, at least 3 s): a crack speeds up as it grows
            keep = max(3.0, 0.2 * (now - self.t0))
            while len(self.history) > 2 and now - self.history[0][0] > keep:
                self.history.pop(0)
        if now - self.last >= self.interval_s:
            self.last = now
            self._write(self.line(now))

    def close(self, detail: str | None = None, fraction: float | None = None, done: float | None = None) -> None:
        """Draw the final state once (`done` units, `fraction`, `detail` e.g. the end reason)
        and end the line."""
        if self.closed:
            return
        self.closed = True
        if done is not None:
            self.done = float(done)
            self.fraction = self._fraction(done, fraction)
        if fraction is not None:
            self.fraction = min(max(fraction, 0.0), 1.0)
        if detail is not None:
            self.detail = detail
        self._write(self.line(time.perf_counter(), final=True), end=True)

    def line(self, now: float, final: bool = False) -> str:
        el = now - self.t0
        rate = (self.done - self.start) / el if el > 0 else 0.0
        parts = [self.what] if self.what else []
        f = self.fraction
        if f is not None:
            if self.tty:
                fill = int(round(20 * f))
                parts.append(f"[{'#' * fill}{'-' * (20 - fill)}]")
            parts.append(f"{100 * f:5.1f} %")
        if final:
            parts.append(f"in {duration(el)}")
        elif f is not None and len(self.history) > 1 and self.history[-1][1] > self.history[0][1]:
            (ta, fa), (tb, fb) = self.history[0], self.history[-1]
            parts.append(f"{duration((tb - ta) * (1.0 - f) / (fb - fa))} left")
        else:
            parts.append(f"{duration(el)} so far")
        parts.append(eng(rate, f"{self.unit}/s", 3))
        parts.append(f"{self.done:,.0f}" + (f"/{self.total:,.0f}" if self.total else "") + f" {self.unit}")
        if self.detail:
            parts.append(self.detail)
        return "  ".join(parts)

    def _write(self, text: str, end: bool = False) -> None:
        if self.tty:
            width = shutil.get_terminal_size((100, 24)).columns - 1
            if len(text) > width:
                text = text[: max(0, width - 1)] + "…"
            self.stream.write("\r" + text + "\x1b[K" + ("\n" if end else ""))
        else:
            self.stream.write(text + "\n")
        self.stream.flush()
