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
    ConsensusEntry,
    ConsensusState,
    EdgeExcitation,
    ExcitationTable,
    LocalizationState,
    MotionShare,
    PeerPayload,
    SfmEdgeEstimate,
    SfmEstimate,
    TargetBearing,
)
from messages.rigidity import AngleLocalizationShare, GradientBlock, RigidityEigenShare
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
        ("peer.bearings", {"yaw_rad": 0.0, "bearings": [[0, [1e200, 0.0, 0.0]]]}),
        ("peer.bearings", {"yaw_rad": 0.0, "bearings": [[70_000, [1.0, 0.0, 0.0]]]}),
        ("peer.sfm", {"edges": [[0, 1e300, 0.0, 0.0, 0.0]]}),
        ("peer.excitation", {"entries": [[0, 1, 1e300, 10.0]]}),
        ("peer.excitation", {"entries": [[0, 1, 1.0, 1e300]]}),
        ("peer.consensus", {"states": [["e_index", [1e300], [0.0]]]}),
        ("peer.consensus", {"states": [["n" * 1000, [1.0], [0.0]]]}),
        ("peer.consensus", {"states": [["a", [1.0], []]] * 45_000}),
        (
            "peer.angle_localization",
            {
                "p_hat_ned": [0.0, 0.0, 0.0],
                "yaw_hat_rad": 0.0,
                "yaw_known": True,
                "blocks": [[1, [1e300, 0.0, 0.0]]],
            },
        ),
    ],
)
def test_huge_finite_values_are_out_of_range(tag, fields):
    with pytest.raises(MessageError) as info:
        decode(_raw(tag, **fields), PeerPayload)
    assert info.value.reason == "out_of_range", info.value


@pytest.mark.parametrize(
    ("tag", "fields"),
    [
        ("peer.bearings", {"yaw_rad": 0.0, "bearings": [[0]]}),  # a target without its bearing
        ("peer.bearings", {"yaw_rad": 0.0, "bearings": [[0, [1.0, 0.0, 0.0], 5]]}),
        ("peer.sfm", {"edges": [[0, 0.5, 1.0, 0.0]]}),  # no e-foldings
        ("peer.excitation", {"entries": [[0, 1, 1.0]]}),  # no stamp
        ("peer.consensus", {"states": [["e_index", [1.0]]]}),  # no z
        ("peer.consensus", {"states": [[7, [1.0], []]]}),  # a name that is not a string
        ("peer.angle_localization", {"p_hat_ned": [0.0, 0.0, 0.0], "yaw_hat_rad": 0.0,
                                     "yaw_known": True, "blocks": [[1]]}),
    ],
)  # fmt: skip
def test_a_half_entry_is_malformed_on_decode(tag, fields):
    """Entries replace parallel lists (issue 21): one of the wrong arity or types never reaches
    a receiver, which therefore checks no lengths."""
    with pytest.raises(MessageError) as info:
        decode(_raw(tag, **fields), PeerPayload)
    assert info.value.reason == "malformed", info.value


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
        BearingShare(sender=2, yaw_rad=0.1, bearings=[TargetBearing(0, (1.0, 0.0, 0.0)),
                                                      TargetBearing(1, (0.0, 1.0, 0.0))]),
        SfmEstimate(sender=2, edges=[SfmEdgeEstimate(3, -0.01, 40.0, 1e-5, 1e4)]),
        ExcitationTable(sender=2, entries=[EdgeExcitation(2, 3, 0.0, 12.5)]),
        ConsensusState(sender=2, states=[ConsensusEntry("e_index", [0.1], [0.0]),
                                         ConsensusEntry("p_bar", [1.0, 2.0, -3.0], [0.0] * 3)]),
        AngleLocalizationShare(sender=2, p_hat_ned=(1.0, 2.0, -3.0), yaw_hat_rad=0.5,
                               yaw_known=True, blocks=[GradientBlock(0, (0.1, -0.2, 0.3))]),
    ]  # fmt: skip
    for p in payloads:
        assert decode(encode(p), PeerPayload) == p
    clock = SimClock(sender=0, t_s=3600.0, step=1_800_000, speedup=4.0, lockstep=False)
    assert decode(encode(clock), SimClock) == clock
    truth = Truth(sender=1, p_ned=(1.0, 2.0, -5.0), v_ned=(1.0, 0.0, 0.0), yaw_rad=0.5,
                  yaw_rate_rad_s=0.2)  # fmt: skip
    assert decode(encode(truth), Truth) == truth
