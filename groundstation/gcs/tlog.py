"""MAVLink telemetry logs (``.tlog``), the format MAVProxy, QGroundControl and pymavlink's
``mavlogfile`` read and write: for every frame, its receive time as an 8-byte big-endian count
of microseconds since the Unix epoch, then the raw frame."""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path
from typing import IO

_STAMP = struct.Struct(">Q")


def tlog_record(raw: bytes, t_wall_s: float) -> bytes:
    """One tlog record: the stamp (us, big-endian) and the frame."""
    return _STAMP.pack(int(t_wall_s * 1e6)) + bytes(raw)


class TlogWriter:
    """Append-only ``.tlog`` writer (not thread-safe: the recorder holds its lock)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file: IO[bytes] | None = self.path.open("wb")
        self.frames = 0

    def write(self, raw: bytes, t_wall_s: float) -> None:
        if self._file is not None:
            self._file.write(tlog_record(raw, t_wall_s))
            self.frames += 1

    def flush(self) -> None:
        if self._file is not None:
            self._file.flush()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


def iter_tlog_stamps(path: str | Path) -> Iterator[tuple[int, bytes]]:
    """``(stamp_us, frame)`` of a tlog whose frames are MAVLink v1 or v2 (for tests and tools
    that do not want pymavlink); stops at a truncated tail."""
    data = Path(path).read_bytes()
    k = 0
    while k + 8 + 2 <= len(data):
        (t_us,) = _STAMP.unpack_from(data, k)
        start = k + 8
        magic, length = data[start], data[start + 1]
        if magic == 0xFD:
            incompat = data[start + 2] if start + 2 < len(data) else 0
            n = 12 + length + 13 * bool(incompat & 0x01)
        elif magic == 0xFE:
            n = 8 + length
        else:
            return
        if start + n > len(data):
            return
        yield t_us, data[start : start + n]
        k = start + n
