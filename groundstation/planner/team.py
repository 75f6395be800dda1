"""A team of camera vehicles and ground landmarks: paper 004's Fig. 9 experiment, simulated.

Paper 004 (docs/papers.md, Section VII, Fig. 9): 10 UAVs and 10 UGVs; every UAV flies its own
mission "at a slightly different altitude and in a different part of the environment" (median
trajectory 359.4 m, 4.17 km in all); the UGVs are placed once, for the setpoints of every UAV
(the minimax of paper eq. 7 over all of them: one planning problem whose setpoints are the
union of the missions' waypoints); each UAV fuses its odometry with bearings to the UGVs. The
metric is each UAV's drift reduction against its odometry alone, averaged over the UAVs
(71.50%, standard deviation 9.85%).

:func:`team_missions` builds the missions (seeded): the area is cut into a grid of cells, one
per UAV; each UAV flies a jittered closed loop inside its cell at its own altitude. The
per-UAV evaluation is :func:`groundstation.planner.validation.run_errors` (the UAVs do not
measure each other, as in the paper's factor graph, Fig. 6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from groundstation.planner.validation import Mission, OdometryNoise, run_errors
from onboard.geometry import FloatArray


@dataclass(frozen=True)
class TeamLayout:
    """The area and how the missions fill it (metres; NED, origin at the area's centre)."""

    n_vehicles: int = 10
    cols: int = 5
    cell_m: float = 50.0  # square cells, ``cols`` across (east) and as many rows as needed
    loop_radius_m: float = 19.0  # nominal distance of the waypoints from the cell's centre
    waypoints_per_loop: int = 6
    jitter_m: float = 4.0  # each waypoint moved by up to this much (uniform, per axis)
    altitude_m: tuple[float, float] = (8.0, 17.0)  # each vehicle's height, spread evenly
    speed_m_s: float = 6.0
    rounds: int = 3


def team_missions(layout: TeamLayout, seed: int) -> list[Mission]:
    """One closed waypoint loop per vehicle, each in its own cell and at its own altitude."""
    if layout.n_vehicles < 1 or layout.cols < 1 or layout.waypoints_per_loop < 3:
        raise ValueError("need at least one vehicle, one column and three waypoints per loop")
    if not 0.0 <= layout.jitter_m < layout.loop_radius_m < layout.cell_m / 2.0:
        raise ValueError("need 0 <= jitter_m < loop_radius_m < cell_m / 2")
    rng = np.random.default_rng(seed)
    rows = -(-layout.n_vehicles // layout.cols)
    cols = min(layout.cols, layout.n_vehicles)
    heights = np.linspace(*layout.altitude_m, layout.n_vehicles)
    angles = np.linspace(0.0, 2.0 * np.pi, layout.waypoints_per_loop, endpoint=False)
    out = []
    for i in range(layout.n_vehicles):
        r, c = divmod(i, cols)
        centre_n = (r - (rows - 1) / 2.0) * layout.cell_m
        centre_e = (c - (cols - 1) / 2.0) * layout.cell_m
        phase = rng.uniform(0.0, 2.0 * np.pi)
        ne = layout.loop_radius_m * np.column_stack(
            [np.cos(angles + phase), np.sin(angles + phase)]
        )
        ne += rng.uniform(-layout.jitter_m, layout.jitter_m, size=ne.shape)
        ne += [centre_n, centre_e]
        w = np.column_stack([ne, np.full(len(ne), -heights[i])])
        out.append(Mission(w, speed_m_s=layout.speed_m_s, rounds=layout.rounds))
    return out


def mission_length_m(mission: Mission) -> float:
    """Distance flown: the loop's perimeter times the rounds."""
    w = np.asarray(mission.waypoints_ned)
    return float(mission.rounds * np.sum(np.linalg.norm(np.roll(w, -1, axis=0) - w, axis=1)))


def team_setpoints(missions: list[Mission]) -> FloatArray:
    """The planner's setpoints: every vehicle's waypoints, ``(sum K_i, 3)``."""
    return np.vstack([np.asarray(m.waypoints_ned, dtype=float) for m in missions])


def team_drifts(
    missions: list[Mission],
    landmarks_ned: ArrayLike,
    sigma_m: float,
    noise: OdometryNoise,
    seed: int | tuple[int, ...],
    detection_range_m: float | None = None,
) -> FloatArray:
    """Each vehicle's final position error (drift, m), ``(n_vehicles,)``.

    Vehicle ``i`` gets the noise stream ``(*seed, i)``: the same odometry for any landmarks.
    """
    base = tuple(np.atleast_1d(np.asarray(seed, dtype=np.int64)).tolist())
    return np.array(
        [
            run_errors(
                m, landmarks_ned, sigma_m, noise, (*base, i), detection_range_m=detection_range_m
            ).final_m
            for i, m in enumerate(missions)
        ]
    )


def drift_reduction(drift_m: ArrayLike, baseline_m: ArrayLike) -> FloatArray:
    """Per-vehicle ``1 - drift / baseline`` (paper 004 Fig. 8-9 "Drift Red.")."""
    d, b = np.asarray(drift_m, dtype=float), np.asarray(baseline_m, dtype=float)
    if d.shape != b.shape or not np.all(b > 0):
        raise ValueError("need matching shapes and positive baseline drifts")
    return 1.0 - d / b
