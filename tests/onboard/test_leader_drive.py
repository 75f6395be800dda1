"""A driven leader (onboard/control/leader.py, onboard/core/motion.py): a velocity for a duration
and then a hold, waypoints flown in order at a bounded speed, and in the core the drive's NED
velocity turned into the body frame by the odometry yaw and saturated by ``v_max``; only the
formation's leader takes a drive, and followers keep flying the formation law."""

from __future__ import annotations

import math

import numpy as np
import pytest

from messages.agent import BearingMeasurement, OwnMeasurements
from onboard.control.leader import LeaderPlan, ned_to_body, waypoint_velocity
from onboard.core.agent import AgentCore
from onboard.core.config import build_config
from onboard.geometry import bearings_body, rot_z

TRIANGLE = ((0, 1), (1, 0), (1, 2), (2, 1), (0, 2), (2, 0))
P = np.array([[0.0, 0.0, -5.0], [4.0, 0.0, -5.0], [2.0, 3.464, -5.0]])
YAW = np.array([0.3, -0.4, 1.1])


def test_a_velocity_is_flown_for_its_duration_then_the_leader_holds():
    plan = LeaderPlan(velocity_ned=(0.2, -0.1, 0.0), duration_s=2.0)
    assert plan.step(10.0, None) == ((0.2, -0.1, 0.0), "velocity")  # starts at its first step
    assert plan.step(11.9, None) == ((0.2, -0.1, 0.0), "velocity")
    assert plan.step(12.0, None) == ((0.0, 0.0, 0.0), "velocity done")
    assert LeaderPlan(velocity_ned=(1.0, 0.0, 0.0)).step(1e6, None)[1] == "velocity"


def test_waypoints_are_flown_in_order_at_a_bounded_speed():
    wps = [(2.0, 0.0, -5.0), (2.0, 2.0, -6.0), (0.0, 2.0, -5.0)]
    plan = LeaderPlan(waypoints_ned=wps, speed_m_s=0.5, tolerance_m=0.2)
    p = np.array([-1.0, 0.0, -5.0])
    dt, visited, speeds, states = 0.05, [], [], []
    for k in range(1200):
        v, state = plan.step(k * dt, tuple(p))
        speeds.append(math.hypot(*v))
        states.append(state)
        p = p + dt * np.array(v)
        near = [m for m, w in enumerate(wps) if np.linalg.norm(p - w) < 0.2]
        if near and (not visited or visited[-1] != near[0]):
            visited.append(near[0])
    assert visited == [0, 1, 2]
    assert max(speeds) <= 0.5 + 1e-12
    assert states[0] == "waypoint 1/3" and "waypoint 2/3" in states
    assert states[-1] == "waypoints done"
    assert np.linalg.norm(p - wps[-1]) < 0.01  # the last one is held
    assert LeaderPlan(waypoints_ned=wps).step(0.0, None) == ((0.0, 0.0, 0.0),
                                                             "no odometry position")  # fmt: skip


def test_waypoint_velocity_is_bounded_and_proportional_near_the_waypoint():
    assert waypoint_velocity((0.0, 0.0, 0.0), (10.0, 0.0, 0.0), 0.5) == (0.5, 0.0, 0.0)
    v = waypoint_velocity((0.0, 0.0, 0.0), (0.0, 0.2, 0.0), 0.5, k_p=1.0)
    assert v == pytest.approx((0.0, 0.2, 0.0))
    yaw = 0.7
    assert np.allclose(rot_z(yaw) @ np.array(ned_to_body((1.0, 2.0, 3.0), yaw)), (1.0, 2.0, 3.0))


def _core(agent_id: int, v_max: float = 3.0) -> AgentCore:
    beta, _ = bearings_body(P, YAW, TRIANGLE)
    desired = tuple(
        (i, j, tuple(float(x) for x in b)) for (i, j), b in zip(TRIANGLE, beta, strict=True)
    )
    cfg = build_config(
        agent_id=agent_id, n_agents=3, edges=TRIANGLE, mode="formation-active",
        p_hat0_ned=tuple(tuple(float(x) for x in r) for r in P),
        yaw_hat0_rad=tuple(float(y) for y in YAW), desired_beta_body=desired,
        desired_yaw_rad=tuple(float(y) for y in YAW), v_max_m_s=v_max,
    )  # fmt: skip
    return AgentCore(cfg)


def _own(t, i, position=None):
    others = [j for j in range(3) if j != i]
    b, _ = bearings_body(P, YAW, [(i, j) for j in others])
    return OwnMeasurements(
        t_s=t, yaw_rad=float(YAW[i]), v_body=(0.0, 0.0, 0.0), yaw_rate_rad_s=0.0,
        bearings=tuple(BearingMeasurement(j, tuple(b[k]), t) for k, j in enumerate(others)),
        position_ned=position,
    )  # fmt: skip


def test_the_leader_flies_its_drive_in_the_body_frame_saturated_by_v_max():
    core = _core(0, v_max=1.0)
    assert not core.drive_leader(LeaderPlan(velocity_ned=(0.3, 0.0, 0.0)))  # no leader yet
    core.adopt_formation(P, YAW, leader=0)
    sp, _ = core.step(0.0, _own(0.0, 0))
    assert sp.v_body == (0.0, 0.0, 0.0) and core.status().leader_drive == "hold"
    assert core.drive_leader(LeaderPlan(velocity_ned=(0.3, 0.1, -0.05), duration_s=1.0))
    sp, _ = core.step(0.1, _own(0.1, 0))
    assert np.allclose(rot_z(YAW[0]) @ np.array(sp.v_body), (0.3, 0.1, -0.05))
    assert core.status().leader_drive == "velocity"
    core.step(1.2, _own(1.2, 0))
    assert core.status().leader_drive == "velocity done"

    core.drive_leader(LeaderPlan(velocity_ned=(5.0, 0.0, 0.0)))  # beyond v_max
    sp, _ = core.step(1.3, _own(1.3, 0))
    assert math.hypot(*sp.v_body) == pytest.approx(1.0)
    assert np.allclose(rot_z(YAW[0]) @ np.array(sp.v_body), (1.0, 0.0, 0.0))

    core.drive_leader(LeaderPlan(waypoints_ned=[(1.0, 0.0, -5.0)], speed_m_s=0.4))
    sp, _ = core.step(1.4, _own(1.4, 0, position=(0.0, 0.0, -5.0)))
    assert np.allclose(rot_z(YAW[0]) @ np.array(sp.v_body), (0.4, 0.0, 0.0))
    assert core.status().leader_drive == "waypoint 1/1"


def test_a_follower_refuses_a_drive_and_a_new_leader_drops_it():
    follower = _core(1)
    follower.adopt_formation(P, YAW, leader=0)
    assert not follower.drive_leader(LeaderPlan(velocity_ned=(0.3, 0.0, 0.0)))
    assert follower.status().leader_drive == ""
    leader = _core(0)
    leader.adopt_formation(P, YAW, leader=0)
    assert leader.drive_leader(LeaderPlan(velocity_ned=(0.3, 0.0, 0.0)))
    leader.adopt_formation(2.0 * P, YAW, leader=0)  # the same leader: the drive stays
    assert leader.controller.drive is not None
    leader.adopt_formation(P, YAW, leader=1)
    assert leader.controller.drive is None
