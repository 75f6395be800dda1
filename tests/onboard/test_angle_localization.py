"""Angle-based localization (paper 003 eq. 10-11): gradients, distributed = centralized,
convergence on switching IAR graphs, and the yaw read from bearings."""

from __future__ import annotations

import math

import numpy as np
import pytest

from onboard.estimation.angle_localization import (
    AngleLocalizer,
    angle_localization_gradient,
    local_angle_gradient,
    local_vertical_gradient,
    yaw_from_bearings,
)
from onboard.geometry import bearings_body, bearings_world, rot_z
from onboard.graph import angle_set, complete_graph
from onboard.rigidity.angle import angle_function, is_infinitesimally_angle_rigid


def _framework(seed: int = 0, n: int = 6) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-3.0, 3.0, (n, 3)) + np.array([0.0, 0.0, -5.0])


def test_gradient_matches_finite_differences() -> None:
    p = _framework()
    edges = complete_graph(6)
    angles = angle_set(edges)
    f_meas = angle_function(p, angles)
    p_hat = p + np.random.default_rng(1).normal(scale=0.3, size=p.shape)
    value, grad = angle_localization_gradient(p_hat, angles, f_meas, (0, 1), 4.2, 3.0, 0.7)
    assert value > 0.0
    h = 1e-6
    fd = np.zeros_like(p_hat)
    for k in range(p_hat.size):
        e = np.zeros(p_hat.size)
        e[k] = h
        up = angle_localization_gradient(
            p_hat + e.reshape(p.shape), angles, f_meas, (0, 1), 4.2, 3.0, 0.7
        )
        dn = angle_localization_gradient(
            p_hat - e.reshape(p.shape), angles, f_meas, (0, 1), 4.2, 3.0, 0.7
        )
        fd.flat[k] = (up[0] - dn[0]) / (2 * h)
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-8)


def test_local_blocks_sum_to_the_centralized_gradient() -> None:
    p = _framework(2)
    p_hat = p + np.random.default_rng(3).normal(scale=0.2, size=p.shape)
    yaw = np.random.default_rng(4).uniform(-np.pi, np.pi, 6)
    # a directed graph: everyone sees 3 others
    edges = np.array([(i, (i + s) % 6) for i in range(6) for s in (1, 2, 4)])
    beta, _ = bearings_body(p, yaw, edges)
    total = np.zeros_like(p)
    for i in range(6):
        rows = edges[:, 0] == i
        seen = edges[rows, 1]
        _, g = local_angle_gradient(p_hat[i], p_hat[seen], beta[rows], 2.5)
        total[i] += g[0]
        np.add.at(total, seen, g[1:])
    angles = angle_set(edges)
    _, ref = angle_localization_gradient(p_hat, angles, angle_function(p, angles), k_angle=2.5)
    np.testing.assert_allclose(total, ref, atol=1e-12)


def _kabsch_error(p_hat: np.ndarray, p: np.ndarray) -> float:
    a, b = p_hat - p_hat.mean(0), p - p.mean(0)
    u, _, vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(u @ vt))
    r = u @ np.diag([1.0, 1.0, d]) @ vt
    return float(np.sqrt(np.mean(np.sum((a @ r - b) ** 2, axis=1))))


