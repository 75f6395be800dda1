"""Validation of a landmark placement: a camera vehicle fuses bearings to it along a mission.

Paper 004 Section VII-B in miniature. A vehicle flies a closed loop of waypoints (the planner's
setpoints) several rounds at constant speed. Its odometry drifts like visual-inertial odometry:
the measured velocity carries a bias that starts random and wanders (a random walk), plus white
noise. At every waypoint (a keyframe; paper 004 Remark after Assumption 2: bearings about every
5 s, attitude known, the vehicle yaws to see every landmark) it measures the unit bearing to
each landmark with isotropic noise ``sigma_m`` per component, the model the planner uses
(eq. 1). An EKF on position and velocity bias fuses both. The drift is the position error at
the end of the mission (the paper's metric); the mean error over the mission is also reported.

The random baseline of the paper places the ground vehicles "randomly within the region
enclosed by the UAV's waypoints": :func:`random_landmarks_in_hull` draws them uniformly in the
convex hull of the waypoints' ground projection.

Truth and estimation are separate: :func:`fly_mission`, :func:`simulate_odometry` and
:func:`simulate_bearings` use the true path; :func:`ekf_track` sees only their outputs and the
landmark positions (known: the landmarks are the well-localized vehicles).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import Delaunay

from onboard.geometry import FloatArray, IntArray


@dataclass(frozen=True)
class Mission:
    """A closed loop of waypoints (NED, m) flown ``rounds`` times at ``speed_m_s``."""

    waypoints_ned: FloatArray  # (K, 3)
    speed_m_s: float
    rounds: int
    dt_s: float = 0.1


@dataclass(frozen=True)
class OdometryNoise:
    """Velocity-odometry error: bias ``b0 ~ N(0, bias0^2 I)`` wandering as a random walk.

    ``v_meas = v + b + w`` with ``w ~ N(0, white^2 I)`` per sample and ``db ~ N(0, walk^2 dt I)``.
    The defaults drift about 1.5% of the distance flown (paper 004 Fig. 8: VIO drift 19-24 m
    over 1.0-1.4 km).
    """

    bias0_m_s: float = 0.04
    bias_walk_mps_per_sqrt_s: float = 0.004
    white_m_s: float = 0.2


@dataclass(frozen=True)
class Flight:
    """True path sampled every ``dt_s`` and the samples at which a waypoint is reached."""

    p_ned: FloatArray  # (T, 3)
    keyframes: IntArray  # (K rounds,) sample indices
    waypoint_index: IntArray  # (K rounds,) the waypoint reached at each keyframe
    dt_s: float


def fly_mission(mission: Mission) -> Flight:
    """Constant-speed flight along the waypoint loop, with a keyframe at every waypoint."""
    w = np.asarray(mission.waypoints_ned, dtype=float)
    loop = np.vstack([w, w[:1]])
    seg = np.diff(loop, axis=0)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(seg, axis=1))])
    step_m = mission.speed_m_s * mission.dt_s
    n_steps = round(mission.rounds * arc[-1] / step_m)
    s = (np.arange(n_steps + 1) * step_m) % arc[-1]
    k = np.clip(np.searchsorted(arc, s, side="right") - 1, 0, len(seg) - 1)
    frac = (s - arc[k]) / (arc[k + 1] - arc[k])
    p = loop[k] + frac[:, None] * seg[k]
    arrivals = (arc[1:, None] + arc[-1] * np.arange(mission.rounds)[None, :]).T.ravel()
    keyframes = np.clip(np.round(arrivals / step_m).astype(int), 1, n_steps)
    waypoint = np.tile((np.arange(len(w)) + 1) % len(w), mission.rounds)
    return Flight(p_ned=p, keyframes=keyframes, waypoint_index=waypoint, dt_s=mission.dt_s)


def simulate_odometry(flight: Flight, noise: OdometryNoise, rng: np.random.Generator) -> FloatArray:
    """Measured velocities ``(T - 1, 3)``: true velocity + drifting bias + white noise."""
    dt = flight.dt_s
    v = np.diff(flight.p_ned, axis=0) / dt
    walk = noise.bias_walk_mps_per_sqrt_s * np.sqrt(dt) * rng.normal(size=v.shape)
    bias = noise.bias0_m_s * rng.normal(size=3) + np.cumsum(walk, axis=0)
    return v + bias + noise.white_m_s * rng.normal(size=v.shape)


def simulate_bearings(
    flight: Flight, landmarks_ned: ArrayLike, sigma_m: float, rng: np.random.Generator
) -> FloatArray:
    """Noisy unit bearings ``(K, M, 3)`` to every landmark at every keyframe (paper 004 eq. 1)."""
    z = np.asarray(landmarks_ned, dtype=float).reshape(-1, 3)
    r = z[None, :, :] - flight.p_ned[flight.keyframes][:, None, :]
    h = r / np.linalg.norm(r, axis=-1, keepdims=True)
    return h + sigma_m * rng.normal(size=h.shape)


def in_view(
    p_ned: ArrayLike, yaw_rad: ArrayLike, landmarks_ned: ArrayLike, fov_rad: float
) -> np.ndarray:
    """``(K, M)`` mask: landmark ``j`` inside the cone of full angle ``fov_rad`` around the
    level camera axis ``(cos yaw_k, sin yaw_k, 0)`` from ``p_ned[k]`` (paper 004 eq. 19)."""
    p = np.asarray(p_ned, dtype=float).reshape(-1, 3)
    yaw = np.asarray(yaw_rad, dtype=float).reshape(-1)
    z = np.asarray(landmarks_ned, dtype=float).reshape(-1, 3)
    r = z[None, :, :] - p[:, None, :]
    axis = np.stack([np.cos(yaw), np.sin(yaw), np.zeros_like(yaw)], axis=-1)
    along = np.einsum("kc,kmc->km", axis, r)
    return along >= np.cos(fov_rad / 2.0) * np.linalg.norm(r, axis=-1)


def best_view_headings(
    waypoints_ned: ArrayLike, landmarks_ned: ArrayLike, fov_rad: float, candidates: int = 72
) -> FloatArray:
    """Per waypoint, the heading (of ``candidates`` evenly spaced) that sees most landmarks.

    Ties go to the heading closest to the landmarks' mean direction. Used for placements that
    come without planned headings (the random baseline).
    """
    w = np.asarray(waypoints_ned, dtype=float).reshape(-1, 3)
    z = np.asarray(landmarks_ned, dtype=float).reshape(-1, 3)
    yaw = np.linspace(-np.pi, np.pi, candidates, endpoint=False)
    p = np.repeat(w, candidates, axis=0)
    seen = in_view(p, np.tile(yaw, len(w)), z, fov_rad).sum(axis=1).reshape(len(w), candidates)
    u = z[None, :, :2] - w[:, None, :2]
    u /= np.maximum(np.linalg.norm(u, axis=-1, keepdims=True), 1e-12)
    mean_dir = u.sum(axis=1)
    score = np.cos(yaw[None, :] - np.arctan2(mean_dir[:, 1], mean_dir[:, 0])[:, None])
    return yaw[np.argmax(seen + 0.499 * (score + 1.0), axis=1)]  # the tie-break adds < 1


def ekf_track(
    v_meas: ArrayLike,
    dt_s: float,
    keyframes: ArrayLike,
    bearings: ArrayLike,
    landmarks_ned: ArrayLike,
    sigma_m: float,
    noise: OdometryNoise,
    p0_ned: ArrayLike,
    p0_sigma_m: float,
    visible: ArrayLike | None = None,
) -> FloatArray:
    """Position estimates ``(T, 3)`` of an EKF on ``[p, b]`` (position, velocity bias).

    ``visible (K, M)`` marks the bearings actually measured (default: all).

    Prediction ``p += (v_meas - b) dt`` with the noise model of ``noise``; at ``keyframes[k]``
    the update with ``bearings[k] (M, 3)``, ``h = (z - p)/|z - p|``, ``dh/dp = -(I - h h^T)/|z - p|``
    and ``R = sigma_m^2 I`` (Joseph form). No bearings (``M = 0``) is dead reckoning.
    """
    v = np.asarray(v_meas, dtype=float)
    z = np.asarray(landmarks_ned, dtype=float).reshape(-1, 3)
    y_all = np.asarray(bearings, dtype=float).reshape(len(np.asarray(keyframes)), z.shape[0], 3)
    update_at = {int(k): i for i, k in enumerate(np.asarray(keyframes))}
    seen = (
        np.ones(y_all.shape[:2], dtype=bool)
        if visible is None
        else np.asarray(visible, dtype=bool).reshape(y_all.shape[:2])
    )
    eye3 = np.eye(3)
    f = np.block([[eye3, -dt_s * eye3], [np.zeros((3, 3)), eye3]])
    q = np.diag(
        [(noise.white_m_s * dt_s) ** 2] * 3 + [noise.bias_walk_mps_per_sqrt_s**2 * dt_s] * 3
    )
    x = np.concatenate([np.asarray(p0_ned, dtype=float), np.zeros(3)])
    cov = np.diag([p0_sigma_m**2] * 3 + [noise.bias0_m_s**2] * 3)
    out = np.empty((v.shape[0] + 1, 3))
    out[0] = x[:3]
    for k in range(1, v.shape[0] + 1):
        x = np.concatenate([x[:3] + (v[k - 1] - x[3:]) * dt_s, x[3:]])
        cov = f @ cov @ f.T + q
        if k in update_at and np.any(seen[update_at[k]]):
            mask = seen[update_at[k]]
            d = z[mask] - x[:3]
            dist = np.linalg.norm(d, axis=1)
            h = d / dist[:, None]
            jac_p = -(eye3 - h[:, :, None] * h[:, None, :]) / dist[:, None, None]
            jac = np.hstack([jac_p.reshape(-1, 3), np.zeros((3 * len(d), 3))])
            innovation = y_all[update_at[k]][mask].ravel() - h.ravel()
            r_noise = sigma_m**2 * np.eye(3 * len(d))
            gain = np.linalg.solve(jac @ cov @ jac.T + r_noise, jac @ cov).T
            x = x + gain @ innovation
            a = np.eye(6) - gain @ jac
            cov = a @ cov @ a.T + gain @ r_noise @ gain.T
        out[k] = x[:3]
    return out


def random_landmarks_in_hull(
    waypoints_ned: ArrayLike,
    n_landmarks: int,
    ground_down_m: float,
    r_min_m: float,
    rng: np.random.Generator,
    max_tries: int = 1000,
) -> FloatArray:
    """``n_landmarks`` ground points uniform in the convex hull of the waypoints' projection.

    Points closer than ``r_min_m`` to a waypoint are redrawn (the planner's constraint).
    Raises ``ValueError`` if the hull is degenerate or too few points are found.
    """
    w = np.asarray(waypoints_ned, dtype=float)
    try:
        hull = Delaunay(w[:, :2])
    except Exception as exc:  # scipy raises QhullError for collinear points
        raise ValueError(f"waypoints enclose no area: {exc}") from None
    lo, hi = w[:, :2].min(axis=0), w[:, :2].max(axis=0)
    found: list[FloatArray] = []
    for _ in range(max_tries):
        ne = rng.uniform(lo, hi, size=(8 * n_landmarks, 2))
        pts = np.column_stack([ne, np.full(len(ne), ground_down_m)])
        inside = hull.find_simplex(ne) >= 0
        d2 = np.sum((pts[:, None, :] - w[None, :, :]) ** 2, axis=-1)
        found.extend(pts[inside & np.all(d2 >= r_min_m**2, axis=1)])
        if len(found) >= n_landmarks:
            return np.asarray(found[:n_landmarks])
    raise ValueError("could not draw landmarks inside the waypoints' hull")


@dataclass(frozen=True)
class PredictedReductions:
    """What the one-update model (paper 004 eq. 4, 7) predicts a placement gains over another.

    Each field is ``1 - planned / baseline`` of a statistic of the setpoints' traces
    ``tr(J^-1)``: the **worst** trace (what the planner minimizes), the mean trace, and the mean
    1-sigma radius ``sqrt(tr)``, the one a mean position error follows.
    """

    worst_trace: float
    mean_trace: float
    mean_radius: float


def predicted_reductions(
    traces_planned: ArrayLike, traces_baseline: ArrayLike
) -> PredictedReductions:
    """Reductions of the planned traces ``(N,)`` against baseline draws ``(R, N)``.

    The baseline statistics are averaged over the ``R`` draws (one row per random placement).
    A placement can cut the worst setpoint's trace a lot and its mean radius little: the
    minimax objective lifts the worst-seen setpoints, while most setpoints of a random placement
    are already seen well.
    """
    tp = np.asarray(traces_planned, dtype=float).reshape(-1)
    tb = np.asarray(traces_baseline, dtype=float).reshape(-1, tp.size)
    return PredictedReductions(
        worst_trace=float(1.0 - tp.max() / tb.max(axis=1).mean()),
        mean_trace=float(1.0 - tp.mean() / tb.mean()),
        mean_radius=float(1.0 - np.sqrt(tp).mean() / np.sqrt(tb).mean()),
    )


@dataclass(frozen=True)
class TrackErrors:
    """Position errors of one run: at the end (drift), averaged over the mission, and the
    whole series (one per sample of the flight, every ``Mission.dt_s``), m."""

    final_m: float
    mean_m: float
    series_m: FloatArray


def run_errors(
    mission: Mission,
    landmarks_ned: ArrayLike,
    sigma_m: float,
    noise: OdometryNoise,
    seed: int | tuple[int, ...],
    p0_sigma_m: float = 1.0,
    headings_rad: ArrayLike | None = None,
    fov_rad: float | None = None,
    detection_range_m: float | None = None,
) -> TrackErrors:
    """Simulate one flight with seeded noise and return the EKF's errors.

    With ``fov_rad`` the camera has that field of view and, at waypoint ``i``, the heading
    ``headings_rad[i]``: only landmarks inside the cone are measured. Without it the vehicle
    sees every landmark (it yaws around at each waypoint, paper 004 Assumption 2). With
    ``detection_range_m`` landmarks farther than that are not detected (not in the planner's
    model: a sensitivity study).

    The same ``seed`` gives the same path noise and odometry for any landmarks (the bearing
    noise is drawn from a separate stream), so placements are compared on equal terms.
    """
    flight = fly_mission(mission)
    base = np.atleast_1d(np.asarray(seed, dtype=np.int64)).tolist()
    rng_odo = np.random.default_rng([*base, 0])
    rng_bearing = np.random.default_rng([*base, 1])
    p0 = flight.p_ned[0] + p0_sigma_m * rng_odo.normal(size=3)
    v_meas = simulate_odometry(flight, noise, rng_odo)
    z = np.asarray(landmarks_ned, dtype=float).reshape(-1, 3)
    y = simulate_bearings(flight, z, sigma_m, rng_bearing)
    p_key = flight.p_ned[flight.keyframes]
    visible = np.ones((len(p_key), len(z)), dtype=bool)
    if fov_rad is not None:
        if headings_rad is None:
            raise ValueError("a field of view needs one heading per waypoint")
        yaw = np.asarray(headings_rad, dtype=float)[flight.waypoint_index]
        visible &= in_view(p_key, yaw, z, fov_rad)
    if detection_range_m is not None:
        visible &= np.linalg.norm(z[None, :, :] - p_key[:, None, :], axis=-1) <= detection_range_m
    est = ekf_track(
        v_meas, flight.dt_s, flight.keyframes, y, z, sigma_m, noise, p0, p0_sigma_m, visible
    )
    err = np.linalg.norm(est - flight.p_ned, axis=1)
    return TrackErrors(final_m=float(err[-1]), mean_m=float(np.mean(err)), series_m=err)
