"""A formation change in flight (onboard/core/motion.py): the core recomputes ``beta*_ij`` from
the new formation on its own sensing edges, its command descends the new bearing cost
(paper 002 eq. 20), and a leader is not moved by the law."""

import numpy as np
import pytest

from messages.agent import BearingMeasurement, OwnMeasurements
from onboard.core.agent import AgentCore
from onboard.core.config import build_config
from onboard.geometry import bearings_body, rot_z

TRIANGLE = ((0, 1), (1, 0), (1, 2), (2, 1), (0, 2), (2, 0))
P_OLD = np.array([[0.0, 0.0, -5.0], [4.0, 0.0, -5.0], [2.0, 3.464, -5.0]])  # equilateral
P_NEW = np.array([[0.0, 0.0, -5.0], [6.0, 0.0, -5.0], [3.0, 2.0, -5.0]])  # isosceles, larger
YAW = np.array([0.3, -0.4, 1.1])


def _core(mode="formation", agent_id=0):
    beta, _ = bearings_body(P_OLD, YAW, TRIANGLE)
    desired = tuple(
        (i, j, tuple(float(x) for x in b)) for (i, j), b in zip(TRIANGLE, beta, strict=True)
    )
    cfg = build_config(
        agent_id=agent_id, n_agents=3, edges=TRIANGLE, mode=mode,
        p_hat0_ned=tuple(tuple(float(x) for x in r) for r in P_OLD),
        yaw_hat0_rad=tuple(float(y) for y in YAW), desired_beta_body=desired,
        desired_yaw_rad=tuple(float(y) for y in YAW),
    )  # fmt: skip
    return AgentCore(cfg)


def _own(t, p, i):
    others = [j for j in range(3) if j != i]
    b, _ = bearings_body(p, YAW, [(i, j) for j in others])
    return OwnMeasurements(
        t_s=t, yaw_rad=float(YAW[i]), v_body=(0.0, 0.0, 0.0), yaw_rate_rad_s=0.0,
        bearings=tuple(BearingMeasurement(j, tuple(b[k]), t) for k, j in enumerate(others)),
    )  # fmt: skip


def _cost(p, i, desired):
    """Agent ``i``'s out-edge bearing cost ``sum_j 1 - beta_ij . beta*_ij``."""
    edges = [(i, j) for j in range(3) if j != i]
    b, _ = bearings_body(p, YAW, edges)
    return sum(1.0 - float(b[k] @ desired[e]) for k, e in enumerate(edges))


def _command(core, p, i=0):
    sp = None
    for k in range(3):
        sp, _ = core.step(0.1 * k, _own(0.1 * k, p, i))
    return np.array(sp.v_body)


def test_the_new_desired_bearings_come_from_the_new_formation_on_the_same_edges():
    core = _core()
    assert core.adopt_formation(P_NEW, YAW, leader=None)
    want, _ = bearings_body(P_NEW, YAW, TRIANGLE)
    desired = core.controller.desired
    assert sorted(desired) == sorted(TRIANGLE)
    for (i, j), b in zip(TRIANGLE, want, strict=True):
        assert np.allclose(desired[(i, j)], b, atol=1e-12)


def test_the_command_moves_towards_the_new_formation():
    core = _core()
    assert np.allclose(_command(core, P_OLD), 0.0, atol=1e-9)  # at the old formation: still
    core.adopt_formation(P_NEW, YAW)
    v_body = _command(core, P_OLD)
    assert np.linalg.norm(v_body) > 1e-3
    desired = core.controller.desired
    step = P_OLD.copy()
    step[0] += 1e-3 * rot_z(YAW[0]) @ v_body / np.linalg.norm(v_body)  # body -> NED
    assert _cost(step, 0, desired) < _cost(P_OLD, 0, desired) - 1e-7


@pytest.mark.parametrize("mode", ["formation", "formation-active"])
def test_a_leader_holds_and_the_others_follow(mode):
    leader = _core(mode, agent_id=0)
    leader.adopt_formation(P_NEW, YAW, leader=0)
    assert np.allclose(_command(leader, P_OLD), 0.0)
    follower = _core(mode, agent_id=1)
    follower.adopt_formation(P_NEW, YAW, leader=0)
    assert np.linalg.norm(_command(follower, P_OLD, i=1)) > 1e-3


def test_a_mode_without_a_formation_refuses_it():
    assert not _core("active").adopt_formation(P_NEW, YAW)
