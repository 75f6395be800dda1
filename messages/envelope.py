"""One peer message per publish tick: the tick's payloads batched in a :class:`PeerEnvelope`.

An agent publishes, per publish period, the newest payload of each kind it has
(:mod:`messages.peer`, :mod:`messages.rigidity`): up to 8 kinds. Each on its own key, a daemon
of a 6-vehicle team handled about 1,150 Zenoh samples and Python callbacks per second, and Zenoh
(its Rust threads and the callbacks) was the largest share of the daemon's CPU (issue 27). One
envelope per tick on ``bf/<fleet>/<id>/peer`` (:data:`messages.keys.PEER_TOPIC`) is one sample
and one callback for all of them.

The envelope changes the transport, not the payloads: :func:`unpack` gives back the individual
payloads the agent core's inbox took before, each checked as :func:`messages.codec.decode`
checks a payload of its own (schema version, NaN and infinity, the bounds of
:mod:`messages.limits`, the float64 arrays, a fleet member as sender), and each must name as
its sender the agent whose key the envelope came on. The checks are per payload: a bad one is
dropped with its reason, its siblings are kept (msgspec decodes the whole envelope in C; only
when that fails are the payloads decoded one by one, to tell which one is bad and why). A
receiver's replay window stays per (sender, kind) (:mod:`onboard.daemon.replay`): each payload
keeps its own header (``seq``, ``stamp_s``).
"""

from __future__ import annotations

from collections.abc import Collection, Iterable
from dataclasses import dataclass, field
from typing import Annotated, Any

import msgspec

from messages.codec import (
    MAX_PAYLOAD_BYTES,
    SCHEMA_VERSION,
    MessageError,
    Payload,
    _dec_hook,
    check_payload,
    decode,
    decode_struct,
    encode,
    encode_unchecked,
    may_hold_nonfinite,
)
from messages.keys import PEER_TOPIC, parse_key
from messages.limits import AgentId, Seq, Stamp
from messages.peer import PeerPayload
from messages.vocabulary import DropReason

ENVELOPE_MAX_PAYLOADS = 16
"""Most payloads in one envelope: one per kind (9 today), with room for kinds to come."""


class PeerEnvelope(Payload, tag="peer.envelope"):
    """The peer payloads one agent publishes in one tick, the newest of each kind (module
    docstring). The header's ``sender`` is the publisher, ``seq`` numbers its envelopes and
    ``stamp_s`` is the newest of its payloads' stamps; every payload keeps its own header."""

    payloads: Annotated[list[PeerPayload], msgspec.Meta(max_length=ENVELOPE_MAX_PAYLOADS)]


class _RawEnvelope(
    msgspec.Struct, tag_field="type", tag="peer.envelope", kw_only=True, forbid_unknown_fields=True
):
    """An envelope whose payloads are left as MessagePack (:func:`unpack`'s slow path). Not a
    :class:`Payload` subclass, so that no registry of payload types by tag
    (:func:`groundstation.gcs.schemas.payload_types`) mistakes it for :class:`PeerEnvelope`."""

    version: int = SCHEMA_VERSION
    sender: AgentId
    seq: Seq = 0
    stamp_s: Stamp = 0.0
    payloads: Annotated[list[msgspec.Raw], msgspec.Meta(max_length=ENVELOPE_MAX_PAYLOADS)]


_fast_decoder = msgspec.msgpack.Decoder(PeerEnvelope, dec_hook=_dec_hook)
"""The whole envelope in one C call (the float64 arrays through the codec's hook)."""


def kind_of(payload: Payload | type[Payload]) -> str:
    """A payload's kind: its tag without ``peer.`` (``"motion"``, ``"rigidity_eigen"``)."""
    cls = payload if isinstance(payload, type) else type(payload)
    return str(cls.__struct_config__.tag).removeprefix("peer.")


@dataclass
class Packed:
    """What :func:`pack` made: the envelope's bytes (``None`` when no payload was left) and
    the payloads it left out, each with the reason (a NaN or an infinity)."""

    data: bytes | None
    payloads: list[Payload]
    rejected: list[tuple[Payload, MessageError]] = field(default_factory=list)


def pack(sender: int, seq: int, payloads: Iterable[Payload]) -> Packed:
    """Encode one tick's payloads (the newest of each kind, in the order first met) as one
    :class:`PeerEnvelope`. A payload holding a NaN or an infinity is left out (the fleet never
    gets a non-finite estimate), the others still go: the bytes are checked as
    :func:`messages.codec.encode` checks them, each payload walked only on a hit."""
    latest: dict[str, Payload] = {}
    for p in payloads:
        latest[p.__struct_config__.tag] = p  # type: ignore[attr-defined]
    inner = list(latest.values())
    if not inner:
        return Packed(None, [])
    stamp = max(p.stamp_s for p in inner)
    data = encode_unchecked(PeerEnvelope(sender=sender, seq=seq, stamp_s=stamp, payloads=inner))
    rejected: list[tuple[Payload, MessageError]] = []
    if may_hold_nonfinite(data, inner):
        good: list[Payload] = []
        for p in inner:
            try:
                encode(p)  # the exact walk, which names the field
            except MessageError as exc:
                rejected.append((p, exc))
                continue
            good.append(p)
        if rejected:
            inner = good
            stamp = max((p.stamp_s for p in inner), default=stamp)
            env = PeerEnvelope(sender=sender, seq=seq, stamp_s=stamp, payloads=inner)
            data = encode_unchecked(env) if inner else None
    return Packed(data, inner, rejected)


