"""One bad sample must never break a vehicle (issue 23): regression tests of the agent core and
its estimators against well-formed poison, one defect each."""

from __future__ import annotations

import math

import msgspec

from messages.agent import BearingMeasurement, OwnMeasurements
from messages.codec import decode, encode
from messages.peer import (
    BearingShare,
    ConsensusEntry,
    ConsensusState,
    EdgeExcitation,
    ExcitationTable,
    MotionShare,
    PeerPayload,
    SfmEdgeEstimate,
    SfmEstimate,
    TargetBearing,
)
from messages.sim import CameraBearings
from onboard.core.agent import AgentCore
from onboard.core.config import build_config
from onboard.daemon.bearings import SimCameraSource
from onboard.daemon.peers import DropCounter
from onboard.estimation.sfm_observer import predict_bearing

TRIANGLE = ((0, 1), (1, 0), (1, 2), (2, 1), (0, 2), (2, 0))
P0 = ((0.0, 0.0, -2.0), (2.5, 0.5, -2.6), (0.5, 2.6, -1.5))


def core(agent_id: int = 1, **kw) -> AgentCore:
    return AgentCore(
        build_config(agent_id=agent_id, n_agents=3, edges=TRIANGLE, p_hat0_ned=P0, seed=1, **kw)
    )


def own(t_s: float) -> OwnMeasurements:
    return OwnMeasurements(t_s=t_s, yaw_rad=0.1, v_body=(0.0, 0.0, 0.0), yaw_rate_rad_s=0.0)


def wire(msg):
    """Through the codec, as a daemon receives it."""
    return decode(encode(msg), PeerPayload)


# ---------------------------------------------------------------- defect 1: magnitudes


def test_predict_bearing_never_divides_by_zero():
    assert predict_bearing((0.0, 0.0, 0.0), 0.5, (0.0, 0.0, 0.0), 0.0, 0.002) == (0.0, 0.0, 0.0)
    # a huge relative velocity overflows the norm: the bearing is kept, not turned into zeros
    beta = (1.0, 0.0, 0.0)
    for _ in range(3):
        beta = predict_bearing(beta, 0.5, (0.0, 1e160, 0.0), 0.0, 0.002)
    assert beta == (1.0, 0.0, 0.0)


def test_a_received_sfm_estimate_expires():
    c = core(1)  # edge (0, 1) is run by agent 0, which shares chi_hat with agent 1
    c.step(1.0, own(1.0))
    est = SfmEstimate(
        sender=0, seq=1, stamp_s=1.0, edges=[SfmEdgeEstimate(1, 0.25, 1.0, 0.0, 10.0)]
    )
    c.step(1.01, own(1.01), [wire(est)])
    assert c.chi_hat(0) == 0.25
    assert c.status().chi_hat_inv_m[0] == 0.25
    c.step(1.0 + 2 * c.config.safety.peer_timeout_s, own(1.0 + 2 * c.config.safety.peer_timeout_s))
    assert c.chi_hat(0) is None  # a silent neighbour's last distance is not kept forever
    assert 0 not in c.status().chi_hat_inv_m
    assert c.scale.received_e_folds(0) == 0.0 and not c.scale_converged()
    assert all(math.isfinite(x) for x in c.status().p_hat_ned)


def test_a_received_sfm_estimate_of_a_vanishing_inverse_distance_is_no_distance():
    """A bit-flipped ``chihat`` (1e-158: finite, within the codec's range) reached the rigidity
    layer as a distance of 1e158 m (bench_poison d1-bitflip); the floor every other user of
    an SfM estimate applies (``chi_min_inv_m``) now holds for the rigidity layer's too."""
    c = core(1)
    c.step(1.0, own(1.0))
    for chi, kept in ((0.25, True), (1e-158, False), (0.5 * c.scale.gains.chi_min_inv_m, False)):
        est = SfmEstimate(
            sender=0, seq=1, stamp_s=1.01, edges=[SfmEdgeEstimate(1, chi, 1.0, 0.0, 10.0)]
        )
        c.scale.sfm_in.clear()
        c.step(1.01, own(1.01), [wire(est)])
        assert c.chi_hat(0) == chi  # still reported as received
        assert (c.scale.distances().get(0) == 1.0 / chi) is kept  # edge (1, 2) is its own


# ---------------------------------------------------------------- defect 2: future stamps


def motion(sender: int, stamp_s: float, seq: int = 0) -> MotionShare:
    return MotionShare(
        sender=sender, seq=seq, stamp_s=stamp_s, v_body=(0.1, 0.0, 0.0), yaw_rate_rad_s=0.0,
        yaw_rad=0.5,
    )  # fmt: skip


