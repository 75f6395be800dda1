"""Record everything the ground station hears into an MCAP file (https://mcap.dev) that
Foxglove shows as it is, and every MAVLink frame into a ``.tlog`` beside it.

Every channel has a JSON Schema and JSON messages (:mod:`groundstation.gcs.schemas`); every
message's ``log_time`` is the wall-clock receive time in ns; each channel's metadata says its
``source``:

* ``zenoh`` — one channel per Zenoh key and payload type, topic = the key
  (``bf/alpha/3/status``), schema ``bearingflock.<Type>`` from the msgspec struct; samples that
  are not a valid payload (malformed, foreign, another version) are kept verbatim, base64, on a
  ``bearingflock.RawSample`` channel of their key;
* ``liveliness`` — one per liveliness key (``bf/alpha/3/alive``), ``{"alive": true|false}``;
* ``mavlink`` — one per MAVLink system and message, topic ``mavlink/<sysid>/<NAME>``, schema
  ``mavlink.<NAME>`` (the raw frames are in the ``.tlog``: :mod:`groundstation.gcs.tlog`);
* ``scene`` — Foxglove's ``foxglove.FrameTransforms`` and ``foxglove.SceneUpdate`` of the
  team (:mod:`groundstation.gcs.foxglove_scene`), so the 3D panel shows it.

:func:`iter_records` gives back the Zenoh samples as their exact wire bytes (encoding
:data:`ZENOH_ENCODING`) and liveliness as ``b"1"``/``b"0"`` (:data:`LIVELINESS_ENCODING`), from
these files and from those of earlier versions (schema-less ``msgpack`` and ``mavlink``
channels), so replay and plots read both.
"""

from __future__ import annotations

import struct
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import IO, Any

import msgspec

from groundstation.gcs import schemas
from groundstation.gcs.foxglove_scene import (
    FRAME_TRANSFORMS_SCHEMA,
    SCENE_SCHEMA_NAME,
    SCENE_TOPIC,
    SCENE_UPDATE_SCHEMA,
    TRANSFORMS_SCHEMA_NAME,
    TRANSFORMS_TOPIC,
    SceneBuilder,
)
from groundstation.gcs.tlog import TlogWriter

ZENOH_ENCODING = "msgpack"
"""Encoding of the Zenoh samples :func:`iter_records` yields (and of old recordings' channels)."""
LIVELINESS_ENCODING = "bearingflock/liveliness"
MAVLINK_ENCODING = "mavlink"
"""Raw MAVLink frames: the channels of recordings written before the JSON ones."""
MAVLINK_TOPIC_PREFIX = "mavlink/"
_scene_json = msgspec.json.Encoder()
CHUNK_BYTES = 64 * 1024
"""Uncompressed size at which a chunk is written out (MCAP compresses per chunk)."""
FLUSH_PERIOD_S = 1.0
"""A chunk is also written out, and the file flushed, at least this often while messages come:
a recorder killed without warning (SIGKILL, power loss) loses at most the last
``FLUSH_PERIOD_S`` or the last :data:`CHUNK_BYTES` of messages, whichever is less."""


class Source(str, Enum):
    """Words of a channel's ``source`` metadata (and :attr:`Record.source`)."""

    ZENOH = "zenoh"
    LIVELINESS = "liveliness"
    MAVLINK = "mavlink"
    SCENE = "scene"

    def __str__(self) -> str:
        return self.value

    def __format__(self, spec: str) -> str:
        return format(self.value, spec)


@dataclass(frozen=True)
class Record:
    """One recorded message, as the ground station received it."""

    topic: str
    encoding: str
    data: bytes
    log_time_ns: int
    source: str = ""


def tlog_path(mcap_path: str | Path) -> Path:
    """Where the ``.tlog`` of a recording goes: beside it, same name."""
    return Path(mcap_path).with_suffix(".tlog")


