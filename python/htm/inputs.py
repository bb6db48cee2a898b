"""Reading what a person hands htm (spec, record, a–N table, model, config): the one place that
turns a missing, binary, non-UTF-8 or empty file, a non-finite number or a misspelt name into one
line naming the file, row and field (raised as the caller's HtmError subclass, so every command
exits 2 with that line and no traceback)."""
from __future__ import annotations

import difflib
import math
from collections.abc import Iterable
from pathlib import Path

from htm.errors import HtmError


def read_text(path: str | Path, what: str, error: type[HtmError] = HtmError) -> str:
    """The text of `path` (UTF-8); `what` names it in the error (``"spec"``, ``"a–N table"``).
    Refuses a missing file, a folder, a binary file and one that is not UTF-8."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise error(f"{p}: no such file (the {what})") from None
    except IsADirectoryError:
        raise error(f"{p}: is a folder, not a {what} file") from None
    except OSError as e:
        raise error(f"{p}: cannot read the {what} file ({e.strerror or e})") from None
    return decode(data, p, what, error)


def decode(data: bytes, p: str | Path, what: str, error: type[HtmError] = HtmError) -> str:
    """`data` (the bytes of file `p`) as UTF-8 text, or `error` saying where it is not text (or
    that there is none)."""
    nul = data.find(b"\0")
    if nul >= 0:
        raise error(f"{p}: binary data, not text (a NUL byte at offset {nul:,}); expected the {what}")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data[: e.start].count(b"\n") + 1
        raise error(f"{p}: line {line}: not UTF-8 text (byte 0x{data[e.start]:02x} at offset {e.start:,}); "
                    f"expected the {what} in UTF-8") from None
    text = text.removeprefix("\ufeff")
    if not text.strip():
        raise error(f"{p}: the file is empty; expected the {what}")
    return text


def close_match(name: str, present: Iterable[str]) -> str | None:
    """The name in `present` that `name` was most likely meant as (a misspelling or another case)."""
    present = [str(p) for p in present]
    for p in present:
        if p.lower() == name.lower() and p != name:
            return p
    found = difflib.get_close_matches(name, present, n=1, cutoff=0.6)
    return found[0] if found else None


def missing(name: str, present: Iterable[str]) -> str:
    """The end of a "`name` is missing" message: the close match present, if any."""
    m = close_match(name, present)
    return f" (found `{m}`: a misspelling of `{name}`?)" if m else ""


def finite(value: float, where: str, error: type[HtmError] = HtmError) -> float:
    """`value` if it is a finite number, else `error` naming `where` (a NaN, or 1e400 read as inf)."""
    if not math.isfinite(value):
        raise error(f"{where} = {value} is not a finite number" + (" (too large for a double: read as infinity)" if math.isinf(value) else ""))
    return value
