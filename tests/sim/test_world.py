"""The kinematic world: lag, limits, frames, hold laws, ground, observations, layouts."""

from __future__ import annotations

import math

import numpy as np
import pytest

from onboard.geometry import rot_z
from sim.world import (
    GRAVITY_MPS2,
    DynamicsConfig,
    SensorNoise,
    World,
    formation_layout,
    grid_layout,
    observe,
    random_layout,
)

AIR = np.array([[0.0, 0.0, -10.0]])


def _run(w: World, seconds: float, dt: float = 0.002) -> None:
    for _ in range(round(seconds / dt)):
        w.step(dt)


def test_first_order_lag_time_constant():
    w = World(AIR, [0.0], DynamicsConfig(tau_v_s=0.3, accel_max_m_s2=100.0))
    w.command_velocity(0, (0.5, 0.0, 0.0), body=False)
    _run(w, 0.3)
    assert w.v_ned[0, 0] == pytest.approx(0.5 * (1.0 - math.exp(-1.0)), rel=0.01)
    _run(w, 3.0)
    assert w.v_ned[0, 0] == pytest.approx(0.5, abs=1e-4)


def test_acceleration_limit_holds_every_step():
    cfg = DynamicsConfig(accel_max_m_s2=2.0)
    w = World(AIR, [0.0], cfg)
    w.command_velocity(0, (8.0, -6.0, 0.0), body=False)
    dt = 0.01
    v_prev = w.v_ned.copy()
    for _ in range(700):  # 10 m/s at 2 m/s^2: 5 s, then the lag
        w.step(dt)
        assert np.linalg.norm(w.v_ned - v_prev) / dt <= 2.0 + 1e-9
        v_prev = w.v_ned.copy()
    assert np.linalg.norm(w.v_ned[0, :2]) == pytest.approx(10.0, abs=0.05)


def test_speed_and_yaw_rate_limits():
    cfg = DynamicsConfig(v_max_xy_m_s=3.0, yaw_rate_max_rad_s=0.5)
    w = World(AIR, [0.0], cfg)
    w.command_velocity(0, (10.0, 0.0, -10.0), body=False)
    w.command_yaw_rate(0, 5.0)
    _run(w, 5.0, dt=0.01)
    assert w.v_ned[0, 0] == pytest.approx(3.0, abs=1e-3)
    assert w.v_ned[0, 2] == pytest.approx(-cfg.v_max_up_m_s, abs=1e-3)
    assert w.yaw_rate_rad_s[0] == pytest.approx(0.5, abs=1e-4)


def test_body_command_is_rotated_by_the_current_yaw():
    w = World(AIR, [math.pi / 2], DynamicsConfig(accel_max_m_s2=100.0))
    w.command_velocity(0, (1.0, 0.0, 0.0), body=True)
    _run(w, 3.0, dt=0.01)
    np.testing.assert_allclose(w.v_ned[0], [0.0, 1.0, 0.0], atol=1e-4)  # nose east


def test_body_velocity_with_yaw_rate_flies_a_circle():
    u, r = 2.0, 0.5
    w = World(
        AIR,
        [0.0],
        DynamicsConfig(
            tau_v_s=0.05, tau_yaw_s=0.05, accel_max_m_s2=100.0, yaw_acc_max_rad_s2=100.0
        ),
    )
    w.command_velocity(0, (u, 0.0, 0.0), body=True)
    w.command_yaw_rate(0, r)
    _run(w, 2.0)
    pts = []
    for _ in range(60):
        _run(w, 0.2)
        pts.append(w.p_ned[0, :2].copy())
        # velocity is along the nose
        np.testing.assert_allclose(w.v_ned[0], rot_z(w.yaw_rad[0]) @ [u, 0.0, 0.0], atol=0.12)
    pts = np.array(pts)
    # algebraic circle fit: x^2 + y^2 = 2 a x + 2 b y + c
    sol = np.linalg.lstsq(np.c_[2 * pts, np.ones(len(pts))], np.sum(pts**2, axis=1), rcond=None)[0]
    radius = np.linalg.norm(pts - sol[:2], axis=1)
    assert radius == pytest.approx(np.full(len(pts), u / r), rel=0.02)


def test_vectorized_equals_one_by_one():
    p = np.array([[0.0, 0.0, -5.0], [10.0, 0.0, -3.0], [0.0, 7.0, 0.0]])
    yaw = np.array([0.3, -1.0, 2.0])
    cmds = [
        ((1.0, 0.5, -0.2), True, 0.3),
        ((0.0, -2.0, 0.5), False, -0.4),
        ((3.0, 0.0, -1.0), True, 0.0),
    ]
    together = World(p, yaw)
    singles = [World(p[i : i + 1], yaw[i : i + 1]) for i in range(3)]
    for i, (v, body, r) in enumerate(cmds):
        together.command_velocity(i, v, body)
        together.command_yaw_rate(i, r)
        singles[i].command_velocity(0, v, body)
        singles[i].command_yaw_rate(0, r)
    together.command_hold(2, (5.0, 5.0, -4.0))
    singles[2].command_hold(0, (5.0, 5.0, -4.0))
    for _ in range(200):
        together.step(0.01)
        for s in singles:
            s.step(0.01)
    for i in range(3):
        np.testing.assert_allclose(together.p_ned[i], singles[i].p_ned[0], atol=1e-12)
        assert together.yaw_rad[i] == pytest.approx(singles[i].yaw_rad[0], abs=1e-12)