@dataclass
class Recorder:
    """Thread-safe MCAP (and ``.tlog``) writer; hook :meth:`zenoh_sample`, :meth:`alive` and
    :meth:`mavlink` into the listeners. :meth:`close` writes the summary (always call it)."""

    path: Path
    fleet: str
    tlog: bool = True
    chunk_bytes: int = CHUNK_BYTES
    counts: dict[str, int] = field(default_factory=dict)
    scene: SceneBuilder = field(default_factory=SceneBuilder)
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _schemas: dict[str, int] = field(default_factory=dict)
    _channels: dict[tuple[str, str], int] = field(default_factory=dict)
    _seq: dict[int, int] = field(default_factory=dict)
    _file: IO[bytes] | None = None
    _writer: Any = None
    _tlog: TlogWriter | None = None
    _flushed_s: float = 0.0
    _flusher: threading.Thread | None = None
    _stop: threading.Event = field(default_factory=threading.Event)

    def __post_init__(self) -> None:
        from mcap.writer import Writer

        self.path = Path(self.path)
        self._file = self.path.open("wb")
        if self.tlog:
            self._tlog = TlogWriter(tlog_path(self.path))
        self._writer = Writer(self._file, chunk_size=self.chunk_bytes)
        self._writer.start(profile="", library="bearingflock gcs record")
        self._writer.add_metadata(
            "bearingflock", {"fleet": self.fleet, "started_unix_s": f"{time.time():.3f}"}
        )
        self._file.flush()  # the header is on disk: a killed recorder leaves an MCAP file
        self._flushed_s = time.monotonic()
        self._flusher = threading.Thread(target=self._flush_loop, name="mcap-flush", daemon=True)
        self._flusher.start()

    def _flush_loop(self) -> None:
        """Flush in quiet moments too (a chunk with no messages is not written)."""
        while not self._stop.wait(FLUSH_PERIOD_S / 2):
            with self._lock:
                if self._writer is None:
                    return
                if time.monotonic() - self._flushed_s >= FLUSH_PERIOD_S:
                    self._flush()

    def _flush(self) -> None:
        """Write the open chunk and flush both files (the lock is held)."""
        self._writer.flush()
        if self._tlog is not None:
            self._tlog.flush()
        self._flushed_s = time.monotonic()

    def _schema_id(self, name: str, data: bytes) -> int:
        sid = self._schemas.get(name)
        if sid is None:
            sid = self._writer.register_schema(name, schemas.SCHEMA_ENCODING, data)
            self._schemas[name] = sid
        return sid

    def _write(
        self, topic: str, schema: tuple[str, bytes], data: bytes, t_ns: int, source: Source
    ) -> None:
        """Write one message (the lock is held)."""
        ch = self._channels.get((topic, schema[0]))
        if ch is None:
            sid = self._schema_id(*schema)
            ch = self._writer.register_channel(
                topic, schemas.JSON_ENCODING, sid, {"source": Source(source).value}
            )
            self._channels[(topic, schema[0])] = ch
        seq = self._seq.get(ch, 0)
        self._seq[ch] = seq + 1
        self._writer.add_message(ch, t_ns, data, t_ns, seq)
        self.counts[source.value] = self.counts.get(source.value, 0) + 1
        if time.monotonic() - self._flushed_s >= FLUSH_PERIOD_S:
            self._flush()

    def zenoh_sample(self, key: str, data: bytes, t_wall_s: float) -> None:
        t_ns = int(t_wall_s * 1e9)
        payload, reason = schemas.decode_sample(data)
        if payload is None:
            schema = (schemas.RAW_SCHEMA_NAME, schemas.RAW_SCHEMA)
            body = schemas.raw_json(data, reason)
        else:
            cls = type(payload)
            schema = (schemas.payload_schema_name(cls), schemas.payload_schema(cls))
            body = schemas.payload_json(payload)
        with self._lock:
            if self._writer is None:
                return
            self._write(key, schema, body, t_ns, Source.ZENOH)
            if payload is not None:
                self.scene.add(payload, t_ns)
                self._maybe_scene(t_ns)

    def _maybe_scene(self, t_ns: int) -> None:
        msgs = self.scene.messages(t_ns)
        if msgs is None:
            return
        tfs, update = msgs
        self._write(
            TRANSFORMS_TOPIC, (TRANSFORMS_SCHEMA_NAME, FRAME_TRANSFORMS_SCHEMA),
            _scene_json.encode(tfs), t_ns, Source.SCENE,
        )  # fmt: skip
        self._write(
            SCENE_TOPIC, (SCENE_SCHEMA_NAME, SCENE_UPDATE_SCHEMA),
            _scene_json.encode(update), t_ns, Source.SCENE,
        )  # fmt: skip

    def alive(self, key: str, alive: bool, t_wall_s: float) -> None:
        schema = (schemas.LIVELINESS_SCHEMA_NAME, schemas.LIVELINESS_SCHEMA)
        with self._lock:
            if self._writer is not None:
                self._write(
                    key, schema, schemas.liveliness_json(alive), int(t_wall_s * 1e9),
                    Source.LIVELINESS,
                )  # fmt: skip

    def mavlink(self, msg: Any, raw: bytes, t_wall_s: float) -> None:
        name = str(msg.get_type())
        topic = f"{MAVLINK_TOPIC_PREFIX}{int(msg.get_srcSystem())}/{name}"
        try:
            schema = (f"{schemas.MAVLINK_SCHEMA_PREFIX}{name}", schemas.mavlink_schema(type(msg)))
            body = schemas.mavlink_json(msg)
        except (AttributeError, TypeError, ValueError):  # not a decoded message (BAD_DATA, ...)
            schema = (schemas.RAW_SCHEMA_NAME, schemas.RAW_SCHEMA)
            body = schemas.raw_json(raw, f"MAVLink {name}")
        with self._lock:
            if self._writer is None:
                return
            if self._tlog is not None:
                self._tlog.write(raw, t_wall_s)
            self._write(topic, schema, body, int(t_wall_s * 1e9), Source.MAVLINK)

    def close(self) -> None:
        self._stop.set()
        with self._lock:
            if self._writer is not None:
                self._writer.finish()
                self._writer = None
            if self._file is not None:
                self._file.close()
                self._file = None
            if self._tlog is not None:
                self._tlog.close()
                self._tlog = None