def test_one_future_stamped_peer_sample_does_not_freeze_peer_state():
    c = core(1)  # runs the SfM observer of edge (1, 2): agent 2's motion history matters
    t = 1.0
    c.step(t, own(t), [wire(motion(2, t))])
    future = wire(motion(2, t + 1e6))
    bearings = wire(BearingShare(sender=2, stamp_s=t + 1e6, yaw_rad=0.0,
                                 bearings=[TargetBearing(1, (1.0, 0.0, 0.0))]))  # fmt: skip
    table = wire(ExcitationTable(sender=2, stamp_s=t,
                                 entries=[EdgeExcitation(0, 2, 5.0, t + 1e6)]))  # fmt: skip
    c.step(t + 0.01, own(t + 0.01), [future, bearings, table])
    for k in range(2, 50):
        t_k = t + 0.01 * k
        c.step(t_k, own(t_k), [wire(motion(2, t_k))])
        assert c.scale.motion_hist[2].newest_s == t_k  # real samples keep coming in
    assert c.dropped["future_stamp"] == 3
    assert 2 not in c.bearings.beta_in and (0, 2) not in c.scale.lam_table


def test_one_future_stamped_camera_frame_does_not_blind_the_core():
    c = core(1)
    beta = (1.0, 0.0, 0.0)

    def frame(t_s: float, stamp_s: float) -> OwnMeasurements:
        b = (BearingMeasurement(0, beta, stamp_s), BearingMeasurement(2, beta, stamp_s))
        return msgspec.structs.replace(own(t_s), bearings=b)

    _, out = c.step(1.0, frame(1.0, 1e6))
    assert not [p for p in out if isinstance(p, BearingShare)] and c.dropped["future_stamp"] == 2
    _, out = c.step(1.02, frame(1.02, 1.01))
    assert [p.stamp_s for p in out if isinstance(p, BearingShare)] == [1.01]


class _Link:
    """What :class:`SimCameraSource` needs of a peer link: its id, the fleet's ids, subscribe."""

    id, known, fleet = 1, frozenset({0, 1, 2}), "t"

    def subscribe(self, key_expr, handler):
        self.handler = handler


class _Sample:
    """A Zenoh sample as the handler reads it (``sample.payload.to_bytes()``)."""

    def __init__(self, msg) -> None:
        self.payload, self.data = self, encode(msg)

    def to_bytes(self) -> bytes:
        return self.data


_sample = _Sample


def test_sim_camera_drops_future_frames_and_bearings_stale_can_fire():
    now = [10.0]
    link, drops = _Link(), DropCounter()
    src = SimCameraSource(link, drops, lambda: now[0])
    frame = lambda stamp: CameraBearings(  # noqa: E731
        sender=1, stamp_s=stamp, targets=[0], beta_body=[(1.0, 0.0, 0.0)]
    )
    link.handler(_sample(frame(10.0 + 1e6)))
    assert src.poll() is None and drops.snapshot() == {"camera_future_stamp": 1}
    link.handler(_sample(frame(10.0)))
    assert src.poll()[0].stamp_s == 10.0
    now[0] = 10.5  # a frame within the allowed skew is fresh, never of negative age
    link.handler(_sample(frame(11.0)))
    assert src.poll()[0].stamp_s == 11.0 and src.age_s(now[0]) == 0.0
    assert src.age_s(13.0) == 2.0  # and it ages: bearings_stale fires once stale_s passes
    now[0] = 0.2  # the simulator restarted: the frame "newest by stamp" lies in the future
    link.handler(_sample(frame(0.2)))
    assert src.poll()[0].stamp_s == 0.2


def test_a_clock_reset_rebuilds_the_stamped_peer_state():
    c = core(1)
    for k in range(100):
        t_k = 100.0 + 0.01 * k
        c.step(t_k, own(t_k), [wire(motion(2, t_k))])
    c.step(0.5, own(0.5), [wire(motion(2, 0.5))])  # restarted simulator: time starts again
    assert c.dropped["time_backwards"] == 1
    c.step(0.51, own(0.51), [wire(motion(2, 0.51))])
    assert c.scale.motion_hist[2].newest_s == 0.51 and c.bearings.own_hist.newest_s == 0.51


# ---------------------------------------------------------------- defect 4: bounded tables


def test_consensus_names_and_excitation_edges_are_bounded_by_the_fleet():
    c = core(1)
    t = 1.0
    for k in range(20):
        t += 0.01
        names = [f"n{k}_{m}" for m in range(1000)]
        cons = ConsensusState(sender=2, stamp_s=t, states=[
            ConsensusEntry(name, [0.0], [0.0]) for name in ["e_index", *names]])  # fmt: skip
        first = [m % 50 for m in range(1000)]
        second = [50 + k + m // 50 for m in range(1000)]
        table = ExcitationTable(sender=2, stamp_s=t, entries=[
            EdgeExcitation(a, b, 1.0, t) for a, b in zip([0, *first], [2, *second], strict=True)
        ])  # fmt: skip
        c.step(t, own(t), [wire(cons), wire(table)])
    assert (
        set(c.scale.cons_in) <= {"e_index", "p_bar", "dlam_dwl", "w_l"}
        and 2 in c.scale.cons_in["e_index"]
    )
    assert set(c.scale.lam_table) <= {(0, 1), (0, 2), (1, 2)} and (0, 2) in c.scale.lam_table
    assert c.dropped["unknown_name"] == 20_000 and c.dropped["unknown_edge"] == 20_000
