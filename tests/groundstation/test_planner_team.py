"""The team scenario of paper 004 Fig. 9 (groundstation/planner/team.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from groundstation.planner.team import (
    TeamLayout,
    drift_reduction,
    mission_length_m,
    team_drifts,
    team_missions,
    team_setpoints,
)
from groundstation.planner.validation import OdometryNoise


def test_missions_are_seeded_one_per_cell_at_distinct_heights() -> None:
    layout = TeamLayout()
    a, b = team_missions(layout, 3), team_missions(layout, 3)
    assert len(a) == 10
    for ma, mb in zip(a, b, strict=True):
        np.testing.assert_array_equal(ma.waypoints_ned, mb.waypoints_ned)
    assert not np.array_equal(a[0].waypoints_ned, team_missions(layout, 4)[0].waypoints_ned)
    centres = np.array([m.waypoints_ned[:, :2].mean(axis=0) for m in a])
    # each loop stays inside its own 50 m cell: centres on the 5 x 2 grid, waypoints within
    # loop radius + jitter of the centre
    expected = np.array([[(r - 0.5) * 50.0, (c - 2) * 50.0] for r in range(2) for c in range(5)])
    np.testing.assert_allclose(centres, expected, atol=layout.jitter_m)
    for m, c in zip(a, expected, strict=True):
        reach = np.linalg.norm(m.waypoints_ned[:, :2] - c, axis=1)
        assert np.all(reach < layout.cell_m / 2.0)
        assert np.ptp(m.waypoints_ned[:, 2]) == 0.0  # one height per vehicle
    heights = [-m.waypoints_ned[0, 2] for m in a]
    assert len(set(heights)) == 10 and min(heights) == 8.0 and max(heights) == 17.0
    lengths = [mission_length_m(m) for m in a]
    assert 250.0 < np.median(lengths) < 450.0  # paper: median 359 m
    assert team_setpoints(a).shape == (60, 3)


def test_bad_layout_is_refused() -> None:
    with pytest.raises(ValueError, match="jitter"):
        team_missions(TeamLayout(loop_radius_m=30.0), 0)
    with pytest.raises(ValueError, match="vehicle"):
        team_missions(TeamLayout(n_vehicles=0), 0)


def test_team_drifts_same_odometry_for_any_landmarks_and_landmarks_help() -> None:
    layout = TeamLayout(n_vehicles=2, cols=2, rounds=2)
    missions = team_missions(layout, 0)
    noise = OdometryNoise()
    none = team_drifts(missions, np.zeros((0, 3)), 0.1, noise, (5, 0))
    np.testing.assert_array_equal(none, team_drifts(missions, np.zeros((0, 3)), 0.1, noise, (5, 0)))
    # a landmark pair at each cell's centre, on the ground
    centres = np.array([[*m.waypoints_ned[:, :2].mean(axis=0), 0.0] for m in missions])
    north, east = np.array([8.0, 0.0, 0.0]), np.array([0.0, 8.0, 0.0])
    landmarks = np.vstack([centres + north, centres - east])
    seen = team_drifts(missions, landmarks, 0.1, noise, (5, 0))
    assert seen.shape == (2,)
    # landmarks cut the drift of the team: summed over both vehicles and three noise seeds
    # (one vehicle's dead-reckoning drift can by chance be as small as the bearings' floor)
    with_lm = sum(team_drifts(missions, landmarks, 0.1, noise, (s, 0)).sum() for s in range(3))
    without = sum(
        team_drifts(missions, np.zeros((0, 3)), 0.1, noise, (s, 0)).sum() for s in range(3)
    )
    assert with_lm < 0.7 * without, (with_lm, without)  # measured: 0.51
    # a vehicle whose landmarks are all out of range is back to dead reckoning
    far = team_drifts(missions, landmarks, 0.1, noise, (5, 0), detection_range_m=1.0)
    np.testing.assert_allclose(far, none)
    # the bigger the odometry noise, the bigger the dead-reckoning drift on the same draws
    louder = replace(noise, white_m_s=4 * noise.white_m_s)
    assert team_drifts(missions, np.zeros((0, 3)), 0.1, louder, (5, 0)).mean() > none.mean()


def test_drift_reduction() -> None:
    np.testing.assert_allclose(drift_reduction([1.0, 3.0], [4.0, 4.0]), [0.75, 0.25])
    with pytest.raises(ValueError, match="positive"):
        drift_reduction([1.0], [0.0])
    with pytest.raises(ValueError, match="shapes"):
        drift_reduction([1.0, 2.0], [1.0])
