"""The append-only test journal: length- and checksum-framed records, one file per run segment.

A segment file starts with `MAGIC`, then records: `u32 length | u32 crc32 | u8 kind | payload`
(little endian; the CRC covers kind and payload). A payload is `u32 n | n bytes of JSON meta |
arrays | blob`, where `meta["arrays"]` lists `[name, numpy dtype, shape]` and `meta["blob"]` the
blob's length, so rows stay binary (exact f64) while the meta stays readable.

Durability: every record is written whole and flushed to the OS at once (a SIGKILL of the
process loses nothing written); `os.fsync` runs at every event, at close, and otherwise at most
`fsync_interval_s` (1 s) after the previous one (power loss costs at most the last second).
Reading: a record cut short or failing its checksum at the very end of a segment is a torn write
and is dropped; anything else that fails to decode is corruption and raises `RecordError`
naming the file and byte offset, without changing anything. After a write error the writer is
closed for good (the next run appends a new segment), so a torn record is always a segment's last.
"""
from __future__ import annotations

import json
import os
import struct
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from htm.errors import RecordError

MAGIC = b"HTMJRNL1"
_HEAD = struct.Struct("<IIB")
_U32 = struct.Struct("<I")

# record kinds
HEADER = b"H"   # who wrote this segment (test id, segment number, software)
CHUNK = b"C"    # per-cycle rows (+ raw samples, + engine snapshot as blob)
SIGNALS = b"W"  # a decimated window of live signals
EVENT = b"E"    # an event (limit trip, mode change, operator action)
CLOSE = b"Z"    # the test ended: status, end reason, summary


@dataclass
class Record:
    kind: bytes
    meta: dict[str, Any]
    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    blob: bytes = b""


def encode(kind: bytes, meta: dict[str, Any], arrays: dict[str, np.ndarray] | None = None, blob: bytes = b"") -> bytes:
    """One framed record."""
    arrays = {k: np.ascontiguousarray(v) for k, v in (arrays or {}).items()}
    m = dict(meta, arrays=[[k, v.dtype.str, list(v.shape)] for k, v in arrays.items()], blob=len(blob))
    js = json.dumps(m, separators=(",", ":"), default=float).encode()
    payload = b"".join([kind, _U32.pack(len(js)), js, *(v.tobytes() for v in arrays.values()), blob])
    return _HEAD.pack(len(payload) - 1, zlib.crc32(payload), kind[0]) + payload[1:]


def _decode(payload: memoryview, kind: bytes) -> Record:
    (n,) = _U32.unpack_from(payload, 0)
    meta = json.loads(bytes(payload[4:4 + n]))
    pos = 4 + n
    arrays = {}
    for name, dt, shape in meta.pop("arrays"):
        dtype = np.dtype(dt)
        size = dtype.itemsize * int(np.prod(shape, dtype=np.int64))
        arrays[name] = np.frombuffer(payload[pos:pos + size], dtype=dtype).reshape(shape).copy()
        pos += size
    nb = meta.pop("blob")
    blob = bytes(payload[pos:pos + nb])
    if pos + nb != len(payload):
        raise RecordError("journal: payload length does not match its arrays")
    return Record(kind, meta, arrays, blob)


@dataclass
class Segment:
    path: Path
    records: list[Record]
    torn_bytes: int  # bytes of a torn last record that were dropped (0: clean end)


def read_segment(path: Path) -> Segment:
    """Every whole record of one segment file; a torn last record is dropped, not an error."""
    data = memoryview(Path(path).read_bytes())
    if bytes(data[:len(MAGIC)]) != MAGIC:
        if len(data) < len(MAGIC) and MAGIC.startswith(bytes(data)):
            return Segment(Path(path), [], len(data))  # killed while writing the magic
        raise RecordError(f"journal {path} is not an htm journal (bad magic); nothing was changed")
    pos, size, out = len(MAGIC), len(data), []
    while pos < size:
        if size - pos < _HEAD.size:
            return Segment(Path(path), out, size - pos)
        length, crc, kind = _HEAD.unpack_from(data, pos)
        end = pos + _HEAD.size + length
        if end > size:
            return Segment(Path(path), out, size - pos)
        payload = bytes([kind]) + bytes(data[pos + _HEAD.size:end])
        if zlib.crc32(payload) != crc:
            if end == size:
                return Segment(Path(path), out, size - pos)
            raise RecordError(f"journal {path} is corrupted at byte {pos} (checksum mismatch, {size - end} bytes follow); "
                              "nothing was changed — restore the file from a backup or export what precedes it")
        try:
            out.append(_decode(memoryview(payload)[1:], bytes([kind])))
        except (ValueError, KeyError, TypeError) as e:
            raise RecordError(f"journal {path} is corrupted at byte {pos} ({e}); nothing was changed") from None
        pos = end
    return Segment(Path(path), out, 0)


def segments(test_dir: Path) -> list[Path]:
    """The journal segment files of a test, in order."""
    return sorted(Path(test_dir).glob("journal-*.htmj"))


def read_journal(test_dir: Path) -> list[Segment]:
    return [read_segment(p) for p in segments(test_dir)]


class JournalWriter:
    """Appends records to a new segment file. `opener(path)` returns the binary file (tests inject
    one that fails like a full disk); a write error closes the writer and raises `RecordError`."""

    def __init__(self, path: Path, *, fsync_interval_s: float = 1.0, opener: Callable[[Path], BinaryIO] | None = None):
        self.path = Path(path)
        if self.path.exists():
            raise RecordError(f"journal segment {self.path} already exists; nothing was overwritten")
        self.fsync_interval_s = fsync_interval_s
        self._f: BinaryIO | None = (opener or (lambda p: open(p, "xb")))(self.path)
        self._last_sync = time.monotonic()
        self.bytes_written = 0
        self._write(MAGIC, sync=True)

    @property
    def closed(self) -> bool:
        return self._f is None

    def _write(self, data: bytes, sync: bool) -> None:
        if self._f is None:
            raise RecordError(f"journal {self.path} is closed after an earlier write error")
        try:
            self._f.write(data)
            self._f.flush()
            now = time.monotonic()
            if sync or now - self._last_sync >= self.fsync_interval_s:
                os.fsync(self._f.fileno())
                self._last_sync = now
        except OSError as e:
            f, self._f = self._f, None
            try:
                f.close()
            except OSError:
                pass
            raise RecordError(f"cannot write the journal {self.path}: {e.strerror or e}") from e
        self.bytes_written += len(data)

    def append(self, kind: bytes, meta: dict[str, Any], arrays: dict[str, np.ndarray] | None = None,
               blob: bytes = b"", sync: bool = False) -> None:
        """Append one record; `sync` forces an fsync now (events, close)."""
        self._write(encode(kind, meta, arrays, blob), sync)

    def close(self) -> None:
        if self._f is not None:
            f, self._f = self._f, None
            try:
                f.flush()
                os.fsync(f.fileno())
            finally:
                f.close()
