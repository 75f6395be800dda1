"""The agent core's flight recorder: every input of every core step, for an exact replay.

The agent core is deterministic: given its configuration and the sequence of ``(t_s, own
measurements, inbox)`` of its steps it computes the same estimates and commands again. A
daemon started with ``BEARINGFLOCK_CORE_TAPE=DIR`` in its environment (the demo's and the
benchmarks' daemons inherit it) writes exactly that to ``DIR/agent<I>.tape``, so a flight on real firmware can be replayed offline
with :func:`replay`, with the same or a changed configuration: what an estimator option would
have done on that flight, without flying it again (issue 22's real-firmware drift was
studied this way). Nothing of the simulator's truth is in a tape, only what the core saw.

Format: a stream of frames, each a 4-byte big-endian length and a MessagePack document. The
first is the header ``{"version": 1, "agent_id": I, "config": AgentConfig}``; then one
``[t_s, OwnMeasurements, [payload, ...]]`` per core step, the payloads in the wire encoding
(:func:`messages.codec.encode`). A tape cut short by a crash reads up to its last whole frame.
About 9 MB per minute per daemon at the default rates (3 vehicles, SITL).
"""

from __future__ import annotations

import logging
import os
import struct
import threading
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any, BinaryIO

import msgspec

from messages.agent import OwnMeasurements, Setpoint
from messages.codec import Payload, decode, encode
from messages.peer import PeerPayload
from onboard.core.config import AgentConfig

log = logging.getLogger(__name__)

TAPE_ENV = "BEARINGFLOCK_CORE_TAPE"
"""Directory for the daemons' tapes (one ``agent<I>.tape`` each; empty or unset: none)."""
TAPE_VERSION = 1
_LEN = struct.Struct(">I")


class TapeHeader(msgspec.Struct, forbid_unknown_fields=True):
    version: int
    agent_id: int
    config: AgentConfig


class TapeError(ValueError):
    """A file that is not a core tape, or one of another version."""


def tape_path(agent_id: int) -> Path | None:
    """The tape to write, ``$BEARINGFLOCK_CORE_TAPE/agent<I>.tape`` (None: no tape)."""
    folder = os.environ.get(TAPE_ENV, "")
    return Path(folder) / f"agent{agent_id}.tape" if folder else None


class TapeWriter:
    """Appends core steps to a tape. Thread-safe; :meth:`close` flushes. A write that fails (a
    full disk) stops the recording with one logged error, never the daemon: :attr:`failed`."""

    def __init__(self, path: str | Path, config: AgentConfig) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file: BinaryIO = self.path.open("wb")
        self._enc = msgspec.msgpack.Encoder()
        self._lock = threading.Lock()
        self.failed = False
        self._write(TapeHeader(TAPE_VERSION, config.graph.agent_id, config))

    def _write(self, doc: Any) -> None:
        if self.failed:
            return
        data = self._enc.encode(doc)
        with self._lock:
            try:
                self._file.write(_LEN.pack(len(data)) + data)
            except (OSError, ValueError) as exc:  # ValueError: written after close
                self.failed = True
                log.error("core tape %s: recording stopped (%s)", self.path, exc)

    def step(self, t_s: float, own: OwnMeasurements, inbox: Iterable[Payload]) -> None:
        """Record one core step's inputs."""
        if not self.failed:
            self._write((t_s, own, [encode(p) for p in inbox]))

    def close(self) -> None:
        with self._lock:
            try:
                self._file.close()
            except OSError as exc:
                log.error("core tape %s: %s", self.path, exc)


def open_tape(path: Path | None, config: AgentConfig) -> TapeWriter | None:
    """The daemon's tape at ``path`` (None: none); one that cannot be opened is logged and the
    daemon flies without it."""
    if path is None:
        return None
    try:
        return TapeWriter(path, config)
    except OSError as exc:
        log.error("core tape %s cannot be written (%s): flying without it", path, exc)
        return None


def _frames(f: BinaryIO) -> Iterator[bytes]:
    while len(head := f.read(_LEN.size)) == _LEN.size:
        (n,) = _LEN.unpack(head)
        data = f.read(n)
        if len(data) < n:  # cut short by a crash: the last whole frame was the end
            return
        yield data


_Step = tuple[float, OwnMeasurements, list[bytes]]


def read_tape(
    path: str | Path,
) -> tuple[TapeHeader, Iterator[tuple[float, OwnMeasurements, list[Payload]]]]:
    """The header and an iterator over ``(t_s, own, inbox)`` of every recorded step."""
    f = Path(path).open("rb")
    frames = _frames(f)
    first = next(frames, None)
    try:
        header = msgspec.msgpack.decode(first or b"", type=TapeHeader)
    except msgspec.ValidationError as exc:
        f.close()
        raise TapeError(f"{path}: not a core tape ({exc})") from None
    except msgspec.DecodeError:
        f.close()
        raise TapeError(f"{path}: not a core tape") from None
    if header.version != TAPE_VERSION:
        f.close()
        raise TapeError(f"{path}: tape version {header.version}, this reader {TAPE_VERSION}")
    step_dec = msgspec.msgpack.Decoder(_Step)

    def steps() -> Iterator[tuple[float, OwnMeasurements, list[Payload]]]:
        with f:
            for data in frames:
                t_s, own, raw = step_dec.decode(data)
                yield t_s, own, [decode(p, PeerPayload) for p in raw]

    return header, steps()


def replay(
    path: str | Path,
    change: Callable[[AgentConfig], AgentConfig] | None = None,
    until_s: float | None = None,
) -> Iterator[tuple[float, Setpoint, list[Payload]]]:
    """Run a fresh core on a tape's inputs (``change``: a different configuration); yields each
    step's ``(t_s, setpoint, payloads out)``. The same configuration gives the flight's own
    outputs again (the daemon's sub-steps across late ticks are on the tape as steps)."""
    from onboard.core.agent import AgentCore

    header, steps = read_tape(path)
    core = AgentCore(change(header.config) if change else header.config)
    for t_s, own, inbox in steps:
        if until_s is not None and t_s > until_s:
            return
        setpoint, out = core.step(t_s, own, inbox)
        yield t_s, setpoint, out
