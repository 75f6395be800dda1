"""The peer envelope (issue 27): one message per publish tick, unpacked into the payloads the
inbox took before, each checked on its own (:mod:`messages.envelope`)."""

import msgspec
import numpy as np
import pytest

from messages.codec import MAX_PAYLOAD_BYTES, SCHEMA_VERSION, MessageError, encode_unchecked
from messages.envelope import (
    ENVELOPE_MAX_PAYLOADS,
    PeerEnvelope,
    envelope_sender,
    kind_of,
    pack,
    sample_payloads,
    unpack,
)
from messages.keys import peer_key
from messages.peer import (
    BearingShare,
    LocalizationState,
    MotionShare,
    SfmEdgeEstimate,
    SfmEstimate,
    TargetBearing,
)
from messages.rigidity import RigidityEigenShare


def _tick(sender: int = 1, seq: int = 10, t: float = 5.0) -> list:
    return [
        MotionShare(sender=sender, seq=seq, stamp_s=t, v_body=(0.5, 0.0, -0.1),
                    yaw_rate_rad_s=0.1, yaw_rad=0.2),
        BearingShare(sender=sender, seq=seq, stamp_s=t - 0.01, yaw_rad=0.2,
                     bearings=[TargetBearing(target=0, beta_body=(1.0, 0.0, 0.0))]),
        SfmEstimate(sender=sender, seq=seq, stamp_s=t,
                    edges=[SfmEdgeEstimate(peer=2, chi_hat_inv_m=0.2, excitation=0.01,
                                           e_index=0.1, e_folds=3.0)]),
        RigidityEigenShare(sender=sender, seq=seq, stamp_s=t, lambda_hat=0.5, targets=[0],
                           state=np.arange(4.0), per_target=np.array([0.25, -1.0]), round=3),
    ]  # fmt: skip


def _same(a: object, b: object) -> bool:
    """Struct equality with the float64 arrays compared by value."""
    if type(a) is not type(b):
        return False
    for name in a.__struct_fields__:  # type: ignore[attr-defined]
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray):
            if not np.array_equal(x, y):
                return False
        elif x != y:
            return False
    return True


def _raw_envelope(sender: int, payloads: list[dict], **header: object) -> bytes:
    """An envelope as plain MessagePack, payloads given as maps (anything a forger can send)."""
    body = {"type": "peer.envelope", "sender": sender, "seq": 1, "stamp_s": 5.0, **header,
            "payloads": payloads}  # fmt: skip
    return msgspec.msgpack.encode(body)


def _as_map(p: object) -> dict:
    return msgspec.msgpack.decode(encode_unchecked(p))  # type: ignore[arg-type]


def test_round_trip_gives_back_every_payload():
    tick = _tick()
    packed = pack(1, 7, tick)
    assert packed.data is not None and packed.rejected == []
    got = unpack(packed.data, sender=1, known_senders=range(3))
    assert got.errors == []
    assert (got.sender, got.seq, got.stamp_s) == (1, 7, 5.0)  # the newest inner stamp
    assert len(got.payloads) == len(tick)
    assert all(_same(a, b) for a, b in zip(got.payloads, tick, strict=True))
    assert got.payloads[3].state.dtype == np.float64


def test_pack_keeps_the_newest_of_each_kind():
    old = MotionShare(sender=1, seq=1, stamp_s=1.0, v_body=(0.0, 0.0, 0.0),
                      yaw_rate_rad_s=0.0, yaw_rad=0.0)  # fmt: skip
    loc = LocalizationState(sender=1, seq=1, stamp_s=1.0, p_hat_ned=(1.0, 2.0, 3.0),
                            yaw_hat_rad=0.0)  # fmt: skip
    new = msgspec.structs.replace(old, seq=2, stamp_s=1.1)
    packed = pack(1, 1, [old, loc, new])
    got = unpack(packed.data, sender=1)
    assert [kind_of(p) for p in got.payloads] == ["motion", "localization"]
    assert got.payloads[0].seq == 2


def test_pack_leaves_out_a_nonfinite_payload_and_sends_the_rest():
    tick = _tick()
    bad = msgspec.structs.replace(tick[0], yaw_rad=float("nan"))
    nan_array = msgspec.structs.replace(tick[3], state=np.array([0.0, np.inf]))
    packed = pack(1, 3, [bad, tick[1], nan_array])
    assert [type(p) for p, _ in packed.rejected] == [MotionShare, RigidityEigenShare]
    assert all(exc.reason == "nonfinite" for _, exc in packed.rejected)
    got = unpack(packed.data, sender=1)
    assert [type(p) for p in got.payloads] == [BearingShare]
    assert pack(1, 4, [bad]).data is None
    assert pack(1, 5, []).data is None


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (b"\xc1garbage", "malformed"),
        (b"", "malformed"),
        (encode_unchecked(_tick()[0]), "malformed"),  # a bare payload is not an envelope
        (_raw_envelope(1, [], version=SCHEMA_VERSION + 1), "version"),
        (_raw_envelope(1, [], stamp_s=float("nan")), "nonfinite"),
        (_raw_envelope(1, [{"type": "peer.motion"}] * (ENVELOPE_MAX_PAYLOADS + 1)), "out_of_range"),
        (_raw_envelope(1, "not a list"), "malformed"),  # type: ignore[arg-type]
        (_raw_envelope(2, []), "sender_mismatch"),  # the envelope itself claims another sender
        (_raw_envelope(9, []), "unknown_sender"),  # checked first, as a bare payload was
        (b"\x00" * (MAX_PAYLOAD_BYTES + 1), "oversize"),
    ],
)
def test_a_bad_envelope_is_one_error_with_its_reason(data, reason):
    with pytest.raises(MessageError) as info:
        unpack(data, sender=1, known_senders=range(3))
    assert info.value.reason == reason


