"""Problem 2-3 and eq. 19-20 of paper 004 as casadi expressions (for IPOPT and ISRES).

The traces ``tr(J_delta(x_i; z)^-1)`` (eq. 7 with the closed form eq. 34) and the scaled
constraints of :func:`groundstation.planner.problem.constraint_values`, built symbolically so
casadi can differentiate them exactly (first and second order) and evaluate them fast. The
problem data enter as parameters (:class:`Params`), so one compiled function serves every
problem of the same shape (:func:`shape_key`). Tests check these expressions against the
numpy implementation in ``onboard.rigidity.information``.

casadi is imported inside the functions so that importing this module stays cheap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from groundstation.planner.problem import PlacementProblem, headings_for
from onboard.rigidity.information import prior_information


def landmark_dims(problem: PlacementProblem) -> int:
    return 2 if problem.planar else 3


@dataclass(frozen=True)
class Params:
    """Symbolic problem data, so one compiled solver serves every problem of the same shape."""

    x: Any  # (3, N) setpoints
    info0: Any  # (3, 3) prior information
    inv_sigma2: Any
    delta2: Any
    r_min: Any
    r_max: Any
    ground: Any
    cos_half: Any
    headings: Any  # (N,) fixed headings (ignored where free)
    scale: Any  # trace scale

    @staticmethod
    def symbols(n: int) -> tuple[Params, Any]:
        import casadi as ca

        v = ca.SX.sym("p", 3 * n + 9 + 7 + n)
        params = Params(
            x=ca.reshape(v[: 3 * n], 3, n),
            info0=ca.reshape(v[3 * n : 3 * n + 9], 3, 3),
            inv_sigma2=v[3 * n + 9],
            delta2=v[3 * n + 10],
            r_min=v[3 * n + 11],
            r_max=v[3 * n + 12],
            ground=v[3 * n + 13],
            cos_half=v[3 * n + 14],
            scale=v[3 * n + 15],
            headings=v[3 * n + 16 :],
        )
        return params, v


def parameter_values(problem: PlacementProblem, scale: float) -> np.ndarray:
    """Numbers for :meth:`Params.symbols`, in the same order."""
    cos_half = 1.0 if problem.fov_rad is None else math.cos(problem.fov_rad / 2.0)
    ground = 0.0 if problem.ground_down_m is None else problem.ground_down_m
    return np.concatenate(
        [
            problem.setpoints_ned.ravel(),  # row-major (N, 3) == column-major (3, N)
            prior_information(problem.prior_cov).ravel(),
            [1.0 / problem.sigma_m**2, problem.delta**2, problem.r_min_m, problem.r_max_m],
            [ground, cos_half, scale],
            headings_for(problem),
        ]
    )


def symbolic_landmarks(problem: PlacementProblem, z_vars: Any, par: Params) -> list[Any]:
    """The landmark positions as casadi 3-vectors (the down coordinate fixed when planar)."""
    import casadi as ca

    dims = landmark_dims(problem)
    out = []
    for j in range(problem.n_landmarks):
        zj = z_vars[dims * j : dims * (j + 1)]
        out.append(ca.vertcat(zj, par.ground) if problem.planar else zj)
    return out


def symbolic_traces(problem: PlacementProblem, landmarks: list[Any], par: Params) -> list[Any]:
    """``tr(J_delta(x_i; z)^-1)`` per setpoint as casadi expressions (eq. 7 with eq. 34).

    ``tr(J^-1)`` of the symmetric 3x3 ``J`` is the sum of its principal 2x2 minors over ``det J``.
    """
    import casadi as ca

    traces = []
    for i in range(problem.n_setpoints):
        jm = par.info0
        for z in landmarks:
            r = z - par.x[:, i]
            s2 = ca.dot(r, r) + par.delta2
            jm = jm + (ca.SX.eye(3) / s2 - (s2 + par.delta2) / s2**3 * (r @ r.T)) * par.inv_sigma2
        a, b, c = jm[0, 0], jm[1, 1], jm[2, 2]
        d, e, f = jm[0, 1], jm[0, 2], jm[1, 2]
        minors = (b * c - f * f) + (a * c - e * e) + (a * b - d * d)
        det = a * (b * c - f * f) - d * (d * c - f * e) + e * (d * f - b * e)
        traces.append(minors / det)
    return traces


def trace_function(problem: PlacementProblem) -> Any:
    """casadi Function ``z (M*dims) -> traces (N)``, the expressions IPOPT differentiates."""
    import casadi as ca

    par, v = Params.symbols(problem.n_setpoints)
    z_vars = ca.SX.sym("z", landmark_dims(problem) * problem.n_landmarks)
    traces = ca.vertcat(*symbolic_traces(problem, symbolic_landmarks(problem, z_vars, par), par))
    values = ca.DM(parameter_values(problem, 1.0))
    return ca.Function("traces", [z_vars], [ca.substitute(traces, v, values)])


def shape_key(problem: PlacementProblem) -> tuple[object, ...]:
    """What a compiled function depends on: sizes, planarity and which headings are free."""
    free = tuple(bool(f) for f in problem.free_headings)
    return (problem.n_setpoints, problem.n_landmarks, problem.planar, problem.fov_rad is None, free)


def symbolic_constraints(
    problem: PlacementProblem, landmarks: list[Any], psi_vars: Any, par: Params
) -> list[Any]:
    """Constraints ``c <= 0`` in the order and scaling of ``problem.constraint_values``."""
    import casadi as ca

    n = problem.n_setpoints
    g = [ca.dot(z, z) / par.r_max**2 - 1.0 for z in landmarks]
    g += [1.0 - ca.sumsqr(z - par.x[:, i]) / par.r_min**2 for i in range(n) for z in landmarks]
    if problem.fov_rad is not None:
        slot = {int(i): k for k, i in enumerate(np.flatnonzero(problem.free_headings))}
        for i in range(n):
            psi = psi_vars[slot[i]] if i in slot else par.headings[i]
            heading = ca.vertcat(ca.cos(psi), ca.sin(psi), 0.0)
            for z in landmarks:
                r = z - par.x[:, i]
                cone = par.cos_half * ca.sqrt(ca.dot(r, r) + par.delta2)
                g.append((cone - ca.dot(heading, r)) / par.r_min)
    return g


def decision_symbols(problem: PlacementProblem) -> tuple[Any, Any]:
    """Landmark coordinates ``z`` (north, east[, down] per landmark) and free headings ``psi``."""
    import casadi as ca

    z_vars = ca.SX.sym("z", landmark_dims(problem) * problem.n_landmarks)
    psi_vars = ca.SX.sym("psi", int(np.sum(problem.free_headings)))
    return z_vars, psi_vars


def objective_and_constraints(problem: PlacementProblem) -> Any:
    """casadi Function ``(w = [z; psi], p) -> (max_i trace_i, constraints)`` for Problem 2."""
    import casadi as ca

    par, v = Params.symbols(problem.n_setpoints)
    z_vars, psi_vars = decision_symbols(problem)
    landmarks = symbolic_landmarks(problem, z_vars, par)
    worst = ca.mmax(ca.vertcat(*symbolic_traces(problem, landmarks, par)))
    g = ca.vertcat(*symbolic_constraints(problem, landmarks, psi_vars, par))
    return ca.Function("fg", [ca.vertcat(z_vars, psi_vars), v], [worst, g])
