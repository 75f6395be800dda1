"""EKF validation of a placement (paper 004 Section VII in miniature): flight, sensors, filter."""

from __future__ import annotations

import numpy as np
import pytest

from groundstation.planner.validation import (
    Mission,
    OdometryNoise,
    best_view_headings,
    ekf_track,
    fly_mission,
    in_view,
    predicted_reductions,
    random_landmarks_in_hull,
    run_errors,
    simulate_bearings,
    simulate_odometry,
)

SQUARE = np.array(
    [[-20.0, -20.0, -10.0], [20.0, -20.0, -10.0], [20.0, 20.0, -10.0], [-20.0, 20.0, -10.0]]
)
LANDMARKS = np.array([[0.0, -8.0, 0.0], [-6.0, 10.0, 0.0], [9.0, 4.0, 0.0]])


def test_flight_passes_every_waypoint_at_a_keyframe() -> None:
    mission = Mission(SQUARE, speed_m_s=5.0, rounds=2)
    flight = fly_mission(mission)
    assert len(flight.keyframes) == 2 * len(SQUARE)
    step = np.linalg.norm(np.diff(flight.p_ned, axis=0), axis=1)
    np.testing.assert_allclose(step, 0.5, atol=1e-9)  # constant speed, corners included
    at_keyframes = flight.p_ned[flight.keyframes]
    expected = np.vstack([SQUARE[1:], SQUARE[:1]] * 2)
    np.testing.assert_allclose(at_keyframes, expected, atol=0.25 + 1e-9)


def test_filter_is_exact_without_noise() -> None:
    """No odometry error, exact bearings, exact start: the estimate is the true path."""
    mission = Mission(SQUARE, speed_m_s=5.0, rounds=1)
    flight = fly_mission(mission)
    quiet = OdometryNoise(bias0_m_s=0.0, bias_walk_mps_per_sqrt_s=0.0, white_m_s=0.0)
    rng = np.random.default_rng(0)
    v = simulate_odometry(flight, quiet, rng)
    y = simulate_bearings(flight, LANDMARKS, 0.0, rng)
    est = ekf_track(
        v, flight.dt_s, flight.keyframes, y, LANDMARKS, 0.05, quiet, flight.p_ned[0], 1.0
    )
    np.testing.assert_allclose(est, flight.p_ned, atol=1e-9)


def test_bearings_correct_drift() -> None:
    """Over seeded runs the end error with landmarks is well below dead reckoning's."""
    mission = Mission(SQUARE, speed_m_s=5.0, rounds=3)
    noise = OdometryNoise(bias0_m_s=0.1)
    with_lm = [run_errors(mission, LANDMARKS, 0.05, noise, seed=s).final_m for s in range(6)]
    without = [run_errors(mission, np.zeros((0, 3)), 0.05, noise, seed=s).final_m for s in range(6)]
    assert np.mean(with_lm) < 0.5 * np.mean(without)


def test_runs_are_seeded() -> None:
    mission = Mission(SQUARE, speed_m_s=5.0, rounds=1)
    a = run_errors(mission, LANDMARKS, 0.1, OdometryNoise(), seed=(3, 1))
    b = run_errors(mission, LANDMARKS, 0.1, OdometryNoise(), seed=(3, 1))
    c = run_errors(mission, LANDMARKS, 0.1, OdometryNoise(), seed=(3, 2))
    assert (a.final_m, a.mean_m) == (b.final_m, b.mean_m)
    np.testing.assert_array_equal(a.series_m, b.series_m)
    assert a.final_m != c.final_m
    flight = fly_mission(mission)
    assert a.series_m.shape == (len(flight.p_ned),)
    assert a.series_m[-1] == a.final_m
    assert a.mean_m == pytest.approx(np.mean(a.series_m))


def test_random_landmarks_lie_in_the_hull_on_the_ground() -> None:
    pts = random_landmarks_in_hull(SQUARE, 50, 0.0, 5.0, np.random.default_rng(4))
    assert pts.shape == (50, 3)
    np.testing.assert_array_equal(pts[:, 2], 0.0)
    assert np.all(np.abs(pts[:, :2]) <= 20.0)
    again = random_landmarks_in_hull(SQUARE, 50, 0.0, 5.0, np.random.default_rng(4))
    np.testing.assert_array_equal(pts, again)
    d = np.linalg.norm(pts[:, None, :] - SQUARE[None], axis=-1)
    assert np.all(d >= 5.0)


def test_collinear_waypoints_enclose_no_region() -> None:
    line = np.array([[0.0, 0.0, -5.0], [10.0, 0.0, -5.0], [20.0, 0.0, -5.0]])
    with pytest.raises(ValueError, match="enclose no area"):
        random_landmarks_in_hull(line, 2, 0.0, 1.0, np.random.default_rng(0))


def test_camera_cone_and_best_heading() -> None:
    p = np.zeros((1, 3))
    angles = np.radians([0.0, 44.0, 46.0, 180.0])
    z = np.stack([10.0 * np.cos(angles), 10.0 * np.sin(angles), np.zeros(4)], axis=-1)
    seen = in_view(p, [0.0], z, np.radians(90.0))
    np.testing.assert_array_equal(seen, [[True, True, False, False]])
    east = np.array([[2.0, 10.0, 0.0], [-2.0, 12.0, 0.0], [0.0, -30.0, 0.0]])
    yaw = best_view_headings(p, east, np.radians(60.0))
    assert abs(yaw[0] - np.pi / 2.0) <= np.radians(10.0)
    assert in_view(p, yaw, east, np.radians(60.0)).sum() == 2


def test_landmarks_outside_the_view_are_not_used() -> None:
    """A camera pointed away from every landmark is dead reckoning, bit for bit."""
    mission = Mission(SQUARE, speed_m_s=5.0, rounds=1)
    away = np.full(len(SQUARE), np.pi)  # facing south; the landmark is 200 m north
    far = np.array([[200.0, 0.0, 0.0]])
    blind = run_errors(mission, far, 0.1, OdometryNoise(), (5,), headings_rad=away, fov_rad=1.0)
    none = run_errors(mission, np.zeros((0, 3)), 0.1, OdometryNoise(), (5,))
    np.testing.assert_array_equal(blind.series_m, none.series_m)
    short = run_errors(mission, far, 0.1, OdometryNoise(), (5,), detection_range_m=150.0)
    np.testing.assert_array_equal(short.series_m, none.series_m)
    seen = run_errors(mission, far, 0.1, OdometryNoise(), (5,), detection_range_m=250.0)
    assert not np.array_equal(seen.series_m, none.series_m)
    with pytest.raises(ValueError, match="heading"):
        run_errors(mission, far, 0.1, OdometryNoise(), (5,), fov_rad=1.0)


def test_predicted_reductions_separate_the_worst_setpoint_from_the_typical_one() -> None:
    # Planned: both setpoints at trace 1. Random draws: one setpoint at 4 (badly seen), one at
    # 0.25, then both at 1. By hand: worst 1 - 1/2.5, mean trace 1 - 1/1.5625, mean radius
    # 1 - 1/1.125.
    red = predicted_reductions([1.0, 1.0], [[4.0, 0.25], [1.0, 1.0]])
    assert red.worst_trace == pytest.approx(0.6)
    assert red.mean_trace == pytest.approx(1.0 - 1.0 / 1.5625)
    assert red.mean_radius == pytest.approx(1.0 - 1.0 / 1.125)
    assert predicted_reductions([2.0, 3.0], [[2.0, 3.0]]).mean_radius == pytest.approx(0.0)
