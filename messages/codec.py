"""One codec for everything that crosses a process boundary.

Every payload is a :class:`Payload` subclass (a ``msgspec.Struct``) that carries its schema
version, the sender id, a per-sender sequence number and a timestamp, so receivers can measure
loss and age. Payloads travel as MessagePack with a ``type`` tag; :func:`decode` validates size,
type, version, finiteness of every float, its physical range (:mod:`messages.limits`) and
(optionally) the sender, and raises one error type,
:class:`MessageError`, with a one-line reason that a daemon counts and logs before dropping.

Long numeric vectors (a consensus state of a hundred floats) are :data:`F64Array` fields: a
1-D numpy array that travels as one MessagePack ``bin`` of little-endian float64, so neither
side converts a hundred Python floats one by one.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Collection, Iterable
from functools import lru_cache
from typing import Any, TypeVar

import msgspec
import numpy as np
import numpy.typing as npt

from messages.limits import ARRAY_ABS_MAX, AgentId, Seq, Stamp
from messages.vocabulary import DropReason

SCHEMA_VERSION = 4
"""2: :class:`messages.rigidity.RigidityEigenShare` carries its vectors as :data:`F64Array`.
3: one unit-suffix dialect (``_m_s``, ``_rad_s``): :class:`messages.sim.Truth` has
``yaw_rate_rad_s`` (was ``yaw_rate_radps``); every payload is bounded by
:mod:`messages.limits`.
4: payloads that carried parallel lists carry one list of small entries
(:class:`messages.peer.TargetBearing`, ``SfmEdgeEstimate``, ``EdgeExcitation``,
``ConsensusEntry``, :class:`messages.rigidity.GradientBlock`), checked whole on decode."""
MAX_PAYLOAD_BYTES = 1 << 20
"""Larger payloads are rejected before decoding (1 MiB; images are the largest legitimate ones)."""


class MessageError(ValueError):
    """A payload that cannot be accepted: malformed, wrong type or version, non-finite, oversize,
    or from an unknown sender. ``reason`` is the word its counter is keyed by."""

    def __init__(self, reason: DropReason, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


class Payload(msgspec.Struct, tag_field="type", kw_only=True, forbid_unknown_fields=True):
    """Base of every payload: schema version, sender id, sequence number and timestamp (s)."""

    version: int = SCHEMA_VERSION
    sender: AgentId
    seq: Seq = 0
    stamp_s: Stamp = 0.0


P = TypeVar("P", bound=Payload)

F64Array = npt.NDArray[np.float64]
"""A payload field holding a 1-D float64 array; on the wire a ``bin`` of little-endian float64
(8 bytes per entry). Decoded arrays are read-only views of the received bytes."""


def _enc_hook(value: Any) -> Any:
    if isinstance(value, np.ndarray) and value.ndim == 1 and value.dtype.kind == "f":
        return value.astype("<f8", copy=False).tobytes()
    shape = getattr(value, "shape", "")
    raise TypeError(f"cannot encode {type(value).__name__} {shape} in a payload (1-D float only)")


def _dec_hook(kind: Any, value: Any) -> Any:
    if getattr(kind, "__origin__", kind) is np.ndarray:
        if isinstance(value, bytes) and len(value) % 8 == 0:
            return np.frombuffer(value, dtype="<f8")
        raise msgspec.ValidationError("expected float64 array bytes (a multiple of 8 long)")
    raise NotImplementedError(f"no decoder for {kind!r}")


_encoder = msgspec.msgpack.Encoder(enc_hook=_enc_hook)


_HUGE_F64 = (b"\xcb\x7f", b"\xcb\xff")
"""How a MessagePack float64 (``0xcb`` + 8 big-endian bytes) of magnitude >= 2**1009 starts,
which every NaN and +-inf is (all exponent bits ones). msgspec writes every Python float as a
float64; the prefix can also occur inside other bytes (a ``bin`` array, a string), which only
sends :func:`encode` down its slow, exact path."""


def encode(payload: Payload) -> bytes:
    """Serialize a payload to MessagePack bytes (raises :class:`MessageError` on NaN/inf).

    The finiteness check scans the encoded bytes for a non-finite float64 (two C substring
    searches) and the float64 arrays in numpy, instead of walking every float in Python; a hit
    (or a type whose floats the bytes may not show, :func:`_encode_plan`) runs the exact walk,
    which names the field."""
    data = _encoder.encode(payload)
    if may_hold_nonfinite(data, (payload,)):
        _check_finite(payload, "payload")
    return data


def encode_unchecked(payload: msgspec.Struct) -> bytes:
    """MessagePack bytes without the finiteness check: for a caller that runs
    :func:`may_hold_nonfinite` itself (:func:`messages.envelope.pack`)."""
    return _encoder.encode(payload)


def may_hold_nonfinite(data: bytes, payloads: Iterable[Payload]) -> bool:
    """Whether ``data``, the encoding of ``payloads`` (or of a struct holding them), may hold a
    NaN or an infinity: a non-finite float64's prefix in the bytes, a non-finite entry of a
    float64 array, or a payload type whose floats the bytes may not show. ``False`` proves every
    float finite; ``True`` calls for the exact walk (:func:`encode` of each payload)."""
    if _HUGE_F64[0] in data or _HUGE_F64[1] in data:
        return True
    for payload in payloads:
        arrays, walk = _encode_plan(type(payload))
        if walk or any(not np.isfinite(getattr(payload, name)).all() for name in arrays):
            return True
    return False


def decode(
    data: bytes | bytearray | memoryview,
    kind: type[P] | Any,
    *,
    known_senders: Collection[int] | None = None,
) -> P:
    """Decode and validate ``data`` as ``kind`` (a Payload class or a ``Union`` of them).

    Raises :class:`MessageError` with reason ``oversize``, ``malformed``, ``version``,
    ``nonfinite``, ``out_of_range`` (a bound of :mod:`messages.limits`) or ``unknown_sender``.
    """
    msg = decode_struct(data, kind)
    check_payload(msg, known_senders)
    return msg


def decode_struct(data: bytes | bytearray | memoryview, kind: type[P] | Any) -> P:
    """The first half of :func:`decode`: the size bound and msgspec's decode (its bounds
    checked in C), a failure classified by reason; :func:`check_payload` is the second half
    (:mod:`messages.envelope` runs it on every payload inside an envelope)."""
    if len(data) > MAX_PAYLOAD_BYTES:
        raise MessageError(DropReason.OVERSIZE, f"{len(data)} bytes > {MAX_PAYLOAD_BYTES}")
    try:
        return _decoder(kind).decode(data)
    except msgspec.DecodeError as exc:  # (ValidationError is a DecodeError)
        # a payload of another schema version is reported as such, not as malformed, and a
        # NaN that a range bound caught as nonfinite. Rejecting must cost about what accepting
        # does (issue 23: a ConsensusState of 45,000 names, rejected by msgspec in 12 us, took
        # 230 ms here while the full map was rebuilt and walked, the GIL held in the Zenoh
        # thread; 20 of them stopped a daemon's status for 2.6 s): the version comes from the
        # header alone, a list longer than its bound is out_of_range whatever it holds, and
        # otherwise the map is read only when its bytes can hold a NaN or an infinity
        version = _peek_version(data)
        if isinstance(version, int) and version != SCHEMA_VERSION:
            raise MessageError(
                DropReason.VERSION, f"schema version {version}, expected {SCHEMA_VERSION}"
            ) from None
        if isinstance(exc, msgspec.ValidationError):
            bound = _OUT_OF_RANGE.match(str(exc))
            if bound is not None and bound.group(1):  # "of length": too many entries
                raise MessageError(DropReason.OUT_OF_RANGE, str(exc)) from None
            raw = _peek(data) if _may_hold_nonfinite(data) else None
            if raw is not None and not _all_finite(raw):
                _check_finite(raw, "payload")
            if bound is not None:
                raise MessageError(DropReason.OUT_OF_RANGE, str(exc)) from None
        raise MessageError(DropReason.MALFORMED, str(exc)) from None


def check_payload(msg: Payload, known_senders: Collection[int] | None = None) -> None:
    """The second half of :func:`decode` on a payload msgspec built: its schema version, the
    floats no bound covers, the float64 arrays and (optionally) its sender; raises
    :class:`MessageError`."""
    if msg.version != SCHEMA_VERSION:
        raise MessageError(
            DropReason.VERSION, f"schema version {msg.version}, expected {SCHEMA_VERSION}"
        )
    # msgspec has already rejected NaN/inf in every float bounded by messages.limits; only the
    # fields with an unbounded float are walked here, and the float64 arrays checked in numpy
    for name in _unbounded_fields(type(msg)):
        value = getattr(msg, name)
        if not _all_finite(value):  # fast check; the slow one names the field
            _check_finite(value, f"{type(msg).__name__}.{name}")
    _check_arrays(msg)
    if known_senders is not None and msg.sender not in known_senders:
        raise MessageError(DropReason.UNKNOWN_SENDER, f"sender {msg.sender} is not in the fleet")


@lru_cache(maxsize=64)
def _decoder(kind: Any) -> msgspec.msgpack.Decoder:
    """One decoder per payload type: ``msgspec.msgpack.decode(data, type=...)`` rebuilds its
    type information on every call for a union of tagged structs (100 us instead of 2 us)."""
    return msgspec.msgpack.Decoder(kind, dec_hook=_dec_hook)


_OUT_OF_RANGE = re.compile(r"Expected `\w+`( of length)? [<>]=? ")
"""How msgspec words a violated ``Meta`` bound (messages.limits): reason ``out_of_range``."""


class _Version(msgspec.Struct):
    """A payload's header field ``version`` (every other field is skipped, not built)."""

    version: Any = None


