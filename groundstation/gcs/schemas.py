"""JSON encodings and JSON Schemas of everything ``gcs record`` writes, so Foxglove (and any
MCAP tool) can show every channel without knowing bearingflock.

* Payloads (``messages.*``, every tagged :class:`~messages.codec.Payload`): JSON as
  ``msgspec.json`` writes the struct (the ``type`` tag included; ``F64Array`` fields as lists of
  numbers, ``bytes`` fields as base64 strings), schema from :func:`msgspec.json.schema`.
  :func:`payload_to_msgpack` turns the JSON back into wire bytes.
  A replay republishes the codec's encoding of the same payload: equal to what was received
  once decoded (the bytes differ only where a sender wrote an integer into a float field).
* Samples that are not a valid payload (malformed, another schema version, non-finite, an
  unknown type) are kept verbatim on :data:`RAW_SCHEMA_NAME` channels (``{"data_b64",
  "reason"}``), and a replay republishes them byte for byte.
* Liveliness: ``{"alive": bool}``.
* MAVLink: one JSON object per message (``pymavlink``'s ``to_dict()``), a schema per message
  type built from the pymavlink definition (field names, C types, array lengths).
"""

from __future__ import annotations

import base64
import importlib
import json
from functools import lru_cache
from typing import Any

import msgspec
import numpy as np

from messages.codec import Payload, _dec_hook, encode

JSON_ENCODING = "json"
"""MCAP message encoding and schema encoding of every channel ``gcs record`` writes."""
SCHEMA_ENCODING = "jsonschema"
RAW_SCHEMA_NAME = "bearingflock.RawSample"
LIVELINESS_SCHEMA_NAME = "bearingflock.Liveliness"
PAYLOAD_SCHEMA_PREFIX = "bearingflock."
MAVLINK_SCHEMA_PREFIX = "mavlink."
_MESSAGE_MODULES = (
    "messages.agent",
    "messages.command",
    "messages.envelope",
    "messages.image",
    "messages.peer",
    "messages.rigidity",
    "messages.sim",
)


def _subclasses(cls: type) -> list[type]:
    out = []
    for sub in cls.__subclasses__():
        out.append(sub)
        out.extend(_subclasses(sub))
    return out


@lru_cache(maxsize=1)
def payload_types() -> dict[str, type[Payload]]:
    """Every tagged payload type of the project, by its wire tag (``"vehicle.status"``)."""
    for name in _MESSAGE_MODULES:
        importlib.import_module(name)
    out: dict[str, type[Payload]] = {}
    for cls in _subclasses(Payload):
        tag = cls.__struct_config__.tag
        if isinstance(tag, str) and cls.__module__.startswith("messages."):
            out[tag] = cls
    return out


def _json_enc_hook(value: Any) -> Any:
    if isinstance(value, np.ndarray) and value.ndim == 1 and value.dtype.kind == "f":
        return value.tolist()
    raise TypeError(f"cannot encode {type(value).__name__} as JSON")


def _json_dec_hook(kind: Any, value: Any) -> Any:
    if getattr(kind, "__origin__", kind) is np.ndarray:
        if isinstance(value, list):
            return np.asarray(value, dtype="<f8")
        raise msgspec.ValidationError("expected a list of numbers")
    return _dec_hook(kind, value)


def _schema_hook(kind: Any) -> dict[str, Any]:
    if getattr(kind, "__origin__", kind) is np.ndarray:
        return {"type": "array", "items": {"type": "number"}}
    raise NotImplementedError(f"no JSON schema for {kind!r}")


_json_encoder = msgspec.json.Encoder(enc_hook=_json_enc_hook)


def payload_schema_name(cls: type[Payload]) -> str:
    return f"{PAYLOAD_SCHEMA_PREFIX}{cls.__name__}"


