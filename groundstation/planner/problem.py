"""The landmark placement problem of paper 004 (Problems 1-3 and the field-of-view variant).

Place ``M`` landmarks ``z_1..z_M`` (well-localized vehicles seen by bearing) so that the worst
localization uncertainty ``max_i tr(Sigma_delta(x_i; z))`` over the setpoints ``x_i`` is as
small as possible, subject to ``|z_j| <= R_max`` and ``|z_j - x_i| >= R_min`` (paper 004
Problem 2). The field-of-view variant (eq. 19-20) puts the landmarks on the ground plane
``down = ground_down_m`` and asks that, from each setpoint, one heading ``n_i`` sees every
landmark inside a cone of full angle ``alpha``:
``n_i . (z_j - x_i) >= cos(alpha/2) sqrt(|z_j - x_i|^2 + delta^2)``.

All positions are local NED metres; headings are yaw angles (rad, NED: 0 north, pi/2 east) of
a level body-x camera, ``n_i = (cos psi_i, sin psi_i, 0)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import FloatArray, camera_axis_ned
from onboard.rigidity.information import covariance_trace, prior_information, smoothing_delta


class ProblemError(ValueError):
    """The problem data are invalid (bad numbers, empty or provably infeasible geometry)."""


class PlannerError(RuntimeError):
    """A solver failed to return a feasible placement; the message says why."""


FEASIBILITY_TOL = 1e-6
"""Largest constraint violation (scaled, see :func:`constraint_violation`) a result may have."""


@dataclass(frozen=True)
class PlacementProblem:
    """Data of one placement problem; build it with :func:`make_problem` (which validates)."""

    setpoints_ned: FloatArray  # (N, 3)
    n_landmarks: int
    sigma_m: float
    prior_cov: FloatArray  # (3, 3)
    r_min_m: float
    r_max_m: float
    delta: float
    fov_rad: float | None = None
    headings_rad: FloatArray | None = None  # (N,), NaN where the heading is free
    ground_down_m: float | None = None  # landmarks on this plane when set

    @property
    def n_setpoints(self) -> int:
        return int(self.setpoints_ned.shape[0])

    @property
    def planar(self) -> bool:
        return self.ground_down_m is not None

    @property
    def free_headings(self) -> np.ndarray:
        """Boolean mask of setpoints whose heading the planner chooses (FOV variant only)."""
        if self.fov_rad is None:
            return np.zeros(self.n_setpoints, dtype=bool)
        if self.headings_rad is None:
            return np.ones(self.n_setpoints, dtype=bool)
        return np.isnan(self.headings_rad)


@dataclass(frozen=True)
class PlacementResult:
    """A placement and how good it is: ``objective = max_i tr(Sigma_delta(x_i; z))`` in m^2."""

    method: str
    landmarks_ned: FloatArray  # (M, 3)
    setpoint_traces: FloatArray  # (N,), tr(Sigma_delta(x_i; z)) in m^2
    objective: float
    seconds: float
    headings_rad: FloatArray | None = None  # (N,) with the FOV variant
    details: dict[str, object] = field(default_factory=dict)


def _finite(name: str, value: float) -> float:
    value = float(value)
    if not math.isfinite(value):
        raise ProblemError(f"{name} must be a finite number, got {value}")
    return value


def make_problem(
    setpoints_ned: ArrayLike,
    n_landmarks: int,
    sigma_m: float,
    prior_cov: ArrayLike,
    r_min_m: float,
    r_max_m: float,
    *,
    fov_deg: float | None = None,
    headings_deg: ArrayLike | None = None,
    ground_down_m: float | None = None,
    delta: float | None = None,
) -> PlacementProblem:
    """Validate the data and build a :class:`PlacementProblem`.

    ``delta`` defaults to the rule of Theorem V.1 (:func:`smoothing_delta`). With ``fov_deg``
    the landmarks are planar on ``ground_down_m`` (default 0, the NED origin's level);
    ``headings_deg`` fixes some headings (NaN entries stay free). Raises :class:`ProblemError`.
    """
    x = np.asarray(setpoints_ned, dtype=float)
    if x.ndim != 2 or x.shape[1] != 3 or x.shape[0] == 0:
        raise ProblemError(f"need at least one setpoint of 3 coordinates, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        bad = int(np.argwhere(~np.isfinite(x))[0, 0])
        raise ProblemError(f"setpoint {bad} has a non-finite coordinate")
    if int(n_landmarks) < 1:
        raise ProblemError(f"need at least one landmark, got {n_landmarks}")
    sigma = _finite("sigma_m", sigma_m)
    r_min = _finite("r_min", r_min_m)
    r_max = _finite("r_max", r_max_m)
    if sigma <= 0.0:
        raise ProblemError(f"sigma_m must be positive, got {sigma}")
    if r_min <= 0.0:
        raise ProblemError(f"r_min must be positive, got {r_min}")
    if r_max <= r_min:
        raise ProblemError(f"r_max ({r_max}) must be larger than r_min ({r_min})")
    try:
        prior = np.linalg.inv(prior_information(prior_cov))
    except ValueError as exc:
        raise ProblemError(str(exc)) from None
    fov_rad = None
    headings = None
    ground = None if ground_down_m is None else _finite("ground_down_m", ground_down_m)
    if fov_deg is not None:
        fov = _finite("fov", fov_deg)
        if not 0.0 < fov < 180.0:
            raise ProblemError(f"field of view must be in (0, 180) degrees, got {fov}")
        fov_rad = math.radians(fov)
        ground = 0.0 if ground is None else ground
        if headings_deg is not None:
            headings = np.radians(np.asarray(headings_deg, dtype=float).reshape(-1))
            if headings.shape != (x.shape[0],) or np.any(np.isinf(headings)):
                raise ProblemError("headings must be one finite angle (or NaN = free) per setpoint")
    if delta is None:
        delta = smoothing_delta(r_min)
    if not 0.0 <= float(delta) < r_min:
        raise ProblemError(f"delta must be in [0, r_min), got {delta}")
    problem = PlacementProblem(
        setpoints_ned=x,
        n_landmarks=int(n_landmarks),
        sigma_m=sigma,
        prior_cov=prior,
        r_min_m=r_min,
        r_max_m=r_max,
        delta=float(delta),
        fov_rad=fov_rad,
        headings_rad=headings,
        ground_down_m=ground,
    )
    if candidate_grid(problem, spacing_m=r_max / 15.0).shape[0] == 0:
        raise ProblemError(
            f"no landmark position found with |z| <= r_max ({r_max}) at least r_min ({r_min})"
            " from every setpoint"
            + (" on the ground plane inside every field of view" if fov_rad else "")
            + ": the problem looks infeasible"
        )
    return problem


def headings_for(problem: PlacementProblem, free_rad: ArrayLike | None = None) -> FloatArray:
    """Full heading vector: fixed headings with the free ones filled from ``free_rad``."""
    psi = np.zeros(problem.n_setpoints)
    if problem.headings_rad is not None:
        psi = np.nan_to_num(problem.headings_rad.copy())
    mask = problem.free_headings
    if free_rad is not None:
        psi[mask] = np.asarray(free_rad, dtype=float).reshape(-1)
    return psi


def initial_headings(problem: PlacementProblem, landmarks_ned: ArrayLike) -> FloatArray:
    """Free headings pointing from each free setpoint at the centroid of the given landmarks."""
    z = np.asarray(landmarks_ned, dtype=float).reshape(-1, 3)
    to_centroid = np.mean(z, axis=0) - problem.setpoints_ned[problem.free_headings]
    return np.arctan2(to_centroid[:, 1], to_centroid[:, 0])


def landmark_traces(problem: PlacementProblem, landmarks_ned: ArrayLike) -> FloatArray:
    """``tr(Sigma_delta(x_i; z))`` per setpoint (paper 004 eq. 7)."""
    return covariance_trace(
        problem.setpoints_ned, landmarks_ned, problem.sigma_m, problem.prior_cov, problem.delta
    )


def constraint_values(
    problem: PlacementProblem, landmarks_ned: ArrayLike, headings_rad: ArrayLike | None = None
) -> FloatArray:
    """All constraints as ``c <= 0``, scaled to be dimensionless, flattened.

    ``|z_j|^2 / R_max^2 - 1``, ``1 - |z_j - x_i|^2 / R_min^2`` and, for the FOV variant,
    ``(cos(alpha/2) sqrt(|r|^2 + delta^2) - n_i . r) / R_min`` with ``r = z_j - x_i`` (eq. 20).
    The planar constraint is structural (solvers only move north and east) and not listed.
    """
    z = np.asarray(landmarks_ned, dtype=float).reshape(-1, 3)
    r = z[None, :, :] - problem.setpoints_ned[:, None, :]
    d2 = np.sum(r * r, axis=-1)
    parts = [
        np.sum(z * z, axis=-1) / problem.r_max_m**2 - 1.0,
        (1.0 - d2 / problem.r_min_m**2).ravel(),
    ]
    if problem.fov_rad is not None:
        psi = headings_for(problem) if headings_rad is None else np.asarray(headings_rad)
        n = camera_axis_ned(psi)
        cone = math.cos(problem.fov_rad / 2.0) * np.sqrt(d2 + problem.delta**2)
        parts.append(((cone - np.einsum("nk,nmk->nm", n, r)) / problem.r_min_m).ravel())
    return np.concatenate(parts)


def constraint_violation(
    problem: PlacementProblem, landmarks_ned: ArrayLike, headings_rad: ArrayLike | None = None
) -> float:
    """Largest scaled constraint violation (0 when feasible)."""
    return float(max(0.0, np.max(constraint_values(problem, landmarks_ned, headings_rad))))


def feasible_points(problem: PlacementProblem, pts: FloatArray) -> FloatArray:
    """The rows of ``pts (K, 3)`` that satisfy the single-landmark constraints.

    ``|z| <= R_max``, ``|z - x_i| >= R_min`` for every setpoint and, when every heading is
    fixed, the field-of-view cone of eq. 20 from every setpoint.
    """
    pts = pts[np.sum(pts * pts, axis=-1) <= problem.r_max_m**2]
    d2 = np.sum((pts[:, None, :] - problem.setpoints_ned[None, :, :]) ** 2, axis=-1)
    pts = pts[np.all(d2 >= problem.r_min_m**2, axis=1)]
    if problem.fov_rad is not None and not np.any(problem.free_headings):
        n = camera_axis_ned(headings_for(problem))
        r = pts[:, None, :] - problem.setpoints_ned[None, :, :]
        cone = math.cos(problem.fov_rad / 2.0) * np.sqrt(np.sum(r * r, -1) + problem.delta**2)
        pts = pts[np.all(np.einsum("nc,knc->kn", n, r) >= cone, axis=1)]
    return pts


def candidate_grid(problem: PlacementProblem, spacing_m: float) -> FloatArray:
    """Feasible points of a regular grid (3D, or on the ground plane when planar), ``(K, 3)``.

    The grid has ``spacing_m`` between neighbours and is clipped to the ``R_max`` ball; points
    closer than ``R_min`` to a setpoint (or outside a fixed-heading field of view) are removed.
    """
    r_max = problem.r_max_m
    ticks = np.arange(-r_max, r_max + 0.5 * spacing_m, spacing_m)
    if problem.planar:
        north, east = np.meshgrid(ticks, ticks, indexing="ij")
        pts = np.stack(
            [north.ravel(), east.ravel(), np.full(north.size, problem.ground_down_m)], axis=-1
        )
    else:
        pts = np.stack(np.meshgrid(ticks, ticks, ticks, indexing="ij"), axis=-1).reshape(-1, 3)
    return feasible_points(problem, pts)


def random_feasible_landmarks(
    problem: PlacementProblem, rng: np.random.Generator, max_tries: int = 200
) -> FloatArray:
    """``M`` landmarks drawn uniformly in the feasible set (rejection sampling), ``(M, 3)``.

    The field of view is ignored (it depends on the headings); planar problems sample the
    ground disc. Raises :class:`PlannerError` if too few feasible samples are found.
    """
    m = problem.n_landmarks
    found: list[FloatArray] = []
    for _ in range(max_tries):
        if problem.planar:
            radius = problem.r_max_m * np.sqrt(rng.uniform(size=8 * m))
            angle = rng.uniform(0.0, 2.0 * np.pi, size=8 * m)
            pts = np.stack(
                [
                    radius * np.cos(angle),
                    radius * np.sin(angle),
                    np.full(8 * m, problem.ground_down_m),
                ],
                axis=-1,
            )
        else:
            pts = rng.uniform(-problem.r_max_m, problem.r_max_m, size=(8 * m, 3))
        ok = np.sum(pts * pts, axis=-1) <= problem.r_max_m**2
        d2 = np.sum((pts[:, None, :] - problem.setpoints_ned[None]) ** 2, axis=-1)
        ok &= np.all(d2 >= problem.r_min_m**2, axis=1)
        found.extend(pts[ok])
        if len(found) >= m:
            return np.asarray(found[:m])
    raise PlannerError("could not sample feasible initial landmark positions")


def result_from_landmarks(
    problem: PlacementProblem,
    method: str,
    landmarks_ned: ArrayLike,
    seconds: float,
    headings_rad: ArrayLike | None = None,
    details: dict[str, object] | None = None,
) -> PlacementResult:
    """Evaluate a placement with the numpy model (the same for every method)."""
    z = np.asarray(landmarks_ned, dtype=float).reshape(-1, 3)
    traces = landmark_traces(problem, z)
    return PlacementResult(
        method=method,
        landmarks_ned=z,
        setpoint_traces=traces,
        objective=float(np.max(traces)),
        seconds=float(seconds),
        headings_rad=None if headings_rad is None else np.asarray(headings_rad, dtype=float),
        details=details or {},
    )