_version_decoder = msgspec.msgpack.Decoder(_Version)

_NONFINITE_PREFIXES = (*_HUGE_F64, b"\xca\x7f", b"\xca\xff")
"""Every MessagePack float whose value can be NaN or +-inf starts with one of these: a float64
(``0xcb``) or a float32 (``0xca``, which a hand-made payload may use) with its first exponent
bits ones. Bytes without any of them hold only finite floats (a ``bin`` is not read as floats)."""


def _peek_version(data: bytes | bytearray | memoryview) -> Any:
    """The ``version`` in a payload's header, or ``None`` (not a map, or no such field)."""
    try:
        return _version_decoder.decode(data).version
    except msgspec.DecodeError:
        return None


def _may_hold_nonfinite(data: bytes | bytearray | memoryview) -> bool:
    """Whether ``data`` may hold a NaN or an infinity (C substring searches; a false positive
    only costs the exact walk)."""
    raw = bytes(data)
    return any(prefix in raw for prefix in _NONFINITE_PREFIXES)


def _peek(data: bytes | bytearray | memoryview) -> Any:
    """The payload as plain MessagePack (no schema), or ``None``: read only after a failed
    decode, so a payload from a newer schema is reported as a version mismatch rather than as
    malformed, and a NaN as nonfinite rather than as out of range."""
    try:
        return msgspec.msgpack.decode(bytes(data))
    except msgspec.DecodeError:
        return None


