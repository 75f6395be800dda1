"""MAVLink 2 message signing for the simulated autopilots.

A key file holds the 32-byte secret either as 64 hex characters, as 32 raw bytes, or as a
passphrase whose SHA-256 is the key (what MAVProxy's ``signing setup PASSPHRASE`` and
pymavlink's examples use). With a key configured the vehicle signs what it sends and accepts
only correctly signed messages, except the few that PX4 accepts unsigned (RADIO_STATUS,
ADSB_VEHICLE, COLLISION); everything else unsigned, wrongly signed or replayed is dropped and
counted. The check is :class:`messages.mavsign.SignatureVerifier` (HMAC first, then the
timestamp per stream), not pymavlink's.
"""

from __future__ import annotations

import hashlib
import string
from pathlib import Path
from typing import Any

from messages.mavsign import (  # noqa: F401  (re-exported for the simulator's callers)
    ALLOWED_UNSIGNED_IDS,
    SIGNING_EPOCH_UNIX_S,
    is_signed,
    sign_outgoing,
    signing_timestamp,
)


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


def enable_signing(mav: Any, key: bytes, link_id: int = 0) -> None:
    """Sign what ``mav`` sends; its incoming check is off (:func:`messages.mavsign.sign_outgoing`),
    the :class:`~messages.mavsign.SignatureVerifier` of the vehicle decides."""
    sign_outgoing(mav, key, link_id)
