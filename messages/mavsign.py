"""MAVLink 2 message signing, verified our way (docs/mavlink.md "Signing").

pymavlink 2.4.50's own check has two holes: ``check_signature`` stores a stream's timestamp
*before* it compares the HMAC, so one forged packet with a far-future timestamp and a client's
``(link id, system, component)`` locks that client out; and ``allow_unsigned_callback`` is also
asked about packets whose signature is *wrong*, so a forged RADIO_STATUS passes. Here pymavlink
only packs (and signs what we send); every received message goes through
:class:`SignatureVerifier`:

1. a signed frame's HMAC (SHA-256 over key + frame without the 6 signature bytes, first 6
   bytes) is compared in constant time (:func:`hmac.compare_digest`) *first*; a mismatch is
   ``BAD_SIGNATURE`` and changes nothing;
2. only then the timestamp rule of the MAVLink signing spec, per stream ``(link id, system,
   component)``: a known stream must move forward, a new one may be at most one minute behind
   our clock; a failure is ``REPLAYED``; only an accepted frame updates the stream;
3. an unsigned frame is accepted only for the short allow-list :data:`ALLOWED_UNSIGNED_IDS`
   (PX4's: RADIO_STATUS, ADSB_VEHICLE, COLLISION), never a wrongly signed one.

Only ``GOOD`` messages may make their sender a peer (one that gets telemetry sent back).
"""

from __future__ import annotations

import enum
import hashlib
import hmac
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields
from typing import Any

SIGNING_EPOCH_UNIX_S = 1420070400
"""MAVLink signing timestamps count 10 us units since 2015-01-01 00:00 UTC."""
TIMESTAMP_UNITS_PER_S = 100_000
NEW_STREAM_MAX_AGE = 60 * TIMESTAMP_UNITS_PER_S
"""A new stream's first timestamp may be at most one minute behind ours (the signing spec)."""
SIGNATURE_BLOCK_LEN = 13
"""link id (1) + timestamp (6) + signature (6)."""
MAVLINK2_MAGIC = 0xFD
IFLAG_SIGNED = 0x01
RADIO_STATUS_ID, ADSB_VEHICLE_ID, COLLISION_ID = 109, 246, 247
ALLOWED_UNSIGNED_IDS = frozenset({RADIO_STATUS_ID, ADSB_VEHICLE_ID, COLLISION_ID})
"""Unsigned messages accepted with signing on: PX4's list (``MAV_SIGN_CFG``); a radio injects
RADIO_STATUS and cannot sign. HEARTBEAT is *not* on it: an unsigned heartbeat could otherwise
make its sender a peer or fake a vehicle's mode."""


class Verdict(enum.Enum):
    """What :meth:`SignatureVerifier.check` decided about one frame."""

    GOOD = "good"
    ALLOWED_UNSIGNED = "allowed_unsigned"
    UNSIGNED = "unsigned"
    BAD_SIGNATURE = "bad_signature"
    REPLAYED = "replayed"

    @property
    def accepted(self) -> bool:
        return self in (Verdict.GOOD, Verdict.ALLOWED_UNSIGNED)


@dataclass
class SigningCounters:
    """Frames by verdict (good, allowed unsigned, rejected unsigned, bad signature, replayed)."""

    good: int = 0
    allowed_unsigned: int = 0
    unsigned: int = 0
    bad_signature: int = 0
    replayed: int = 0

    def as_dict(self) -> dict[str, int]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


def signing_timestamp(unix_s: float | None = None) -> int:
    """A signing timestamp (10 us units since 2015-01-01) for ``unix_s`` (default: now)."""
    now = time.time() if unix_s is None else unix_s
    return int((now - SIGNING_EPOCH_UNIX_S) * TIMESTAMP_UNITS_PER_S)


def is_signed(frame: bytes | bytearray) -> bool:
    """True if a raw MAVLink 2 frame carries a signature (incompat flag 0x01)."""
    return len(frame) > 2 and frame[0] == MAVLINK2_MAGIC and bool(frame[2] & IFLAG_SIGNED)


def signature(key: bytes, frame_without_signature: bytes | bytearray) -> bytes:
    """The 6-byte signature: first 6 bytes of SHA-256(key + header..timestamp)."""
    return hashlib.sha256(bytes(key) + bytes(frame_without_signature)).digest()[:6]


def frame_timestamp(frame: bytes | bytearray) -> tuple[int, int]:
    """``(link_id, timestamp)`` of a signed frame."""
    return frame[-13], int.from_bytes(frame[-12:-6], "little")


