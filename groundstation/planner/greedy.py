"""Greedy landmark placement on a grid of candidate points (the baseline of paper 004, IV-B).

Starting from no landmarks, add at each step the feasible grid point whose addition gives the
smallest worst-case covariance trace ``max_i tr(Sigma_delta(x_i; z))`` (ties broken by the sum
of the traces), until ``M`` landmarks are placed. Each step scores every candidate at once: the information of the current set plus
the candidate's term (eq. 7, eq. 34) for every setpoint, ``(K, N, 3, 3)`` matrices.
With the field-of-view variant the headings must all be fixed (the grid is filtered by them).

The candidates are a regular grid over the ``R_max`` ball plus, because the information of a
bearing falls off as ``1/D^2`` and good landmarks often sit near ``R_min`` from a setpoint,
shells of directions around every setpoint at a few multiples of ``R_min`` (without them a
grid coarser than ``R_min`` cannot come close to the setpoints and greedy looks much worse
than it is).
"""

from __future__ import annotations

import time

import numpy as np

from groundstation.planner.problem import (
    PlacementProblem,
    PlacementResult,
    PlannerError,
    ProblemError,
    candidate_grid,
    feasible_points,
    result_from_landmarks,
)
from onboard.rigidity.information import (
    bearing_information,
    bearing_information_terms,
    trace_of_inverse_3x3,
)

DEFAULT_GRID_POINTS = 4000
"""Target number of grid points in the ``R_max`` ball (3D) or disc (planar) before filtering."""


def default_spacing(problem: PlacementProblem, n_points: int = DEFAULT_GRID_POINTS) -> float:
    """Grid spacing that puts about ``n_points`` points in the ball (or disc) of radius R_max."""
    if problem.planar:
        return float(np.sqrt(np.pi * problem.r_max_m**2 / n_points))
    return float(np.cbrt(4.0 / 3.0 * np.pi * problem.r_max_m**3 / n_points))


SHELL_RADII = (1.0, 1.25, 1.5, 2.0, 3.0)
"""Radii of the candidate shells around each setpoint, in units of ``R_min``."""


def fibonacci_directions(count: int) -> np.ndarray:
    """``count`` nearly uniform unit vectors (Fibonacci sphere), ``(count, 3)``."""
    k = np.arange(count) + 0.5
    polar = np.arccos(1.0 - 2.0 * k / count)
    azimuth = np.pi * (1.0 + 5.0**0.5) * k
    return np.stack(
        [np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)], -1
    )


def candidate_points(
    problem: PlacementProblem, spacing_m: float, shell_directions: int = 48
) -> np.ndarray:
    """Feasible grid points plus shells around every setpoint (planar: rings on the ground)."""
    grid = candidate_grid(problem, spacing_m)
    radii = problem.r_min_m * np.asarray(SHELL_RADII)
    x = problem.setpoints_ned
    if problem.planar:
        angle = np.linspace(0.0, 2.0 * np.pi, shell_directions, endpoint=False)
        ring = np.stack([np.cos(angle), np.sin(angle)], -1)
        # horizontal offsets that put a ground point at 3D distance rho from the setpoint
        height2 = (x[:, 2] - problem.ground_down_m) ** 2
        horizontal = np.sqrt(np.maximum(radii[None, :] ** 2 - height2[:, None], 0.0))
        offsets = horizontal[:, :, None, None] * ring[None, None]  # (N, R, D, 2)
        north_east = x[:, None, None, :2] + offsets
        down = np.full((*north_east.shape[:-1], 1), problem.ground_down_m)
        shells = np.concatenate([north_east, down], axis=-1).reshape(-1, 3)
    else:
        dirs = fibonacci_directions(shell_directions)
        shells = (x[:, None, None, :] + radii[None, :, None, None] * dirs[None, None]).reshape(
            -1, 3
        )
    return np.unique(np.vstack([grid, feasible_points(problem, shells)]), axis=0)


def solve_greedy(problem: PlacementProblem, *, spacing_m: float | None = None) -> PlacementResult:
    """Greedy placement on :func:`candidate_points` (grid spacing default :func:`default_spacing`).

    Deterministic (no seed). A grid point is used at most once. Raises :class:`PlannerError` if
    the grid has fewer feasible points than landmarks, :class:`ProblemError` for an FOV problem
    with free headings.
    """
    if problem.fov_rad is not None and np.any(problem.free_headings):
        raise ProblemError("greedy with a field of view needs heading_deg on every setpoint")
    t_start = time.perf_counter()
    spacing = default_spacing(problem) if spacing_m is None else float(spacing_m)
    candidates = candidate_points(problem, spacing)
    if candidates.shape[0] < problem.n_landmarks:
        raise PlannerError(
            f"greedy: only {candidates.shape[0]} feasible candidates (grid spacing {spacing:.3g} m)"
            f" for {problem.n_landmarks} landmarks"
        )
    x = problem.setpoints_ned
    # (K, N, 3, 3): what each candidate adds to each setpoint's information
    added = np.swapaxes(bearing_information_terms(x, candidates, problem.delta), 0, 1)
    added /= problem.sigma_m**2
    info = bearing_information(x, np.zeros((0, 3)), problem.sigma_m, problem.prior_cov, 0.0)
    available = np.ones(candidates.shape[0], dtype=bool)
    chosen: list[int] = []
    for _ in range(problem.n_landmarks):
        traces = trace_of_inverse_3x3(info[None] + added)  # (K, N)
        worst = np.max(traces, axis=1)
        worst[~available] = np.inf
        # ties in the worst trace (common while some setpoint still sees < 2 landmarks) are
        # broken by the total trace, so the step still helps the other setpoints
        ties = worst <= np.min(worst) * (1.0 + 1e-9)
        k = int(np.argmin(np.where(ties, np.sum(traces, axis=1), np.inf)))
        chosen.append(k)
        available[k] = False
        info = info + added[k]
    details = {"candidates": int(candidates.shape[0]), "spacing_m": spacing}
    return result_from_landmarks(
        problem,
        "greedy",
        candidates[chosen],
        time.perf_counter() - t_start,
        None if problem.fov_rad is None else problem.headings_rad,
        details,
    )