def _check_arrays(msg: msgspec.Struct) -> None:
    """Check the float64 array fields (msgspec cannot put a ``Meta`` on them): every entry
    finite (reason ``nonfinite``) and within :data:`messages.limits.ARRAY_ABS_MAX`."""
    for name in _array_fields(type(msg)):
        value = getattr(msg, name)
        if not len(value):
            continue
        peak = float(np.abs(value).max())  # NaN if any entry is NaN
        if not math.isfinite(peak):
            _check_finite(value, f"{type(msg).__name__}.{name}")
        if peak > ARRAY_ABS_MAX:
            raise MessageError(
                DropReason.OUT_OF_RANGE, f"{type(msg).__name__}.{name}: |entry| > {ARRAY_ABS_MAX:g}"
            )


@lru_cache(maxsize=256)
def _unbounded_fields(kind: type[msgspec.Struct]) -> tuple[str, ...]:
    """The fields of a payload type that may hold a NaN or infinity after msgspec decoded them:
    those with a float that no :mod:`messages.limits` bound constrains on both sides (or a type
    msgspec cannot see into). A bounded float is validated in C: msgspec compares it with
    ``ge``/``le``, and NaN fails every comparison, +-inf the finite bound
    (``tests/messages/test_codec.py`` pins this). Most payloads have none: no Python walk."""
    info = msgspec.inspect.type_info(kind)
    assert isinstance(info, msgspec.inspect.StructType)
    return tuple(f.name for f in info.fields if not _every_leaf(f.type, _bounded_by_msgspec, set()))


@lru_cache(maxsize=256)
def _encode_plan(kind: type[msgspec.Struct]) -> tuple[tuple[str, ...], bool]:
    """For :func:`encode`: the top-level float64 array fields of a payload type, and whether
    its values may hold floats that do not appear as MessagePack float64 (an array below the
    top level, ``Any``, an unknown type): then every payload of the type is walked in Python."""
    info = msgspec.inspect.type_info(kind)
    assert isinstance(info, msgspec.inspect.StructType)
    arrays = _array_fields(kind)
    seen: set[int] = {id(info)}
    walk = not all(
        f.name in arrays or _every_leaf(f.type, _encoded_as_float, seen) for f in info.fields
    )
    return arrays, walk