KeyLookup = Callable[[int], "bytes | None"]
"""The key a given source system signs with (``None``: we hold none for it)."""


def key_lookup(keys: bytes | Mapping[int, bytes]) -> KeyLookup:
    """One key for every sender (an autopilot checks everything with its own key), or a key per
    source system (the ground station verifies vehicle ``s`` with vehicle ``s``'s key)."""
    if isinstance(keys, (bytes, bytearray)):
        key = bytes(keys)
        return lambda _sys: key
    table = dict(keys)
    return table.get


class SignatureVerifier:
    """Accept or reject received MAVLink frames (module docstring); counts every verdict.

    One verifier per receiving identity (a vehicle, a daemon's link, the ground station), shared
    by all its sockets and peers: the stream timestamps are the identity's, so a replay through
    another socket is still a replay.
    """

    def __init__(
        self,
        keys: bytes | Mapping[int, bytes],
        allowed_unsigned: frozenset[int] = ALLOWED_UNSIGNED_IDS,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self._key_for = key_lookup(keys)
        self.allowed_unsigned = allowed_unsigned
        self._clock = clock
        self._streams: dict[tuple[int, int, int], int] = {}
        self._newest = 0
        self.counters = SigningCounters()

    def local_timestamp(self) -> int:
        """Our timestamp: the wall clock, or the newest accepted one if that is ahead."""
        return max(signing_timestamp(self._clock()), self._newest)

    def check(
        self, frame: bytes | bytearray, msg_id: int, src_system: int, src_comp: int
    ) -> Verdict:
        """Verdict on one complete frame (header to signature) and count it."""
        verdict = self._verdict(frame, msg_id, src_system, src_comp)
        c = self.counters
        setattr(c, verdict.value, getattr(c, verdict.value) + 1)
        return verdict

    def _verdict(
        self, frame: bytes | bytearray, msg_id: int, src_system: int, src_comp: int
    ) -> Verdict:
        if not is_signed(frame):
            return Verdict.ALLOWED_UNSIGNED if msg_id in self.allowed_unsigned else Verdict.UNSIGNED
        key = self._key_for(src_system)
        if key is None or len(frame) < 12 + SIGNATURE_BLOCK_LEN:
            return Verdict.BAD_SIGNATURE
        if not hmac.compare_digest(signature(key, frame[:-6]), bytes(frame[-6:])):
            return Verdict.BAD_SIGNATURE  # nothing below runs: no state changes
        link_id, ts = frame_timestamp(frame)
        stream = (link_id, src_system, src_comp)
        last = self._streams.get(stream)
        if last is not None:
            if ts <= last:
                return Verdict.REPLAYED
        elif ts + NEW_STREAM_MAX_AGE < self.local_timestamp():
            return Verdict.REPLAYED
        self._streams[stream] = ts
        self._newest = max(self._newest, ts)
        return Verdict.GOOD

    def check_message(self, msg: Any) -> Verdict:
        """:meth:`check` for a message pymavlink parsed (with its own signing check off)."""
        return self.check(
            msg.get_msgbuf(), msg.get_msgId(), msg.get_srcSystem(), msg.get_srcComponent()
        )


def sign_outgoing(mav: Any, key: bytes, link_id: int) -> None:
    """Make a pymavlink ``MAVLink`` object sign what it sends with ``key`` and ``link_id``, and
    switch off its own incoming check (the holes in the module docstring): every message it
    parses must then go through a :class:`SignatureVerifier`."""
    if len(key) != 32:
        raise ValueError(f"signing key must be 32 bytes, got {len(key)}")
    if not 0 <= link_id <= 255:
        raise ValueError(f"signing link id must be in 0..255, got {link_id}")
    mav.signing.secret_key = bytes(key)
    mav.signing.sign_outgoing = True
    mav.signing.link_id = link_id
    mav.signing.timestamp = signing_timestamp()
    mav.signing.allow_unsigned_callback = _accept_all
    mav.check_signature = _signature_checked_later


def _accept_all(_mav: Any, _msg_id: int) -> bool:
    return True


def _signature_checked_later(_msgbuf: Any, _src_system: int, _src_comp: int) -> bool:
    return True


def keep_timestamp_current(mav: Any) -> None:
    """Before a send: a signing timestamp never behind the wall clock (a restarted sender and a
    long-running one both stay ahead of what a receiver stored for their stream)."""
    mav.signing.timestamp = max(mav.signing.timestamp, signing_timestamp())
