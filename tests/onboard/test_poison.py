"""One bad sample must never break a vehicle (issue 23): regression tests of the agent core and
its estimators against well-formed poison, one defect each."""

from __future__ import annotations

import math

from messages.agent import OwnMeasurements
from messages.codec import decode, encode
from messages.peer import PeerPayload, SfmEstimate
from onboard.agent import AgentConfig, AgentCore
from onboard.estimation.sfm_observer import predict_bearing

TRIANGLE = ((0, 1), (1, 0), (1, 2), (2, 1), (0, 2), (2, 0))
P0 = ((0.0, 0.0, -2.0), (2.5, 0.5, -2.6), (0.5, 2.6, -1.5))


def core(agent_id: int = 1, **kw) -> AgentCore:
    return AgentCore(
        AgentConfig(agent_id=agent_id, n_agents=3, edges=TRIANGLE, p_hat0_ned=P0, seed=1, **kw)
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
        sender=0, seq=1, stamp_s=1.0, peers=[1], chi_hat_inv_m=[0.25], excitation=[1.0],
        e_index=[0.0], e_folds=[10.0],
    )  # fmt: skip
    c.step(1.01, own(1.01), [wire(est)])
    assert c.chi_hat(0) == 0.25
    assert c.status().chi_hat_inv_m[0] == 0.25
    c.step(1.0 + 2 * c.config.peer_timeout_s, own(1.0 + 2 * c.config.peer_timeout_s))
    assert c.chi_hat(0) is None  # a silent neighbour's last distance is not kept forever
    assert 0 not in c.status().chi_hat_inv_m
    assert c._received_e_folds(0) == 0.0 and not c.scale_converged()
    assert all(math.isfinite(x) for x in c.status().p_hat_ned)
