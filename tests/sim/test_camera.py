"""The virtual camera: exact geometry, field of view, range, noise, dropout, publishing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from messages.codec import decode
from messages.sim import CameraBearings, Truth
from sim.camera import CameraConfig, CameraPublisher, perturb_bearings, visible_bearings
from sim.world import World


def test_bearings_match_geometry_exactly():
    rng = np.random.default_rng(0)
    p = rng.uniform(-10.0, 10.0, size=(6, 3))
    yaw = rng.uniform(-math.pi, math.pi, size=6)
    edges, beta, d = visible_bearings(p, yaw, 360.0, 1e3)
    assert len(edges) == 30  # everyone sees everyone
    for (i, j), b, dist in zip(edges, beta, d, strict=True):
        # independent computation: rotate the world difference by -yaw_i by hand
        r = p[j] - p[i]
        c, s = math.cos(yaw[i]), math.sin(yaw[i])
        expected = np.array([c * r[0] + s * r[1], -s * r[0] + c * r[1], r[2]]) / np.linalg.norm(r)
        np.testing.assert_allclose(b, expected, atol=1e-12)
        assert dist == pytest.approx(np.linalg.norm(r))


def test_field_of_view_and_range():
    # vehicle 0 at the origin facing east (yaw 90 deg), 90 deg cone, 10 m range
    p = np.array(
        [
            [0.0, 0.0, 0.0],
            [0.0, 5.0, 0.0],  # ahead: seen
            [5.0, 5.2, 0.0],  # atan(5 / 5.2) = 43.9 deg off the axis: seen
            [5.0, 4.8, 0.0],  # atan(5 / 4.8) = 46.2 deg: not seen
            [0.0, 10.5, 0.0],  # ahead but beyond 10 m: not seen
            [0.0, -5.0, 0.0],  # behind: not seen
        ]
    )
    yaw = np.array([math.pi / 2, 0.0, 0.0, 0.0, 0.0, 0.0])
    edges, beta, _ = visible_bearings(p, yaw, 90.0, 10.0)
    seen_by_0 = sorted(int(j) for i, j in edges if i == 0)
    assert seen_by_0 == [1, 2]
    np.testing.assert_allclose(
        beta[(edges[:, 0] == 0) & (edges[:, 1] == 1)][0], [1.0, 0.0, 0.0], atol=1e-12
    )
    assert np.all(beta[:, 0] >= math.cos(math.radians(45.0)) - 1e-12)


def test_noise_and_dropout_statistics_are_seeded():
    beta = np.tile([1.0, 0.0, 0.0], (4000, 1))
    keep, noisy = perturb_bearings(beta, 0.01, 0.25, np.random.default_rng(7))
    keep2, noisy2 = perturb_bearings(beta, 0.01, 0.25, np.random.default_rng(7))
    np.testing.assert_array_equal(noisy, noisy2)
    np.testing.assert_array_equal(keep, keep2)
    np.testing.assert_allclose(np.linalg.norm(noisy, axis=1), 1.0, atol=1e-12)
    angles = np.arccos(np.clip(noisy[:, 0], -1.0, 1.0))
    # angle of a 2-D Gaussian tilt: Rayleigh with sigma = 0.01, mean sigma * sqrt(pi / 2)
    assert angles.mean() == pytest.approx(0.01 * math.sqrt(math.pi / 2), rel=0.05)
    assert keep.mean() == pytest.approx(0.75, abs=0.03)
    k, exact = perturb_bearings(beta, 0.0, 0.0, np.random.default_rng(0))
    assert k.all() and np.array_equal(exact, beta)


def test_publisher_rate_payloads_and_truth():
    w = World(np.array([[0.0, 0.0, -5.0], [4.0, 0.0, -5.0], [0.0, 4.0, -5.0]]), [0.0, math.pi, 0.0])
    got: list[tuple[str, bytes]] = []
    pub = CameraPublisher(
        CameraConfig(rate_hz=30.0), "alpha", lambda k, b: got.append((k, b)), ids=[1, 2, 3]
    )
    dt = 0.01
    for _ in range(100):
        w.step(dt)
        pub(w.t_s, w)
    frames = pub.seq
    assert frames == pytest.approx(30, abs=1)  # 30 Hz of simulation time
    assert len(got) == frames * 6  # bearings + truth per vehicle
    by_key: dict[str, list[bytes]] = {}
    for k, b in got:
        by_key.setdefault(k, []).append(b)
    m = decode(by_key["bf/alpha/1/camera/bearings"][-1], CameraBearings)
    assert m.sender == 1 and m.targets == [2]  # 3 is 90 deg off vehicle 1's axis
    np.testing.assert_allclose(m.beta_body[0], [1.0, 0.0, 0.0], atol=1e-12)
    m2 = decode(by_key["bf/alpha/2/camera/bearings"][-1], CameraBearings)
    assert m2.targets == [1]
    truth = decode(by_key["bf/alpha/3/truth"][-1], Truth)
    assert truth.p_ned == pytest.approx((0.0, 4.0, -5.0)) and truth.sender == 3


def test_bad_camera_config():
    for kwargs in ({"fov_deg": 0.0}, {"range_m": -1.0}, {"dropout": 1.5}, {"rate_hz": 0.0}):
        with pytest.raises(ValueError):
            CameraConfig(**kwargs)


def test_unsynchronized_cameras_keep_their_rate_at_their_own_phase():
    """With ``unsynchronized`` each vehicle's frames come at the camera rate at its own phase
    (seeded): the stamps of two vehicles differ, and the same seed gives the same phases."""

    def stamps(seed: int) -> dict[str, list[float]]:
        w = World(np.array([[0.0, 0.0, -5.0], [4.0, 0.0, -5.0], [0.0, 4.0, -5.0]]), [0.0] * 3)
        got: dict[str, list[float]] = {}
        cfg = CameraConfig(rate_hz=30.0, seed=seed, unsynchronized=True)
        pub = CameraPublisher(cfg, "alpha", lambda k, b: got.setdefault(k, []).append(b))
        for _ in range(300):
            w.step(0.01)
            pub(w.t_s, w)
        return {
            k: [decode(b, CameraBearings).stamp_s for b in v]
            for k, v in got.items()
            if k.endswith("camera/bearings")
        }

    s = stamps(5)
    assert len(s) == 3
    for v in s.values():
        assert len(v) == pytest.approx(90, abs=2)  # 30 Hz of 3 s
        assert np.all(np.diff(v) > 0.0)
    firsts = sorted(v[0] for v in s.values())
    assert firsts[-1] - firsts[0] > 0.005  # not one shutter for the team
    assert stamps(5) == s
