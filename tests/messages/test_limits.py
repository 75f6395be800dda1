"""Magnitude limits at the codec (issue 23, defect 1): a well-formed payload carrying a huge
finite number is rejected with reason ``out_of_range``; NaN stays ``nonfinite``; every value a
flying team produces is accepted."""

from __future__ import annotations

import msgspec
import numpy as np
import pytest

from messages.codec import SCHEMA_VERSION, MessageError, decode, encode
from messages.limits import POSITION_MAX_M, SPEED_MAX_M_S
from messages.peer import (
    BearingShare,
    ConsensusState,
    ExcitationTable,
    LocalizationState,
    MotionShare,
    PeerPayload,
    SfmEstimate,
)
from messages.rigidity import RigidityEigenShare
from messages.sim import SimClock, Truth


def _raw(tag: str, **fields) -> bytes:
    """A payload as a sender that does not check what it sends would put it on the wire."""
    return msgspec.msgpack.encode(
        {"type": tag, "version": SCHEMA_VERSION, "sender": 1, "seq": 3, "stamp_s": 10.0, **fields}
    )


MOTION = {"v_body": [0.5, -0.2, 0.1], "yaw_rate_rad_s": 0.3, "yaw_rad": 1.0}
LOCALIZATION = {"p_hat_ned": [1.0, 2.0, -3.0], "yaw_hat_rad": 0.2}


@pytest.mark.parametrize(
    ("tag", "fields"),
    [
        ("peer.motion", {**MOTION, "v_body": [1e300, 0.0, 0.0]}),
        ("peer.motion", {**MOTION, "v_body": [0.0, 1e154, 0.0]}),
        ("peer.motion", {**MOTION, "yaw_rate_rad_s": 100.0}),
        ("peer.motion", {**MOTION, "yaw_rad": -1e300}),
        ("peer.localization", {**LOCALIZATION, "p_hat_ned": [1e300, 0.0, 0.0]}),
        ("peer.localization", {**LOCALIZATION, "p_hat_ned": [0.0, 0.0, 2 * POSITION_MAX_M]}),
        ("peer.motion", {**MOTION, "stamp_s": 1e300}),
        ("peer.motion", {**MOTION, "seq": -1}),
        ("peer.motion", {**MOTION, "sender": -4}),
        ("peer.bearings", {"yaw_rad": 0.0, "targets": [0], "beta_body": [[1e200, 0.0, 0.0]]}),
        (
            "peer.sfm",
            {"peers": [0], "chi_hat_inv_m": [1e300], "excitation": [0.0], "e_index": [0.0]},
        ),
        (
            "peer.excitation",
            {"first": [0], "second": [1], "excitation": [1e300], "stamps_s": [10.0]},
        ),
        (
            "peer.excitation",
            {"first": [0], "second": [1], "excitation": [1.0], "stamps_s": [1e300]},
        ),
        ("peer.consensus", {"names": ["e_index"], "x": [[1e300]], "z": [[0.0]]}),
        ("peer.consensus", {"names": ["n" * 1000], "x": [[1.0]], "z": [[0.0]]}),
        ("peer.consensus", {"names": ["a"] * 45_000, "x": [[1.0]] * 45_000, "z": [[]] * 45_000}),
    ],
)
def test_huge_finite_values_are_out_of_range(tag, fields):
    with pytest.raises(MessageError) as info:
        decode(_raw(tag, **fields), PeerPayload)
    assert info.value.reason == "out_of_range", info.value


def test_nan_is_still_nonfinite_and_not_out_of_range():
    with pytest.raises(MessageError) as info:
        decode(_raw("peer.motion", **{**MOTION, "v_body": [float("nan"), 0.0, 0.0]}), PeerPayload)
    assert info.value.reason == "nonfinite"


def test_float_arrays_are_bounded_too():
    share = RigidityEigenShare(
        sender=1, lambda_hat=0.1, targets=[0], state=np.array([1.0, 1e300]), per_target=np.ones(3)
    )
    with pytest.raises(MessageError) as info:
        decode(encode(share), PeerPayload)
    assert info.value.reason == "out_of_range"


def test_what_a_flying_team_sends_is_accepted():
    fast = 0.9 * SPEED_MAX_M_S
    payloads = [
        MotionShare(sender=2, seq=9, stamp_s=1.7e9, v_body=(fast, -3.0, 1.0), yaw_rate_rad_s=4.0,
                    yaw_rad=-3.1),
        LocalizationState(sender=2, stamp_s=0.0, p_hat_ned=(5e4, -5e4, -100.0), yaw_hat_rad=3.0),
        BearingShare(sender=2, yaw_rad=0.1, targets=[0, 1], beta_body=[(1.0, 0.0, 0.0)] * 2),
        SfmEstimate(sender=2, peers=[3], chi_hat_inv_m=[-0.01], excitation=[40.0],
                    e_index=[1e-5], e_folds=[1e4]),
        ExcitationTable(sender=2, first=[2], second=[3], excitation=[0.0], stamps_s=[12.5]),
        ConsensusState(sender=2, names=["e_index", "p_bar"], x=[[0.1], [1.0, 2.0, -3.0]],
                       z=[[0.0], [0.0, 0.0, 0.0]]),
    ]  # fmt: skip
    for p in payloads:
        assert decode(encode(p), PeerPayload) == p
    clock = SimClock(sender=0, t_s=3600.0, step=1_800_000, speedup=4.0, lockstep=False)
    assert decode(encode(clock), SimClock) == clock
    truth = Truth(sender=1, p_ned=(1.0, 2.0, -5.0), v_ned=(1.0, 0.0, 0.0), yaw_rad=0.5,
                  yaw_rate_rad_s=0.2)  # fmt: skip
    assert decode(encode(truth), Truth) == truth
