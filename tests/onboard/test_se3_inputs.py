"""The SE(3) EKF's inputs from a tilted multicopter (onboard/estimation/se3_inputs.py):
attitude representations, levelling, the Euler yaw rate, their Jacobians against finite
differences, the noise they carry, the attitude buffer and its bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from onboard.estimation import se3_inputs as si
from onboard.geometry import so3_exp, so3_log
from onboard.vision.camera import BODY_FROM_CAM_FORWARD, rot_rpy

RNG = np.random.default_rng(26)


def _random_attitudes(k: int) -> list[tuple[float, float, float]]:
    lim = math.radians(30.0)
    return [
        (RNG.uniform(-lim, lim), RNG.uniform(-lim, lim), RNG.uniform(-math.pi, math.pi))
        for _ in range(k)
    ]


def _quaternion(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """``q_z(yaw) q_y(pitch) q_x(roll)``, Hamilton product written out (independent of the
    module's matrix formula)."""

    def mul(a, b):
        w1, x1, y1, z1 = a
        w2, x2, y2, z2 = b
        return np.array(
            [
                w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
            ]
        )

    qx = np.array([math.cos(roll / 2), math.sin(roll / 2), 0, 0])
    qy = np.array([math.cos(pitch / 2), 0, math.sin(pitch / 2), 0])
    qz = np.array([math.cos(yaw / 2), 0, 0, math.sin(yaw / 2)])
    return mul(qz, mul(qy, qx))


def test_euler_and_quaternion_give_mavlinks_zyx_attitude():
    for roll, pitch, yaw in _random_attitudes(20):
        r = si.rotation_from_euler(roll, pitch, yaw)
        np.testing.assert_allclose(r, rot_rpy(roll, pitch, yaw), atol=1e-12)
        np.testing.assert_allclose(
            si.rotation_from_quaternion(_quaternion(roll, pitch, yaw)), r, atol=1e-12
        )
        np.testing.assert_allclose(si.euler_from_rotation(r), (roll, pitch, yaw), atol=1e-12)
    # a yaw of 90 degrees turns the nose east: body x -> NED y
    q = (math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4))
    np.testing.assert_allclose(si.rotation_from_quaternion(q) @ [1, 0, 0], [0, 1, 0], atol=1e-12)


@pytest.mark.parametrize(
    ("q", "word"),
    [
        ((1.0, 0.0, 0.0, float("nan")), "nonfinite_attitude"),
        ((1.0, 0.0, 0.0), "nonfinite_attitude"),
        ((1.02, 0.0, 0.0, 0.0), "non_unit_quaternion"),
        ((0.5, 0.5, 0.5, 0.5 * 0.99), "non_unit_quaternion"),
        ((0.0, 0.0, 0.0, 0.0), "non_unit_quaternion"),
        (tuple(_quaternion(math.radians(85.0), 0.0, 0.0)), "attitude_out_of_range"),
    ],
)
def test_bad_quaternions_name_their_counter(q, word):
    with pytest.raises(si.BadAttitude) as err:
        si.rotation_from_quaternion(q)
    assert err.value.word == word


def test_nearly_unit_quaternion_is_normalized_and_bad_euler_angles_name_their_counter():
    q = _quaternion(0.1, -0.2, 0.3) * (1.0 + 5e-4)
    r = si.rotation_from_quaternion(q)
    np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
    for angles, word in (
        ((float("nan"), 0.0, 0.0), "nonfinite_attitude"),
        ((0.0, float("inf"), 0.0), "nonfinite_attitude"),
        ((0.0, math.radians(89.0), 0.0), "attitude_out_of_range"),
    ):
        with pytest.raises(si.BadAttitude) as err:
            si.rotation_from_euler(*angles)
        assert err.value.word == word


def test_levelling_gives_the_heading_frame_bearing_of_body_and_camera_bearings():
    for roll, pitch, yaw in _random_attitudes(10):
        r = rot_rpy(roll, pitch, yaw)
        b_world = RNG.normal(size=3)
        b_world /= np.linalg.norm(b_world)
        beta_body = r.T @ b_world
        rz = rot_rpy(0.0, 0.0, yaw)
        np.testing.assert_allclose(si.level(beta_body, roll, pitch), rz.T @ b_world, atol=1e-12)
        beta_cam = BODY_FROM_CAM_FORWARD.T @ beta_body
        np.testing.assert_allclose(
            si.level(beta_cam, roll, pitch, BODY_FROM_CAM_FORWARD), rz.T @ b_world, atol=1e-12
        )