def test_an_envelope_from_outside_the_fleet_is_unknown_sender():
    with pytest.raises(MessageError) as info:
        unpack(pack(7, 1, _tick(sender=7)).data, sender=7, known_senders=range(3))
    assert info.value.reason == "unknown_sender"


def test_a_forged_inner_sender_is_dropped_and_its_siblings_kept():
    tick = _tick()
    forged = msgspec.structs.replace(tick[2], sender=2)  # vehicle 1 speaking for vehicle 2
    data = encode_unchecked(PeerEnvelope(sender=1, seq=1, payloads=[tick[0], forged, tick[1]]))
    got = unpack(data, sender=1, known_senders=range(3))
    assert [type(p) for p in got.payloads] == [MotionShare, BearingShare]
    assert [e.reason for e in got.errors] == ["sender_mismatch"]


@pytest.mark.parametrize(
    ("field", "value", "reason"),
    [
        ("yaw_rad", float("nan"), "nonfinite"),
        ("yaw_rad", float("-inf"), "nonfinite"),
        ("v_body", [float("inf"), 0.0, 0.0], "nonfinite"),
        ("v_body", [1e300, 0.0, 0.0], "out_of_range"),
        ("version", SCHEMA_VERSION - 1, "version"),
        ("sender", 99, "unknown_sender"),
        ("v_body", "fast", "malformed"),
    ],
)
def test_a_bad_inner_payload_is_dropped_with_its_reason(field, value, reason):
    tick = _tick()
    motion = {**_as_map(tick[0]), field: value}
    data = _raw_envelope(1, [_as_map(tick[1]), motion, _as_map(tick[2])])
    got = unpack(data, sender=1, known_senders=range(3))
    assert [type(p) for p in got.payloads] == [BearingShare, SfmEstimate]
    assert [e.reason for e in got.errors] == [reason]


def test_nan_inside_a_float64_array_is_caught_on_the_fast_path():
    tick = _tick()
    nan = msgspec.structs.replace(tick[3], per_target=np.array([0.0, np.nan]))
    data = encode_unchecked(PeerEnvelope(sender=1, seq=1, payloads=[tick[0], nan]))
    got = unpack(data, sender=1)
    assert [type(p) for p in got.payloads] == [MotionShare]
    assert [e.reason for e in got.errors] == ["nonfinite"]


def test_kinds_keeps_only_the_kinds_asked_for():
    data = pack(1, 1, _tick()).data
    got = unpack(data, sender=1, kinds={"rigidity_eigen"})
    assert [type(p) for p in got.payloads] == [RigidityEigenShare]
    assert got.errors == []


def test_sample_payloads_reads_the_sender_from_the_key():
    data = pack(1, 1, _tick()).data
    assert envelope_sender(peer_key("alpha", 1)) == 1
    assert envelope_sender("bf/alpha/1/peer/motion") is None
    assert len(sample_payloads(peer_key("alpha", 1), data).payloads) == 4
    with pytest.raises(MessageError) as info:
        sample_payloads(peer_key("alpha", 2), data)  # vehicle 1's envelope on vehicle 2's key
    assert info.value.reason == "sender_mismatch"
    with pytest.raises(MessageError) as info:
        sample_payloads("bf/alpha/1/status", data)
    assert info.value.reason == "foreign"


def test_kinds_not_asked_for_are_not_even_decoded():
    tick = _tick()
    bad_motion = {**_as_map(tick[0]), "yaw_rad": float("nan")}
    bad_eigen = {**_as_map(tick[3]), "lambda_hat": "big"}
    data = _raw_envelope(1, [bad_motion, _as_map(tick[3])])
    got = unpack(data, sender=1, kinds={"rigidity_eigen"})
    assert [type(p) for p in got.payloads] == [RigidityEigenShare] and got.errors == []
    got = unpack(_raw_envelope(1, [bad_motion, bad_eigen]), sender=1, kinds={"rigidity_eigen"})
    assert got.payloads == [] and [e.reason for e in got.errors] == ["malformed"]
    forged = {**_as_map(tick[3]), "sender": 2}
    got = unpack(_raw_envelope(1, [forged]), sender=1, kinds={"rigidity_eigen"})
    assert got.payloads == [] and [e.reason for e in got.errors] == ["sender_mismatch"]
    got = unpack(_raw_envelope(1, [b"\xc1"]), sender=1, kinds={"motion"})  # type: ignore[list-item]
    assert [e.reason for e in got.errors] == ["malformed"]  # no tag to read: counted
