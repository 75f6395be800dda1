"""Geometry: SO(3) exp/log round trips (also near 0 and pi), bearings and relative yaw."""

import numpy as np
import pytest

from onboard.geometry import (
    bearings_body,
    bearings_world,
    hat,
    projector,
    relative_yaw,
    rot_z,
    so3_distance,
    so3_exp,
    so3_log,
    vee,
    wrap_angle,
)


def test_hat_is_cross_product_and_vee_inverts_it():
    rng = np.random.default_rng(0)
    v, w = rng.normal(size=(2, 10, 3))
    assert np.allclose(hat(v) @ w[..., None], np.cross(v, w)[..., None])
    assert np.allclose(vee(hat(v)), v)


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-5, 0.3, 2.0, np.pi - 1e-2, np.pi - 1e-6, np.pi])
def test_exp_log_round_trip(angle):
    rng = np.random.default_rng(1)
    axis = rng.normal(size=(5, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    w = angle * axis
    r = so3_exp(w)
    assert np.allclose(r @ np.swapaxes(r, -1, -2), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(r), 1.0)
    assert np.allclose(so3_exp(so3_log(r)), r, atol=1e-9)
    if angle < np.pi - 1e-3:
        assert np.allclose(so3_log(r), w, atol=1e-9)


def test_exp_matches_scipy():
    from scipy.spatial.transform import Rotation

    w = np.random.default_rng(2).normal(size=(20, 3))
    assert np.allclose(so3_exp(w), Rotation.from_rotvec(w).as_matrix(), atol=1e-12)


def test_distance_is_angle_between_rotations():
    r1 = so3_exp([0.1, -0.2, 0.3])
    r2 = r1 @ so3_exp([0.0, 0.0, 0.7])
    assert so3_distance(r1, r2) == pytest.approx(0.7)
    assert so3_distance(r1, r1) == pytest.approx(0.0, abs=1e-12)


def test_rot_z_is_ned_yaw():
    # +90 deg yaw in NED points the nose (body x) east (world y).
    assert np.allclose(rot_z(np.pi / 2) @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    assert np.allclose(rot_z(0.4), so3_exp([0.0, 0.0, 0.4]))


def test_bearings_and_projector():
    p = np.array([[0.0, 0.0, 0.0], [3.0, 4.0, 0.0], [0.0, 0.0, -2.0]])
    edges = np.array([[0, 1], [0, 2], [1, 0]])
    b, d = bearings_world(p, edges)
    assert np.allclose(d, [5.0, 2.0, 5.0])
    assert np.allclose(b[0], [0.6, 0.8, 0.0])
    pr = projector(b)
    assert np.allclose(pr @ b[..., None], 0.0)
    yaw = np.array([np.pi / 2, 0.0, 0.0])
    beta, _ = bearings_body(p, yaw, edges)
    # Agent 0 faces east: north appears on its left (-y body), east straight ahead.
    assert np.allclose(beta[0], [0.8, -0.6, 0.0])


def test_relative_yaw_exact_on_noiseless_pairs():
    rng = np.random.default_rng(3)
    for _ in range(50):
        p = rng.normal(size=(2, 3)) * 5
        yaw = rng.uniform(-np.pi, np.pi, size=2)
        beta, _ = bearings_body(p, yaw, np.array([[0, 1], [1, 0]]))
        est = relative_yaw(beta[0], beta[1])
        assert abs(wrap_angle(est - (yaw[1] - yaw[0]))) < 1e-12