def test_hold_law_limits_and_converges():
    cfg = DynamicsConfig()
    w = World(np.zeros((1, 3)), [0.0], cfg)
    w.command_hold(0, (20.0, 0.0, -3.0))
    max_xy, max_up = 0.0, 0.0
    for _ in range(3000):
        w.step(0.01)
        max_xy = max(max_xy, float(np.linalg.norm(w.v_ned[0, :2])))
        max_up = max(max_up, float(-w.v_ned[0, 2]))
    assert max_xy <= cfg.hold_max_xy_m_s + 1e-9 and max_xy > 0.9 * cfg.hold_max_xy_m_s
    assert max_up <= cfg.hold_max_up_m_s + 1e-9
    np.testing.assert_allclose(w.p_ned[0], [20.0, 0.0, -3.0], atol=1e-3)


def test_yaw_hold_takes_the_short_way():
    w = World(AIR, [math.radians(170.0)])
    w.command_yaw(0, math.radians(-170.0))
    w.step(0.01)
    w.step(0.01)
    assert w.yaw_rate_rad_s[0] > 0.0  # turns through 180, not back through 0
    _run(w, 6.0, dt=0.01)
    assert abs((w.yaw_rad[0] - math.radians(-170.0) + math.pi) % (2 * math.pi) - math.pi) < 1e-3


def test_ground_contact():
    w = World(np.array([[0.0, 0.0, -1.0]]), [0.0])
    w.command_velocity(0, (1.0, 0.0, 1.5), body=False)
    _run(w, 3.0, dt=0.01)
    assert w.p_ned[0, 2] == 0.0  # never below the ground
    assert w.v_ned[0, 2] == 0.0
    x = w.p_ned[0, 0]
    _run(w, 1.0, dt=0.01)
    assert w.p_ned[0, 0] == x  # no sliding on the ground
    with pytest.raises(ValueError):
        World(np.array([[0.0, np.nan, 0.0]]), [0.0])


def test_observation_exact_without_noise_and_tilt_physics():
    w = World(AIR, [math.pi / 2], DynamicsConfig(accel_max_m_s2=2.0))
    w.command_velocity(0, (5.0, 0.0, 0.0), body=True)  # accelerate forward (east)
    w.step(0.01)
    o = observe(w, SensorNoise(), np.random.default_rng(0))
    np.testing.assert_array_equal(o.p_ned, w.p_ned)
    np.testing.assert_array_equal(o.v_ned, w.v_ned)
    assert o.pitch_rad[0] == pytest.approx(
        -math.atan2(2.0 + 0.3 * w.v_ned[0, 1], GRAVITY_MPS2), abs=1e-9
    )
    assert o.roll_rad[0] == pytest.approx(0.0, abs=1e-12)
    # hovering in a 5 m/s wind blowing towards the north: lean into it (nose up when facing north)
    h = World(AIR, [0.0])
    o = observe(h, SensorNoise(wind_ned_m_s=(5.0, 0.0, 0.0)), np.random.default_rng(0))
    assert o.pitch_rad[0] == pytest.approx(math.atan2(0.3 * 5.0, GRAVITY_MPS2))


def test_noise_is_seeded():
    w = World(np.zeros((4, 3)), np.zeros(4))
    noise = SensorNoise(velocity_std_m_s=0.1, attitude_std_rad=0.01, seed=3)
    a = observe(w, noise, np.random.default_rng(3))
    b = observe(w, noise, np.random.default_rng(3))
    c = observe(w, noise, np.random.default_rng(4))
    np.testing.assert_array_equal(a.v_ned, b.v_ned)
    assert not np.array_equal(a.v_ned, c.v_ned)
    assert 0.0 < np.std(a.v_ned) < 0.3


def test_layouts(tmp_path):
    p, yaw = grid_layout(5, 4.0)
    assert p.shape == (5, 3) and np.all(p[:, 2] == 0.0) and np.all(yaw == 0.0)
    d = np.linalg.norm(p[:, None] - p[None], axis=-1) + np.eye(5) * 99
    assert d.min() == pytest.approx(4.0)
    a, ya = random_layout(6, (10.0, 10.0), seed=1, min_separation_m=2.0)
    b, yb = random_layout(6, (10.0, 10.0), seed=1, min_separation_m=2.0)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(ya, yb)
    assert not np.array_equal(a, random_layout(6, (10.0, 10.0), seed=2)[0])
    d = np.linalg.norm(a[:, None] - a[None], axis=-1) + np.eye(6) * 99
    assert d.min() >= 2.0 and a[:, :2].min() >= 0.0 and a[:, :2].max() <= 10.0
    with pytest.raises(ValueError):
        random_layout(50, (1.0, 1.0), min_separation_m=1.0)
    f = tmp_path / "f.toml"
    f.write_text(
        "[[agent]]\nid = 2\nposition_ned = [1.0, 2.0, -3.0]\nyaw_deg = 90\n"
        "[[agent]]\nid = 1\nposition_ned = [0.0, 0.0, -3.0]\n"
    )
    p, yaw, ids = formation_layout(f)
    assert ids == [1, 2]
    np.testing.assert_allclose(p[1], [1.0, 2.0, -3.0])
    assert yaw[1] == pytest.approx(math.pi / 2)
    bad = tmp_path / "bad.toml"
    bad.write_text("[[agent]]\nid = 1\n")
    with pytest.raises(ValueError):
        formation_layout(bad)
    with pytest.raises(ValueError):
        grid_layout(0)