def _every_leaf(
    t: msgspec.inspect.Type, leaf: Callable[[msgspec.inspect.Type], bool], seen: set[int]
) -> bool:
    """Whether ``leaf`` holds for every non-container type inside ``t`` (lists, tuples, sets,
    dicts, unions and structs are walked; a recursive struct is judged where first met)."""
    mi = msgspec.inspect
    if isinstance(t, (mi.ListType, mi.VarTupleType, mi.SetType, mi.FrozenSetType)):
        return _every_leaf(t.item_type, leaf, seen)
    if isinstance(t, mi.TupleType):
        return all(_every_leaf(x, leaf, seen) for x in t.item_types)
    if isinstance(t, mi.DictType):
        return _every_leaf(t.key_type, leaf, seen) and _every_leaf(t.value_type, leaf, seen)
    if isinstance(t, mi.UnionType):
        return all(_every_leaf(x, leaf, seen) for x in t.types)
    if isinstance(t, mi.StructType):
        if id(t) in seen:
            return True
        seen.add(id(t))
        return all(_every_leaf(f.type, leaf, seen) for f in t.fields)
    return leaf(t)


def _encoded_as_float(t: msgspec.inspect.Type) -> bool:
    """A leaf whose floats are MessagePack floats (arrays below the top level, Any,
    dataclasses, ... are not)."""
    mi = msgspec.inspect
    return isinstance(t, (mi.FloatType, mi.IntType, mi.BoolType, mi.StrType, mi.NoneType,
                          mi.BytesType, mi.ByteArrayType, mi.LiteralType, mi.EnumType))  # fmt: skip


def _bounded_by_msgspec(t: msgspec.inspect.Type) -> bool:
    """A leaf in which msgspec itself rejects every non-finite float: a float with finite bounds
    on both sides, a type without floats, or a float64 array (:func:`_check_arrays` does
    those); Any, dataclasses, ... are walked in Python."""
    mi = msgspec.inspect
    if isinstance(t, mi.FloatType):
        lo = t.ge if t.ge is not None else t.gt
        hi = t.le if t.le is not None else t.lt
        return lo is not None and hi is not None and math.isfinite(lo) and math.isfinite(hi)
    if isinstance(t, (mi.IntType, mi.BoolType, mi.StrType, mi.NoneType, mi.BytesType,
                      mi.ByteArrayType, mi.MemoryViewType, mi.LiteralType, mi.EnumType)):  # fmt: skip
        return True
    if isinstance(t, mi.CustomType):
        return getattr(t.cls, "__origin__", t.cls) is np.ndarray
    return False


@lru_cache(maxsize=256)
def _array_fields(kind: type[msgspec.Struct]) -> tuple[str, ...]:
    """The :data:`F64Array` fields of a payload type (most have none: no per-message scan)."""
    hints = msgspec.structs.fields(kind)
    return tuple(f.name for f in hints if getattr(f.type, "__origin__", f.type) is np.ndarray)


def _all_finite(value: Any) -> bool:
    """Whether every float inside ``value`` is finite: the hot path of :func:`decode` (no field
    names are built; :func:`_check_finite` names the culprit once this says no)."""
    kind = type(value)
    if kind is float:
        return math.isfinite(value)
    if kind is np.ndarray:
        return bool(np.isfinite(value).all())
    if kind is list or kind is tuple:
        items: Iterable[Any] = value
    elif kind is dict:
        items = value.values()
    elif isinstance(value, msgspec.Struct):
        items = (getattr(value, name) for name in value.__struct_fields__)
    else:
        return True
    for item in items:
        k = type(item)
        if k is float:
            if not math.isfinite(item):
                return False
        elif k is not int and k is not str and k is not bool and not _all_finite(item):
            return False
    return True


def _check_finite(value: Any, where: str) -> None:
    if isinstance(value, float):
        if not math.isfinite(value):
            raise MessageError(DropReason.NONFINITE, f"{where} is {value}")
    elif isinstance(value, np.ndarray):
        bad = np.flatnonzero(~np.isfinite(value))
        if len(bad):
            raise MessageError(DropReason.NONFINITE, f"{where}[{bad[0]}] is {value[bad[0]]}")
    elif isinstance(value, msgspec.Struct):
        for name in value.__struct_fields__:
            _check_finite(getattr(value, name), f"{where}.{name}")
    elif isinstance(value, (list, tuple)):
        _check_all(value, where)
    elif isinstance(value, dict):
        for k, v in value.items():
            _check_finite(v, f"{where}[{k!r}]")


def _check_all(items: Iterable[Any], where: str) -> None:
    for k, v in enumerate(items):
        _check_finite(v, f"{where}[{k}]")