def test_converges_on_switching_iar_graphs() -> None:
    """Gradient flow with the graph switching every 0.5 s among three IAR graphs (prop. 4)."""
    p = _framework(5, 7)
    rng = np.random.default_rng(6)
    graphs = []
    while len(graphs) < 3:
        keep = rng.random(42) < 0.45
        e = complete_graph(7)[keep]
        if is_infinitesimally_angle_rigid(p, e):
            graphs.append(e)
    p_hat = p + rng.normal(scale=0.4, size=p.shape)
    err0 = _kabsch_error(p_hat, p)
    d01 = float(np.linalg.norm(p[1] - p[0]))
    dt = 0.01
    measured = [(a, angle_function(p, a)) for a in map(angle_set, graphs)]
    for k in range(1500):
        angles, f_meas = measured[(k // 50) % 3]  # switch every 0.5 s
        _, g = angle_localization_gradient(p_hat, angles, f_meas, (0, 1), d01, 20.0, 1.0)
        p_hat = p_hat - dt * g
    err = _kabsch_error(p_hat, p)
    assert err0 > 0.3
    assert err < 1e-3 * err0


def test_yaw_from_bearings_recovers_the_yaw() -> None:
    p = _framework(7)
    yaw = np.array([2.7, -1.0, 0.3, 1.9, -2.2, 0.0])
    edges = np.array([(0, j) for j in range(1, 6)])
    beta, _ = bearings_body(p, yaw, edges)
    b_world, _ = bearings_world(p, edges)
    assert yaw_from_bearings(beta, b_world) == pytest.approx(2.7, abs=1e-12)
    assert yaw_from_bearings(np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, 0.0, 1.0]])) is None


def test_localizer_integrates_motion_with_the_estimated_yaw() -> None:
    loc = AngleLocalizer(np.array([0.0, 0.0, -2.0]))
    yaw_true, offset = 0.9, -0.4  # odometry yaw = true yaw + offset
    p_seen = np.array([[3.0, 1.0, -2.0], [-1.0, 4.0, -3.0]])
    beta = (
        rot_z(yaw_true).T
        @ ((p_seen - loc.p_hat_ned).T / np.linalg.norm(p_seen - loc.p_hat_ned, axis=1))
    ).T
    loc.update_yaw(yaw_true + offset, beta, p_seen)
    assert loc.yaw_hat(yaw_true + offset) == pytest.approx(yaw_true, abs=1e-12)
    loc.step(0.5, np.array([1.0, 0.0, 0.0]), yaw_true + offset, np.zeros(3))
    np.testing.assert_allclose(
        loc.p_hat_ned, [0.5 * math.cos(yaw_true), 0.5 * math.sin(yaw_true), -2.0], atol=1e-12
    )


def test_local_gradient_rejects_mismatched_inputs() -> None:
    with pytest.raises(ValueError):
        local_angle_gradient(np.zeros(3), np.ones((2, 3)), np.ones((3, 3)) / math.sqrt(3))


def test_vertical_term_gradient_matches_finite_differences() -> None:
    rng = np.random.default_rng(8)
    p_loc = rng.uniform(-3.0, 3.0, (4, 3))
    beta = rng.normal(size=(3, 3))
    beta /= np.linalg.norm(beta, axis=1, keepdims=True)
    value, grad = local_vertical_gradient(p_loc[0], p_loc[1:], beta, 2.5)
    assert value > 0.0
    h = 1e-6
    fd = np.zeros_like(p_loc)
    for k in range(p_loc.size):
        e = np.zeros(p_loc.size)
        e[k] = h
        up, dn = (p_loc + e.reshape(4, 3)), (p_loc - e.reshape(4, 3))
        fd.flat[k] = (
            local_vertical_gradient(up[0], up[1:], beta, 2.5)[0]
            - local_vertical_gradient(dn[0], dn[1:], beta, 2.5)[0]
        ) / (2 * h)
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-8)


def test_vertical_term_vanishes_on_the_truth_and_pins_tilt() -> None:
    p = _framework(9)
    yaw = np.zeros(6)
    edges = np.array([(0, j) for j in range(1, 6)])
    beta, _ = bearings_body(p, yaw, edges)
    assert local_vertical_gradient(p[0], p[1:], beta)[0] == pytest.approx(0.0, abs=1e-20)
    tilt = np.array([[1.0, 0.0, 0.0], [0.0, 0.96, -0.28], [0.0, 0.28, 0.96]])  # about north
    pt = p @ tilt.T
    # angles cannot see the tilt, the vertical term can
    assert local_angle_gradient(pt[0], pt[1:], beta)[0] == pytest.approx(0.0, abs=1e-20)
    assert local_vertical_gradient(pt[0], pt[1:], beta)[0] > 1e-3