def _central_jacobian(f, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    cols = []
    for c in range(len(x)):
        d = np.zeros(len(x))
        d[c] = h
        cols.append((np.atleast_1d(f(x + d)) - np.atleast_1d(f(x - d))) / (2 * h))
    return np.column_stack(cols)


def test_level_jacobian_matches_finite_differences():
    for roll, pitch, _ in _random_attitudes(10):
        beta = RNG.normal(size=3)
        beta /= np.linalg.norm(beta)
        x = np.r_[beta, roll, pitch]
        num = _central_jacobian(lambda z: si.level(z[:3], z[3], z[4]), x)
        np.testing.assert_allclose(si.level_jacobian(beta, roll, pitch), num, atol=1e-8)


def test_heading_motion_jacobian_matches_finite_differences():
    for roll, pitch, _ in _random_attitudes(10):
        v, w = RNG.normal(size=3) * 2.0, RNG.normal(size=3)
        x = np.r_[v, w, roll, pitch]

        def f(z):
            vh, rate = si.heading_motion(z[:3], z[3:6], z[6], z[7])
            return np.r_[vh, rate]

        num = _central_jacobian(f, x)
        np.testing.assert_allclose(si.heading_motion_jacobian(v, w, roll, pitch), num, atol=1e-8)


def test_euler_yaw_rate_is_the_heading_frames_rate():
    """Along ``R(t) = R_z(psi(t)) R_y(theta(t)) R_x(phi(t))``, the gyro reads ``vee(R^T Rdot)``;
    the heading frame ``R_z(psi)`` turns at ``psidot``, which the module recovers."""
    h = 1e-6
    for roll, pitch, yaw in _random_attitudes(10):
        rates = RNG.normal(size=3)

        def rot(t, roll=roll, pitch=pitch, yaw=yaw, rates=rates):
            return rot_rpy(roll + rates[0] * t, pitch + rates[1] * t, yaw + rates[2] * t)

        w_body = so3_log(rot(-h).T @ rot(h)) / (2 * h)
        assert si.euler_yaw_rate(w_body, roll, pitch) == pytest.approx(rates[2], abs=1e-6)
        _, rate = si.heading_motion(np.zeros(3), w_body, roll, pitch)
        assert rate == pytest.approx(rates[2], abs=1e-6)


def test_levelled_bearing_sigma_matches_monte_carlo_tilt_errors():
    """The tilt's error as seen in a levelled bearing: the largest tangent-plane standard
    deviation of ``level(beta, roll + e_r, pitch + e_p)`` over 20000 draws is the module's
    ``sigma`` (with no bearing noise) within 5%; bearing noise adds in quadrature."""
    roll, pitch, sig_t = math.radians(12.0), math.radians(-9.0), math.radians(0.5)
    beta = np.array([0.6, -0.3, 0.2])
    beta /= np.linalg.norm(beta)
    ref = si.level(beta, roll, pitch)
    e = RNG.normal(scale=sig_t, size=(20000, 2))
    errs = np.array([si.level(beta, roll + a, pitch + b) - ref for a, b in e])
    errs -= np.outer(errs @ ref, ref)
    worst = math.sqrt(np.linalg.eigvalsh(np.cov(errs.T))[-1])
    assert si.levelled_bearing_sigma_rad(beta, roll, pitch, 0.0, sig_t) == pytest.approx(
        worst, rel=0.05
    )
    both = si.levelled_bearing_sigma_rad(beta, roll, pitch, math.radians(1.0), sig_t)
    assert both == pytest.approx(math.hypot(math.radians(1.0), worst), rel=0.05)


def test_heading_motion_sigmas_match_monte_carlo():
    roll, pitch, sig_t = math.radians(10.0), math.radians(14.0), math.radians(0.5)
    v, w = np.array([2.0, -1.0, 0.3]), np.array([0.2, 0.5, -0.4])
    sv, sw = 0.05, 0.01
    draws = []
    for _ in range(20000):
        vh, rate = si.heading_motion(
            v + RNG.normal(scale=sv, size=3),
            w + RNG.normal(scale=sw, size=3),
            roll + RNG.normal(scale=sig_t),
            pitch + RNG.normal(scale=sig_t),
        )
        draws.append(np.r_[vh, rate])
    cov = np.cov(np.array(draws).T)
    s_v, s_rate = si.heading_motion_sigmas(v, w, roll, pitch, sv, sw, sig_t)
    assert s_v == pytest.approx(math.sqrt(np.linalg.eigvalsh(cov[:3, :3])[-1]), rel=0.05)
    assert s_rate == pytest.approx(math.sqrt(cov[3, 3]), rel=0.05)
    assert s_v > sv and s_rate > sw / math.cos(pitch) * 0.999


def test_attitude_buffer_interpolates_on_so3_and_respects_gaps():
    axis = np.array([0.3, -0.5, 0.8])
    buf = si.AttitudeBuffer(max_gap_s=0.1)
    for k in range(11):
        buf.add(0.01 * k, so3_exp(axis * 0.01 * k))
    for t in (0.0, 0.0123, 0.05, 0.0999):
        np.testing.assert_allclose(buf.at(t), so3_exp(axis * t), atol=1e-12)  # geodesic: exact
    np.testing.assert_allclose(buf.at(0.15), so3_exp(axis * 0.1), atol=1e-12)  # nearest
    assert buf.at(0.25) is None and buf.at(-0.2) is None and buf.at(float("nan")) is None
    buf.add(0.5, np.eye(3))  # 0.4 s after the last: no interpolation across the gap
    assert buf.at(0.3) is None


@pytest.mark.parametrize(
    ("t", "rot", "word"),
    [
        (float("nan"), np.eye(3), "nonfinite_attitude"),
        (1.0, np.full((3, 3), np.nan), "nonfinite_attitude"),
        (1.0, np.eye(3)[:2], "nonfinite_attitude"),
        (1.0, 1.1 * np.eye(3), "not_a_rotation"),
        (1.0, np.diag([1.0, 1.0, -1.0]), "not_a_rotation"),
        (0.5, np.eye(3), "stale_attitude"),
        (0.2, np.eye(3), "stale_attitude"),
    ],
)
def test_attitude_buffer_rejects_bad_samples_by_name(t, rot, word):
    buf = si.AttitudeBuffer()
    buf.add(0.5, np.eye(3))
    with pytest.raises(si.BadAttitude) as err:
        buf.add(t, rot)
    assert err.value.word == word
    assert buf.t_s == [0.5]
