"""Bearing formation law (paper 002 eq. 20, f_C(c) = 1 - c) and yaw alignment against finite
differences of their costs; random-motion baseline."""

import numpy as np
import pytest

from onboard.control.formation import (
    bearing_error_deg,
    formation_cost,
    formation_velocity,
    yaw_alignment_cost,
    yaw_alignment_rate,
)
from onboard.control.random_motion import RandomMotion
from onboard.geometry import bearings_body, rot_z

EDGES = np.array([[0, 1], [1, 0], [1, 2], [2, 0], [2, 3], [3, 1], [0, 3]])


@pytest.mark.parametrize("seed", [0, 1])
def test_formation_velocity_is_the_negative_gradient(seed):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(4, 3)) * 2
    yaw = rng.uniform(-3, 3, 4)
    des = rng.normal(size=(len(EDGES), 3))
    des /= np.linalg.norm(des, axis=1, keepdims=True)
    beta, _ = bearings_body(p, yaw, EDGES)
    k_f = 0.7
    for i in range(4):
        out = [(tuple(beta[e]), tuple(des[e])) for e in range(len(EDGES)) if EDGES[e, 0] == i]
        inn = [
            (yaw[EDGES[e, 0]] - yaw[i], tuple(beta[e]), tuple(des[e]))
            for e in range(len(EDGES))
            if EDGES[e, 1] == i
        ]
        u_body = np.array(formation_velocity(out, inn, k_f))
        grad = np.zeros(3)
        for m in range(3):
            dp = np.zeros((4, 3))
            dp[i, m] = 1e-6
            grad[m] = (
                formation_cost(p + dp, yaw, EDGES, des) - formation_cost(p - dp, yaw, EDGES, des)
            ) / 2e-6
        assert np.allclose(rot_z(yaw[i]) @ u_body, -k_f * grad, atol=1e-6)


def test_formation_velocity_vanishes_at_the_desired_bearings():
    rng = np.random.default_rng(2)
    p = rng.normal(size=(4, 3))
    yaw = rng.uniform(-3, 3, 4)
    beta, _ = bearings_body(p, yaw, EDGES)
    out = [(tuple(beta[e]), tuple(beta[e])) for e in range(len(EDGES)) if EDGES[e, 0] == 0]
    inn = [(1.0, tuple(beta[e]), tuple(beta[e])) for e in range(len(EDGES)) if EDGES[e, 1] == 0]
    assert np.allclose(formation_velocity(out, inn), 0.0)
    assert formation_cost(p, yaw, EDGES, beta) == pytest.approx(0.0, abs=1e-12)
    assert np.allclose(bearing_error_deg(beta, beta), 0.0, atol=1e-5)


def test_yaw_alignment_is_the_negative_gradient():
    rng = np.random.default_rng(3)
    yaw = rng.uniform(-3, 3, 4)
    yaw_des = rng.uniform(-3, 3, 4)
    pairs = np.array([[0, 1], [1, 2], [2, 3], [0, 3]])
    for i in range(4):
        nbrs = [
            (yaw[b if a == i else a], yaw_des[b if a == i else a] - yaw_des[i])
            for a, b in pairs
            if i in (a, b)
        ]
        e = np.zeros(4)
        e[i] = 1e-6
        fd = (
            yaw_alignment_cost(yaw + e, pairs, yaw_des)
            - yaw_alignment_cost(yaw - e, pairs, yaw_des)
        ) / 2e-6
        assert yaw_alignment_rate(yaw[i], nbrs, k_psi=2.0) == pytest.approx(-2.0 * fd, abs=1e-6)


def test_random_motion_keeps_speed_and_is_seeded():
    a = RandomMotion(seed=4, speed_m_s=0.7)
    b = RandomMotion(seed=4, speed_m_s=0.7)
    c = RandomMotion(seed=5, speed_m_s=0.7)
    ua = [a.step(0.002) for _ in range(2000)]
    ub = [b.step(0.002) for _ in range(2000)]
    uc = [c.step(0.002) for _ in range(2000)]
    assert ua == ub and ua != uc
    assert np.allclose(np.linalg.norm(ua, axis=1), 0.7)
    d = np.array(ua)
    assert np.dot(d[0], d[-1]) / 0.49 < 0.9  # the direction wanders within 4 s
