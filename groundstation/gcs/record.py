"""Record everything the ground station hears into an MCAP file (https://mcap.dev).

Channels (no schemas; every message's ``log_time`` is the wall-clock receive time in ns):

* one per Zenoh key, topic = the key (``bf/alpha/3/status``), encoding ``msgpack`` — the raw
  sample bytes, malformed or foreign ones included, exactly as received;
* one per liveliness key (``bf/alpha/3/alive``), encoding :data:`LIVELINESS_ENCODING`, data
  ``b"1"`` when the token appears and ``b"0"`` when it goes;
* one per MAVLink system, topic ``mavlink/<sysid>``, encoding :data:`MAVLINK_ENCODING` — each
  raw MAVLink frame as received.

:func:`iter_records` reads a file back in log-time order (also a file whose recorder was killed
before writing the summary). Foxglove Studio and the ``mcap`` CLI open these files.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

ZENOH_ENCODING = "msgpack"
LIVELINESS_ENCODING = "bearingflock/liveliness"
MAVLINK_ENCODING = "mavlink"
MAVLINK_TOPIC_PREFIX = "mavlink/"
CHUNK_BYTES = 256 * 1024


@dataclass(frozen=True)
class Record:
    """One recorded message."""

    topic: str
    encoding: str
    data: bytes
    log_time_ns: int


@dataclass
class Recorder:
    """Thread-safe MCAP writer; hook :meth:`zenoh_sample`, :meth:`alive` and :meth:`mavlink`
    into the listeners. :meth:`close` writes the summary (always call it)."""

    path: Path
    fleet: str
    counts: dict[str, int] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _channels: dict[tuple[str, str], int] = field(default_factory=dict)
    _seq: dict[int, int] = field(default_factory=dict)
    _file: IO[bytes] | None = None
    _writer: Any = None

    def __post_init__(self) -> None:
        from mcap.writer import Writer

        self.path = Path(self.path)
        self._file = self.path.open("wb")
        self._writer = Writer(self._file, chunk_size=CHUNK_BYTES)
        self._writer.start(profile="", library="bearingflock gcs record")
        self._writer.add_metadata(
            "bearingflock", {"fleet": self.fleet, "started_unix_s": f"{time.time():.3f}"}
        )

    def _add(self, topic: str, encoding: str, data: bytes, t_wall_s: float, kind: str) -> None:
        t_ns = int(t_wall_s * 1e9)
        with self._lock:
            if self._writer is None:
                return
            ch = self._channels.get((topic, encoding))
            if ch is None:
                ch = self._writer.register_channel(topic, encoding, 0, {"source": kind})
                self._channels[(topic, encoding)] = ch
            seq = self._seq.get(ch, 0)
            self._seq[ch] = seq + 1
            self._writer.add_message(ch, t_ns, bytes(data), t_ns, seq)
            self.counts[kind] = self.counts.get(kind, 0) + 1

    def zenoh_sample(self, key: str, data: bytes, t_wall_s: float) -> None:
        self._add(key, ZENOH_ENCODING, data, t_wall_s, "zenoh")

    def alive(self, key: str, alive: bool, t_wall_s: float) -> None:
        self._add(key, LIVELINESS_ENCODING, b"1" if alive else b"0", t_wall_s, "liveliness")

    def mavlink(self, msg: Any, raw: bytes, t_wall_s: float) -> None:
        topic = f"{MAVLINK_TOPIC_PREFIX}{int(msg.get_srcSystem())}"
        self._add(topic, MAVLINK_ENCODING, raw, t_wall_s, "mavlink")

    def close(self) -> None:
        with self._lock:
            if self._writer is not None:
                self._writer.finish()
                self._writer = None
            if self._file is not None:
                self._file.close()
                self._file = None


MCAP_MAGIC = b"\x89MCAP0\r\n"
"""The first 8 bytes of every MCAP file (MCAP specification, "Magic")."""


class NotMcapError(ValueError):
    """The file is not an MCAP recording at all (an unfinished one is still read)."""


def check_mcap(path: str | Path) -> None:
    """Raise :class:`NotMcapError` unless the file starts with the MCAP magic bytes."""
    with Path(path).open("rb") as f:
        if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise NotMcapError(f"{path}: not an MCAP recording (written by `gcs record`)")


def iter_records(path: str | Path) -> Iterator[Record]:
    """Every message of an MCAP file in log-time order. Raises :class:`NotMcapError` if the
    file does not start with the MCAP magic bytes."""
    from mcap.exceptions import McapError
    from mcap.reader import NonSeekingReader, make_reader

    path = Path(path)
    check_mcap(path)
    with path.open("rb") as f:
        try:
            reader = make_reader(f)
            items = list(reader.iter_messages(log_time_order=True))
        except (McapError, ValueError, EOFError):
            items = []
            f.seek(0)
            try:  # an unfinished file: read chunk by chunk as far as it goes
                for item in NonSeekingReader(f).iter_messages():
                    items.append(item)
            except (McapError, ValueError, EOFError):
                pass
            items.sort(key=lambda it: it[2].log_time)
    for _schema, channel, message in items:
        yield Record(channel.topic, channel.message_encoding, bytes(message.data), message.log_time)