@lru_cache(maxsize=64)
def payload_schema(cls: type[Payload]) -> bytes:
    """JSON Schema (draft 2020-12) of one payload type, its own definition at the root."""
    raw = msgspec.json.schema(cls, schema_hook=_schema_hook)
    defs = raw["$defs"]
    root = dict(defs[cls.__name__])
    root["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    root["title"] = payload_schema_name(cls)
    root["$defs"] = defs
    return json.dumps(root).encode()


_msgpack_untyped = msgspec.msgpack.Decoder()


def decode_sample(data: bytes) -> tuple[Payload | None, str]:
    """The payload these wire bytes hold and ``""``, or ``None`` and why they are not a valid
    payload (the codec's reason word, or ``unknown_type``). A peer envelope is valid only if
    every payload in it is (:func:`messages.envelope.unpack`): a recorder keeps any other
    verbatim; :func:`decode_payloads` keeps its good payloads."""
    from messages.codec import MessageError, decode
    from messages.envelope import PeerEnvelope, unpack

    try:
        raw = _msgpack_untyped.decode(data)
    except msgspec.DecodeError:
        return None, "malformed"
    cls = payload_types().get(raw.get("type")) if isinstance(raw, dict) else None
    if cls is None:
        return None, "unknown_type"
    try:
        if cls is PeerEnvelope:
            got = unpack(data)
            if got.errors:
                return None, got.errors[0].reason
            return got.envelope(), ""
        return decode(data, cls), ""
    except MessageError as exc:
        return None, exc.reason


def decode_payloads(data: bytes) -> tuple[list[Payload], list[str]]:
    """The payloads these wire bytes hold: one, or a peer envelope's valid ones (each checked
    on its own), and the reason words of what was not valid."""
    from messages.codec import MessageError
    from messages.envelope import PeerEnvelope, unpack

    try:
        raw = _msgpack_untyped.decode(data)
    except msgspec.DecodeError:
        return [], ["malformed"]
    if isinstance(raw, dict) and raw.get("type") == PeerEnvelope.__struct_config__.tag:
        try:
            got = unpack(data)
        except MessageError as exc:
            return [], [exc.reason]
        return got.payloads, [e.reason for e in got.errors]
    payload, reason = decode_sample(data)
    return ([payload], []) if payload is not None else ([], [reason])


def payload_json(payload: Payload) -> bytes:
    return _json_encoder.encode(payload)


@lru_cache(maxsize=64)
def _json_decoder(cls: type[Payload]) -> msgspec.json.Decoder:
    return msgspec.json.Decoder(cls, dec_hook=_json_dec_hook)


def payload_from_json(data: bytes, cls: type[Payload]) -> Payload:
    return _json_decoder(cls).decode(data)


def payload_to_msgpack(data: bytes, schema_name: str) -> bytes:
    """The wire bytes of a recorded JSON payload (the inverse of :func:`payload_json`)."""
    name = schema_name.removeprefix(PAYLOAD_SCHEMA_PREFIX)
    for cls in payload_types().values():
        if cls.__name__ == name:
            return encode(payload_from_json(data, cls))
    raise ValueError(f"unknown payload schema {schema_name!r}")


# --- raw samples and liveliness ------------------------------------------------------------------
RAW_SCHEMA = json.dumps(
    {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": RAW_SCHEMA_NAME,
        "description": "A Zenoh sample kept verbatim: not a valid bearingflock payload, or one "
        "whose bytes the codec would not reproduce.",
        "type": "object",
        "properties": {
            "data_b64": {"type": "string", "contentEncoding": "base64"},
            "reason": {"type": "string"},
        },
        "required": ["data_b64", "reason"],
        "additionalProperties": False,
    }
).encode()

LIVELINESS_SCHEMA = json.dumps(
    {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": LIVELINESS_SCHEMA_NAME,
        "description": "A Zenoh liveliness token appeared (true) or went away (false).",
        "type": "object",
        "properties": {"alive": {"type": "boolean"}},
        "required": ["alive"],
        "additionalProperties": False,
    }
).encode()


def raw_json(data: bytes, reason: str) -> bytes:
    return json.dumps(
        {"data_b64": base64.b64encode(bytes(data)).decode(), "reason": reason}
    ).encode()


def raw_from_json(data: bytes) -> bytes:
    return base64.b64decode(json.loads(data)["data_b64"])


def liveliness_json(alive: bool) -> bytes:
    return b'{"alive":true}' if alive else b'{"alive":false}'


def liveliness_from_json(data: bytes) -> bool:
    return bool(json.loads(data)["alive"])


# --- MAVLink -------------------------------------------------------------------------------------
_C_TYPES = {
    "float": {"type": ["number", "null"]},  # NaN (a MAVLink 'unused') is written as null
    "double": {"type": ["number", "null"]},
    "char": {"type": "string"},
}


def _field_schema(c_type: str, length: int) -> dict[str, Any]:
    base = c_type.split("[")[0]
    if base == "char":
        return {"type": "string"}
    item = _C_TYPES.get(base, {"type": "integer"})
    if length:
        return {"type": "array", "items": item, "maxItems": length}
    return item


@lru_cache(maxsize=512)
def mavlink_schema(msg_class: type) -> bytes:
    """JSON Schema of one pymavlink message class, as its ``to_dict()`` writes it."""
    name = str(msg_class.msgname)
    props: dict[str, Any] = {"mavpackettype": {"const": name}}
    # pymavlink: fieldtypes follow fieldnames, array_lengths follow the wire order
    lengths = dict(zip(msg_class.ordered_fieldnames, msg_class.array_lengths or (), strict=False))
    for field, c_type in zip(msg_class.fieldnames, msg_class.fieldtypes, strict=False):
        props[field] = _field_schema(str(c_type), int(lengths.get(field, 0)))
    return json.dumps(
        {
            "$schema": "https://json-schema.org/draft/2020-12/schema",
            "title": f"{MAVLINK_SCHEMA_PREFIX}{name}",
            "description": f"MAVLink {name} (pymavlink to_dict(); NaN floats are null)",
            "type": "object",
            "properties": props,
            "required": ["mavpackettype"],
        }
    ).encode()


_plain_json = msgspec.json.Encoder(enc_hook=lambda v: list(v) if isinstance(v, bytes) else str(v))


def mavlink_json(msg: Any) -> bytes:
    """One MAVLink message as JSON (``to_dict()``; non-finite floats become null)."""
    return _plain_json.encode(msg.to_dict())
