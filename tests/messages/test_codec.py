"""The codec rejects every kind of bad payload with one error type and a reason."""

from typing import Annotated, get_args

import msgspec
import numpy as np
import pytest

from messages.codec import (
    MAX_PAYLOAD_BYTES,
    SCHEMA_VERSION,
    F64Array,
    MessageError,
    Payload,
    _unbounded_fields,
    decode,
    encode,
)
from messages.keys import alive_key, fleet_keys, key, parse_key
from messages.limits import Angle, Speed, SpeedVec3


class Ping(Payload, tag="test.ping"):
    value: float
    items: list[float] = msgspec.field(default_factory=list)


class Pong(Payload, tag="test.pong"):
    text: str


def test_round_trip_keeps_header_and_body():
    msg = Ping(sender=3, seq=7, stamp_s=1.5, value=2.0, items=[1.0, 2.0])
    assert decode(encode(msg), Ping) == msg
    assert decode(encode(msg), Ping | Pong) == msg


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (b"\xc1garbage", "malformed"),
        (msgspec.msgpack.encode({"type": "test.pong", "sender": 1, "text": "x"}), "malformed"),
        (msgspec.msgpack.encode({"type": "test.ping", "sender": 1, "value": "x"}), "malformed"),
        (
            msgspec.msgpack.encode({"type": "test.ping", "version": 9, "sender": 1, "value": 1.0}),
            "version",
        ),
        (
            msgspec.msgpack.encode({"type": "test.ping", "sender": 1, "value": float("nan")}),
            "nonfinite",
        ),
        (
            msgspec.msgpack.encode(
                {"type": "test.ping", "sender": 1, "value": 0.0, "items": [float("inf")]}
            ),
            "nonfinite",
        ),
        (b"\x00" * (MAX_PAYLOAD_BYTES + 1), "oversize"),
    ],
)
def test_bad_payloads_raise_message_error(data, reason):
    with pytest.raises(MessageError) as info:
        decode(data, Ping)
    assert info.value.reason == reason


def test_unknown_sender_and_nan_on_encode():
    data = encode(Ping(sender=9, value=1.0))
    with pytest.raises(MessageError, match="unknown_sender"):
        decode(data, Ping, known_senders={1, 2})
    with pytest.raises(MessageError, match="nonfinite"):
        encode(Ping(sender=1, value=float("nan")))


def test_keys():
    assert key("alpha", 3, "state") == "bf/alpha/3/state"
    assert alive_key("alpha", 3) == "bf/alpha/3/alive"
    assert fleet_keys("alpha") == "bf/alpha/**"
    assert parse_key("bf/alpha/3/consensus/lambda") == ("alpha", 3, "consensus/lambda")
    for bad in ["bf/alpha/x/state", "zz/alpha/1/state", "bf/al pha/1/s"]:
        with pytest.raises(ValueError):
            parse_key(bad)
    with pytest.raises(ValueError):
        key("a/b", 1, "state")


class Nested(Payload, tag="test.nested"):
    names: list[str]
    rows: list[list[float]]
    table: dict[str, tuple[float, float]] = msgspec.field(default_factory=dict)
    pings: list[Ping] = msgspec.field(default_factory=list)


@pytest.mark.parametrize(
    ("bad", "where"),
    [
        ({"rows": [[1.0], [2.0, float("inf")]]}, "rows[1][1]"),
        ({"table": {"a": (1.0, float("nan"))}}, "table['a'][1]"),
        ({"pings": [Ping(sender=1, value=1.0, items=[float("-inf")])]}, "pings[0].items[0]"),
    ],
)
def test_nonfinite_anywhere_inside_is_found_and_named(bad, where):
    fields = {"sender": 1, "names": ["x"], "rows": [[1.0]], **bad}
    with pytest.raises(MessageError) as err:
        encode(Nested(**fields))
    assert err.value.reason == "nonfinite" and where in err.value.detail
    raw = msgspec.msgpack.encode(Nested(**fields))  # a peer that does not check what it sends
    with pytest.raises(MessageError, match="nonfinite"):
        decode(raw, Nested)
    assert decode(encode(Nested(sender=1, names=["x"], rows=[[1.0, 2.0]])), Nested).rows == [
        [1.0, 2.0]
    ]


class Vector(Payload, tag="test.vector"):
    values: F64Array


def test_float_arrays_travel_as_bytes_and_are_validated():
    values = np.array([1.0, -2.5, 3e-9])
    data = encode(Vector(sender=1, values=values))
    assert values.astype("<f8").tobytes() in data  # one bin, not a list of floats
    np.testing.assert_array_equal(decode(data, Vector).values, values)
    with pytest.raises(MessageError, match="nonfinite"):
        encode(Vector(sender=1, values=np.array([0.0, np.inf])))
    bad = [
        ({"values": np.array([0.0, np.nan]).tobytes()}, "nonfinite"),
        ({"values": b"\x00" * 7}, "malformed"),  # not a whole number of float64
        ({"values": [1.0, 2.0]}, "malformed"),  # a list is not the array encoding
    ]
    for fields, reason in bad:
        raw = msgspec.msgpack.encode(
            {"type": "test.vector", "version": SCHEMA_VERSION, "sender": 1, **fields}
        )
        with pytest.raises(MessageError) as info:
            decode(raw, Vector)
        assert info.value.reason == reason
    with pytest.raises(TypeError):
        encode(Vector(sender=1, values=np.zeros((2, 2))))  # only 1-D arrays have an encoding