@dataclass
class Unpacked:
    """What :func:`unpack` found in one envelope: its header, the accepted payloads (oldest
    kind first, as packed) and one :class:`MessageError` per payload it dropped."""

    sender: int
    seq: int
    stamp_s: float
    payloads: list[Any]
    errors: list[MessageError] = field(default_factory=list)

    def envelope(self) -> PeerEnvelope:
        """The accepted payloads in an envelope again (for a recorder)."""
        return PeerEnvelope(
            sender=self.sender, seq=self.seq, stamp_s=self.stamp_s, payloads=self.payloads
        )


def unpack(
    data: bytes | bytearray | memoryview,
    *,
    sender: int | None = None,
    known_senders: Collection[int] | None = None,
    kinds: Collection[str] | None = None,
) -> Unpacked:
    """Decode an envelope into its payloads, each checked as :func:`messages.codec.decode`
    checks one (module docstring).

    ``sender``: the agent id of the key the envelope came on; the envelope and every payload
    in it must name it (a payload that does not is dropped as ``sender_mismatch``).
    ``known_senders``: the fleet (``unknown_sender`` otherwise). ``kinds``: keep only these
    kinds (:func:`kind_of`), e.g. the rigidity layer's from an agent outside the graph; the
    others are not errors. Raises :class:`MessageError` when the envelope itself is unusable
    (oversize, not an envelope, another schema version, its header's sender); a bad payload
    inside only adds to ``errors`` (one of a kind not asked for only when its tag cannot be
    read: its kind is not known then)."""
    env: Any = None
    if kinds is None and len(data) <= MAX_PAYLOAD_BYTES:
        try:
            env = _fast_decoder.decode(data)
        except msgspec.DecodeError:  # a payload (or the envelope) is bad: find out which
            pass
    raw = env is None
    if raw:  # raises for the envelope itself (oversize, not an envelope, its header)
        env = decode_struct(data, _RawEnvelope)
    check_payload(env, known_senders)
    if sender is not None and env.sender != sender:
        raise MessageError(
            DropReason.SENDER_MISMATCH, f"envelope of {env.sender} on agent {sender}'s key"
        )
    out = Unpacked(env.sender, env.seq, env.stamp_s, [])
    tags = None if kinds is None else {f"peer.{k}" for k in kinds}
    for item in env.payloads:
        try:
            if raw:
                # only the kinds asked for are decoded (a payload's tag is read first: the
                # rigidity layer's further neighbours send every kind, it keeps two)
                if tags is not None and _tag_of(item) not in tags:
                    continue
                p = decode(item, PeerPayload, known_senders=known_senders)
            else:
                p = item
                check_payload(p, known_senders)
        except MessageError as exc:
            out.errors.append(exc)
            continue
        if p.sender != env.sender:
            out.errors.append(
                MessageError(
                    DropReason.SENDER_MISMATCH,
                    f"{type(p).__name__} of {p.sender} in the envelope of {env.sender}",
                )
            )
            continue
        out.payloads.append(p)
    return out


class _Tag(msgspec.Struct):
    """A payload's ``type`` tag alone (every other field is skipped, not built)."""

    type: Any = None


_tag_decoder = msgspec.msgpack.Decoder(_Tag)


def _tag_of(raw: msgspec.Raw) -> Any:
    """The tag of one raw payload; :class:`MessageError` (malformed) if it has none to read."""
    try:
        return _tag_decoder.decode(raw).type
    except msgspec.DecodeError as exc:
        raise MessageError(DropReason.MALFORMED, f"payload in an envelope: {exc}") from None


def envelope_sender(key: str) -> int | None:
    """The agent id of an envelope key ``bf/<fleet>/<id>/peer``; ``None`` for any other key."""
    try:
        _, agent_id, topic = parse_key(key)
    except ValueError:
        return None
    return agent_id if topic == PEER_TOPIC else None


def sample_payloads(
    key: str,
    data: bytes | bytearray | memoryview,
    *,
    known_senders: Collection[int] | None = None,
    kinds: Collection[str] | None = None,
) -> Unpacked:
    """:func:`unpack` of one Zenoh sample on an envelope key: the helper every subscriber of
    peer payloads uses (the ground station, the benchmarks, the tests). Raises
    :class:`MessageError` (``foreign``) for a key that is not ``bf/<fleet>/<id>/peer``."""
    agent_id = envelope_sender(key)
    if agent_id is None:
        raise MessageError(DropReason.FOREIGN, f"{key} is not a peer envelope key")
    return unpack(data, sender=agent_id, known_senders=known_senders, kinds=kinds)