MCAP_MAGIC = b"\x89MCAP0\r\n"
"""The first 8 bytes of every MCAP file (MCAP specification, "Magic")."""


class NotMcapError(ValueError):
    """The file is not an MCAP recording at all (an unfinished one is still read)."""


def check_mcap(path: str | Path) -> None:
    """Raise :class:`NotMcapError` unless the file starts with the MCAP magic bytes."""
    with Path(path).open("rb") as f:
        if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise NotMcapError(f"{path}: not an MCAP recording (written by `gcs record`)")


def to_record(schema: Any, channel: Any, message: Any) -> Record | None:
    """One MCAP message as a :class:`Record`: Zenoh samples as their wire bytes, liveliness as
    ``b"1"``/``b"0"``; JSON MAVLink and scene messages as they are; ``None`` for a message this
    version cannot read (a payload schema it does not know)."""
    data, t = bytes(message.data), message.log_time
    enc, topic = channel.message_encoding, channel.topic
    source = channel.metadata.get("source", "")
    if enc != schemas.JSON_ENCODING:  # an earlier version's schema-less channel
        old = {ZENOH_ENCODING: Source.ZENOH, LIVELINESS_ENCODING: Source.LIVELINESS}
        return Record(topic, enc, data, t, old.get(enc, Source.MAVLINK))
    name = schema.name if schema is not None else ""
    if source == Source.LIVELINESS:
        alive = schemas.liveliness_from_json(data)
        return Record(topic, LIVELINESS_ENCODING, b"1" if alive else b"0", t, source)
    if source == Source.ZENOH:
        try:
            if name == schemas.RAW_SCHEMA_NAME:
                wire = schemas.raw_from_json(data)
            else:
                wire = schemas.payload_to_msgpack(data, name)
        except (ValueError, KeyError, TypeError):
            return None
        return Record(topic, ZENOH_ENCODING, wire, t, source)
    return Record(topic, enc, data, t, source)


@dataclass
class Recording:
    """What :func:`read_recording` found: the records in log-time order, and whether the file
    was closed (``complete``) or is what a killed recorder left (read up to its last whole
    chunk; ``dropped_tail_bytes`` after it could not be read)."""

    records: list[Record]
    complete: bool
    dropped_tail_bytes: int = 0
    unreadable: int = 0
    """Messages of a payload schema this version does not know."""

    def describe(self, path: str | Path) -> str:
        """One line for the operator; empty for a complete file."""
        if self.complete:
            return ""
        return (
            f"{path} was not closed (its recorder was killed?): recovered {len(self.records)} "
            f"messages up to its last complete chunk, {self.dropped_tail_bytes} bytes after it "
            "unreadable"
        )


def _read_unfinished(f: IO[bytes], size: int) -> tuple[list, int]:
    """Every message of the whole chunks of a file that has no summary (a killed recorder's),
    and how many bytes at its end could not be read. Read in file order
    (``log_time_order=False``: the reader's time ordering buffers everything until the end of
    the file and loses it all on a truncated tail)."""
    from mcap.exceptions import McapError
    from mcap.reader import NonSeekingReader

    f.seek(0)
    items: list = []
    good_end = 0
    try:
        for item in NonSeekingReader(f).iter_messages(log_time_order=False):
            items.append(item)
            good_end = f.tell()
    except (McapError, ValueError, EOFError, OSError, MemoryError, struct.error):
        pass  # the truncated tail: keep what came before it
    else:
        good_end = size
    items.sort(key=lambda it: it[2].log_time)
    return items, max(0, size - good_end)


def read_recording(path: str | Path) -> Recording:
    """Every message of an MCAP file in log-time order, also of a file whose recorder was
    killed (see :class:`Recording`). Raises :class:`NotMcapError` if the file does not start
    with the MCAP magic bytes."""
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    path = Path(path)
    check_mcap(path)
    size = path.stat().st_size
    complete, tail = True, 0
    with path.open("rb") as f:
        try:
            reader = make_reader(f)
            if reader.get_summary() is None:
                raise McapError("no summary")
            items = list(reader.iter_messages(log_time_order=True))
        except (McapError, ValueError, EOFError, OSError, struct.error):
            complete = False
            items, tail = _read_unfinished(f, size)
    records, unreadable = [], 0
    for schema, channel, message in items:
        rec = to_record(schema, channel, message)
        if rec is None:
            unreadable += 1
        else:
            records.append(rec)
    return Recording(records, complete, tail, unreadable)


def iter_records(path: str | Path) -> Iterator[Record]:
    """The records of :func:`read_recording` (a killed recorder's file too)."""
    yield from read_recording(path).records