class Bounded(Payload, tag="test.bounded"):
    v_body: SpeedVec3
    yaw_rad: Angle
    rows: list[tuple[Speed, Speed]] = msgspec.field(default_factory=list)
    maybe: Speed | None = None
    free: float = 0.0
    half: Annotated[float, msgspec.Meta(ge=0.0)] = 0.0  # no upper bound: +inf passes msgspec


def test_msgspec_bounds_reject_nonfinite_and_only_unbounded_fields_are_walked():
    # the fast path (issue 27): a float bounded on both sides is validated by msgspec in C
    assert _unbounded_fields(Bounded) == ("free", "half")
    ok = {"type": "test.bounded", "sender": 1, "v_body": (1.0, 0.0, 0.0), "yaw_rad": 0.5,
          "rows": [(1.0, 2.0)], "maybe": 1.0}  # fmt: skip
    assert decode(msgspec.msgpack.encode(ok), Bounded).rows == [(1.0, 2.0)]
    for bad in (float("nan"), float("inf"), float("-inf")):
        for fields in (
            {"v_body": (0.0, bad, 0.0)},
            {"yaw_rad": bad},
            {"rows": [(1.0, 2.0), (bad, 0.0)]},
            {"maybe": bad},
            {"free": bad},
            {"half": bad},
        ):
            with pytest.raises(MessageError) as info:
                decode(msgspec.msgpack.encode({**ok, **fields}), Bounded)
            assert info.value.reason == "nonfinite", (fields, info.value)
    with pytest.raises(MessageError) as info:  # an unbounded field is named
        decode(msgspec.msgpack.encode({**ok, "free": float("nan")}), Bounded)
    assert "Bounded.free" in info.value.detail
    with pytest.raises(MessageError) as info:
        decode(msgspec.msgpack.encode({**ok, "half": float("inf")}), Bounded)
    assert "Bounded.half" in info.value.detail


def test_every_peer_payload_is_validated_by_msgspec_alone():
    # no Python walk for what the daemons exchange at 100 Hz (their floats all carry bounds)
    from messages.peer import PeerPayload

    kinds = get_args(PeerPayload)
    assert kinds and all(_unbounded_fields(k) == () for k in kinds)


def test_encode_finds_every_nonfinite_and_only_those():
    # the encoded-bytes scan (issue 27): NaN/inf at any position of a flat or nested payload
    rng = np.random.default_rng(0)
    for bad in (float("nan"), float("inf"), float("-inf")):
        for n in (1, 5, 40):
            items = [float(x) for x in rng.normal(size=n) * 10.0 ** rng.integers(-300, 300, size=n)]
            items[int(rng.integers(n))] = bad
            with pytest.raises(MessageError, match="nonfinite"):
                encode(Ping(sender=1, value=1.0, items=items))
            with pytest.raises(MessageError, match="nonfinite"):
                encode(Ping(sender=1, value=bad))
    # finite values whose bytes look like a huge float64 inside a bin array: still encoded
    tricky = np.frombuffer(b"\x00\x00\x00\x00\xcb\x7f\xf0\x3f" * 2, dtype="<f8")
    assert np.isfinite(tricky).all()
    data = encode(Vector(sender=1, values=tricky))
    assert b"\xcb\x7f\xf0" in data
    np.testing.assert_array_equal(decode(data, Vector).values, tricky)
    huge = Ping(sender=1, value=1.7e308, items=[-1.7e308, 5e-324])  # finite extremes
    assert decode(encode(huge), Ping) == huge


def test_a_rejected_payload_is_not_rebuilt_unless_it_can_hold_a_nan(monkeypatch):
    """Issue 23: rejecting a ``ConsensusState`` of 45,000 names (msgspec: 12 us) cost 230 ms
    while the codec rebuilt the whole map to look for a version and a NaN, the GIL held in the
    receiver's Zenoh thread: ``benchmarks/bench_poison.py --only d4`` saw 20 of them stop a
    daemon's status for 2.6 s. The header alone gives the version; only bytes that can hold a
    NaN or an infinity (float64 or float32) are walked, and a too-long list is out_of_range
    whatever it holds."""
    import struct

    from messages import codec
    from messages.peer import PeerPayload

    walks: list[int] = []
    real_peek = codec._peek
    monkeypatch.setattr(codec, "_peek", lambda data: walks.append(len(data)) or real_peek(data))

    def consensus(n: int, x: float, version: int = SCHEMA_VERSION) -> bytes:
        return msgspec.msgpack.encode(
            {"type": "peer.consensus", "version": version, "sender": 1, "seq": 5,
             "stamp_s": 10.0, "states": [[f"n{k}", [x], []] for k in range(n)]}
        )  # fmt: skip

    for data, reason in [
        (consensus(45_000, 0.0), "out_of_range"),  # too many names
        (consensus(45_000, float("nan")), "out_of_range"),  # too many, whatever they hold
        (consensus(3, 1e300), "out_of_range"),  # a huge finite value
        (consensus(45_000, 0.0, version=SCHEMA_VERSION + 1), "version"),
    ]:
        with pytest.raises(MessageError) as info:
            decode(data, PeerPayload)
        assert info.value.reason == reason, info.value
    assert walks == []
    nan32 = consensus(3, 0.5).replace(b"\xcb" + struct.pack(">d", 0.5), b"\xca\x7f\xc0\x00\x00", 1)
    for data in (consensus(3, float("inf")), nan32):  # a hand-made float32 NaN too
        with pytest.raises(MessageError) as info:
            decode(data, PeerPayload)
        assert info.value.reason == "nonfinite", info.value
    assert len(walks) == 2
