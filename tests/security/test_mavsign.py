"""The signature check itself (pure logic on real pymavlink frames): HMAC first, then the
timestamp per stream; the allow-list only for frames without a signature (issue 24)."""

from __future__ import annotations

import hashlib

from pymavlink.dialects.v20 import common

from messages.mavsign import (
    NEW_STREAM_MAX_AGE,
    TIMESTAMP_UNITS_PER_S,
    SignatureVerifier,
    Verdict,
    sign_outgoing,
    signing_timestamp,
)

KEY = hashlib.sha256(b"vehicle 0").digest()
OTHER = hashlib.sha256(b"attacker").digest()
T0 = 1_800_000_000.0  # a fixed wall clock (s), for determinism
ARM = common.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
RADIO = common.MAVLink_radio_status_message(200, 180, 90, 10, 5, 0, 0)
HB = common.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3)


def _sender(key: bytes | None, ts: int | None = None, link_id: int = 0, sysid: int = 245):
    mav = common.MAVLink(None, srcSystem=sysid, srcComponent=190)
    if key is not None:
        sign_outgoing(mav, key, link_id)
        mav.signing.timestamp = signing_timestamp(T0) if ts is None else ts
    return mav


def _frame(msg, mav) -> bytes:
    buf = bytes(msg.pack(mav))
    mav.seq = (mav.seq + 1) % 256
    return buf


def _check(v: SignatureVerifier, frame: bytes, msg_id: int, sysid: int = 245) -> Verdict:
    return v.check(frame, msg_id, sysid, 190)


def _verifier() -> SignatureVerifier:
    return SignatureVerifier(KEY, clock=lambda: T0)


def test_good_then_replay_then_next():
    v, mav = _verifier(), _sender(KEY)
    first = _frame(ARM, mav)
    assert _check(v, first, 76) is Verdict.GOOD
    assert _check(v, first, 76) is Verdict.REPLAYED  # same timestamp again
    assert _check(v, _frame(ARM, mav), 76) is Verdict.GOOD  # timestamp + 1
    assert v.counters.as_dict() == {
        "good": 2, "allowed_unsigned": 0, "unsigned": 0, "bad_signature": 0, "replayed": 1,
    }  # fmt: skip


def test_wrong_key_and_tampered_frames_are_bad_signatures():
    v = _verifier()
    assert _check(v, _frame(ARM, _sender(OTHER)), 76) is Verdict.BAD_SIGNATURE
    good = bytearray(_frame(ARM, _sender(KEY)))
    good[12] ^= 0x01  # a payload bit: the HMAC covers it
    assert _check(v, bytes(good), 76) is Verdict.BAD_SIGNATURE
    assert _check(v, bytes(good[:14]), 76) is Verdict.BAD_SIGNATURE  # too short to be signed
    assert v.counters.bad_signature == 3 and v.counters.good == 0


def test_forged_far_future_packet_does_not_lock_the_stream():
    """pymavlink 2.4.50 stores the timestamp before the HMAC check: one forged frame with the
    client's (link id, system, component) and a far-future timestamp locked the client out."""
    v = _verifier()
    far = signing_timestamp(T0) + 10 * 365 * 86400 * TIMESTAMP_UNITS_PER_S
    forged = _frame(ARM, _sender(OTHER, ts=far))  # same link id 0, system 245, component 190
    assert _check(v, forged, 76) is Verdict.BAD_SIGNATURE  # before the client's first frame
    client = _sender(KEY)
    assert _check(v, _frame(ARM, client), 76) is Verdict.GOOD
    assert _check(v, forged, 76) is Verdict.BAD_SIGNATURE  # and after it
    assert _check(v, _frame(ARM, client), 76) is Verdict.GOOD
    assert v.local_timestamp() < far


