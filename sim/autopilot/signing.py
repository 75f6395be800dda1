"""MAVLink 2 message signing for the simulated autopilots.

A key file holds the 32-byte secret either as 64 hex characters, as 32 raw bytes, or as a
passphrase whose SHA-256 is the key (what MAVProxy's ``signing setup PASSPHRASE`` and
pymavlink's examples use). With a key configured the vehicle signs what it sends and accepts
only correctly signed messages, except the few that a real autopilot accepts unsigned
(HEARTBEAT and RADIO_STATUS); everything else unsigned or wrongly signed is dropped and counted.
"""

from __future__ import annotations

import hashlib
import string
import time
from pathlib import Path
from typing import Any

SIGNING_EPOCH_UNIX_S = 1420070400
"""MAVLink signing timestamps count 10 us units since 2015-01-01 00:00 UTC."""
ALLOWED_UNSIGNED_IDS = frozenset({0, 109})
"""HEARTBEAT and RADIO_STATUS, as ArduPilot's default ``accept_unsigned_callback``."""


def load_key(path: str | Path) -> bytes:
    """Read a signing key file (hex, raw 32 bytes, or passphrase); ``ValueError`` if unusable."""
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise ValueError(f"cannot read signing key {path}: {exc}") from None
    return key_from_bytes(data)


def key_from_bytes(data: bytes) -> bytes:
    """Key from the contents of a key file (see module docstring)."""
    text = data.strip()
    if len(text) == 64 and all(chr(c) in string.hexdigits for c in text):
        return bytes.fromhex(text.decode())
    if len(data) == 32:
        return data
    if not text:
        raise ValueError("empty signing key file")
    return hashlib.sha256(text).digest()


def signing_timestamp(unix_s: float | None = None) -> int:
    """Current signing timestamp (10 us since 2015-01-01)."""
    now = time.time() if unix_s is None else unix_s
    return int((now - SIGNING_EPOCH_UNIX_S) * 1e5)


def enable_signing(mav: Any, key: bytes, link_id: int = 0) -> None:
    """Configure a pymavlink ``MAVLink`` object to sign outgoing and check incoming messages."""
    if len(key) != 32:
        raise ValueError(f"signing key must be 32 bytes, got {len(key)}")
    mav.signing.secret_key = key
    mav.signing.sign_outgoing = True
    mav.signing.link_id = link_id
    mav.signing.timestamp = signing_timestamp()
    mav.signing.allow_unsigned_callback = _allow_unsigned


def _allow_unsigned(_mav: Any, msg_id: int) -> bool:
    return msg_id in ALLOWED_UNSIGNED_IDS


def is_signed(frame: bytes | bytearray) -> bool:
    """True if a raw MAVLink 2 frame carries a signature (incompat flag 0x01)."""
    return len(frame) > 2 and frame[0] == 0xFD and bool(frame[2] & 0x01)