def test_allow_list_is_for_unsigned_frames_only():
    """pymavlink 2.4.50 asks allow_unsigned_callback about wrongly signed frames too."""
    v = _verifier()
    assert _check(v, _frame(RADIO, _sender(None)), 109) is Verdict.ALLOWED_UNSIGNED
    assert _check(v, _frame(RADIO, _sender(OTHER)), 109) is Verdict.BAD_SIGNATURE
    assert _check(v, _frame(HB, _sender(None)), 0) is Verdict.UNSIGNED  # not on PX4's list
    assert _check(v, _frame(HB, _sender(OTHER)), 0) is Verdict.BAD_SIGNATURE
    assert _check(v, _frame(ARM, _sender(None)), 76) is Verdict.UNSIGNED
    assert Verdict.ALLOWED_UNSIGNED.accepted and not Verdict.BAD_SIGNATURE.accepted


def test_new_stream_at_most_one_minute_old_and_streams_are_separate():
    v = _verifier()
    now = signing_timestamp(T0)
    assert _check(v, _frame(ARM, _sender(KEY, ts=now - NEW_STREAM_MAX_AGE - 10)), 76) is (
        Verdict.REPLAYED
    )
    assert _check(v, _frame(ARM, _sender(KEY, ts=now - NEW_STREAM_MAX_AGE + 10)), 76) is (
        Verdict.GOOD
    )
    # another link id is another stream: its older timestamp is fine
    assert _check(v, _frame(ARM, _sender(KEY, ts=now - 100, link_id=1)), 76) is Verdict.GOOD
    # the first stream moved on to now - 60 s + 10; a frame of it from before is a replay
    assert _check(v, _frame(ARM, _sender(KEY, ts=now - NEW_STREAM_MAX_AGE)), 76) is (
        Verdict.REPLAYED
    )


def test_key_per_system():
    keys = {1: KEY, 2: OTHER}
    v = SignatureVerifier(keys, clock=lambda: T0)
    assert _check(v, _frame(HB, _sender(KEY, sysid=1)), 0, sysid=1) is Verdict.GOOD
    assert _check(v, _frame(HB, _sender(OTHER, sysid=2)), 0, sysid=2) is Verdict.GOOD
    # vehicle 2's key does not speak for vehicle 1, and a system without a key is rejected
    assert _check(v, _frame(HB, _sender(OTHER, sysid=1)), 0, sysid=1) is Verdict.BAD_SIGNATURE
    assert _check(v, _frame(HB, _sender(KEY, sysid=3)), 0, sysid=3) is Verdict.BAD_SIGNATURE


def test_sign_outgoing_turns_pymavlink_own_check_off():
    """The receiving side of a signing pymavlink object passes everything on (the verifier
    decides): its own check would store a forged frame's timestamp."""
    rx = common.MAVLink(None, srcSystem=1, srcComponent=1)
    sign_outgoing(rx, KEY, 0)
    msgs = rx.parse_buffer(_frame(ARM, _sender(OTHER)) + _frame(HB, _sender(None))) or []
    assert [m.get_type() for m in msgs] == ["COMMAND_LONG", "HEARTBEAT"]
    assert rx.signing.stream_timestamps == {}


def test_fleet_access_control_rules():
    from messages.zenoh_acl import fleet_access_control

    acl = fleet_access_control("t1", 2, "alpha")["access_control"]
    assert acl["enabled"] and acl["default_permission"] == "deny"
    rules = {r["id"]: r for r in acl["rules"]}
    assert rules["own_1"]["key_exprs"] == ["bf/t1/1/**"] and rules["own_1"]["flows"] == ["ingress"]
    assert "put" not in rules["read"]["messages"]  # reading is not writing
    subjects = {s["id"]: s["cert_common_names"] for s in acl["subjects"]}
    assert subjects == {
        "gcs": ["alpha-gcs"], "sim": ["alpha-sim"],
        "vehicle_0": ["alpha-vehicle-0"], "vehicle_1": ["alpha-vehicle-1"],
    }  # fmt: skip
    policies = {p["subjects"][0]: p["rules"] for p in acl["policies"]}
    assert policies["vehicle_0"] == ["read", "deliver", "own_0"]  # not own_1, not gcs_put
    assert policies["gcs"] == ["read", "deliver", "gcs_put"]
