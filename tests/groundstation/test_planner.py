"""Landmark placement (paper 004): derivatives, a hand-solved instance, solvers and failures."""

from __future__ import annotations

import math

import numpy as np
import pytest

from groundstation.planner.greedy import candidate_points, solve_greedy
from groundstation.planner.ipopt import IpoptPlacer, solve_ipopt
from groundstation.planner.isres import solve_isres
from groundstation.planner.problem import (
    PlacementProblem,
    PlannerError,
    ProblemError,
    constraint_values,
    constraint_violation,
    landmark_traces,
    make_problem,
)
from groundstation.planner.symbolic import (
    objective_and_constraints,
    parameter_values,
    trace_function,
)
from onboard.rigidity.information import covariance_trace_gradient


def _ball_problem(seed: int, n: int = 5, m: int = 3, **kw: object) -> PlacementProblem:
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    x = 20.0 * u * rng.uniform(size=(n, 1)) ** (1.0 / 3.0)
    return make_problem(x, m, 0.1, 30.0, 2.0, 40.0, **kw)  # type: ignore[arg-type]


def test_symbolic_traces_and_constraints_match_numpy() -> None:
    problem = _ball_problem(1)
    rng = np.random.default_rng(2)
    z = rng.uniform(-30.0, 30.0, (3, 3))
    traces = np.asarray(trace_function(problem)(z.ravel())).ravel()
    np.testing.assert_allclose(traces, landmark_traces(problem, z), rtol=1e-12)
    f, g = objective_and_constraints(problem)(z.ravel(), parameter_values(problem, 1.0))
    assert float(f) == pytest.approx(np.max(traces), rel=1e-12)
    np.testing.assert_allclose(np.asarray(g).ravel(), constraint_values(problem, z), atol=1e-12)


def test_symbolic_fov_constraints_match_numpy() -> None:
    problem = _ball_problem(3, n=4, m=2, fov_deg=80.0, headings_deg=[10.0, np.nan, -40.0, np.nan])
    rng = np.random.default_rng(4)
    z = np.column_stack([rng.uniform(-30.0, 30.0, (2, 2)), np.zeros(2)])
    psi_free = np.array([0.3, 2.0])
    psi = np.radians([10.0, 0.0, -40.0, 0.0])
    psi[[1, 3]] = psi_free
    w = np.concatenate([z[:, :2].ravel(), psi_free])
    _, g = objective_and_constraints(problem)(w, parameter_values(problem, 1.0))
    np.testing.assert_allclose(
        np.asarray(g).ravel(), constraint_values(problem, z, psi), atol=1e-12
    )


def test_gradient_and_hessian_against_finite_differences() -> None:
    """casadi's exact derivatives (what IPOPT uses) vs the analytic gradient and central FD."""
    import casadi as ca

    problem = _ball_problem(5, n=3, m=2)
    traces = trace_function(problem)
    z_sym = ca.SX.sym("z", 6)
    tr_sym = traces(z_sym)
    jac = ca.Function("trace_jacobian", [z_sym], [ca.jacobian(tr_sym, z_sym)])
    hess = ca.Function("trace_hessian", [z_sym], [ca.hessian(tr_sym[0], z_sym)[0]])
    z = np.array([[8.0, -3.0, 5.0], [-6.0, 9.0, -2.0]])
    eps = 1e-5

    analytic = covariance_trace_gradient(
        problem.setpoints_ned, z, problem.sigma_m, problem.prior_cov, problem.delta
    ).reshape(3, 6)
    np.testing.assert_allclose(np.asarray(jac(z.ravel())), analytic, rtol=1e-9, atol=1e-12)
    fd_grad = np.zeros((3, 6))
    fd_hess = np.zeros((6, 6))
    for k in range(6):
        dz = np.zeros(6)
        dz[k] = eps
        plus, minus = z.ravel() + dz, z.ravel() - dz
        fd_grad[:, k] = (
            landmark_traces(problem, plus.reshape(2, 3))
            - landmark_traces(problem, minus.reshape(2, 3))
        ) / (2.0 * eps)
        fd_hess[:, k] = (np.asarray(jac(plus))[0] - np.asarray(jac(minus))[0]) / (2.0 * eps)
    np.testing.assert_allclose(analytic, fd_grad, rtol=1e-6, atol=1e-6 * np.abs(fd_grad).max())
    h = np.asarray(hess(z.ravel()))
    np.testing.assert_allclose(h, h.T, atol=1e-14)
    np.testing.assert_allclose(h, fd_hess, rtol=1e-6, atol=1e-6 * np.abs(fd_hess).max())


@pytest.mark.parametrize("m", [2, 3])
def test_symmetric_instance_matches_hand_computation(m: int) -> None:
    """One setpoint at the origin, no landmark closer than R_min.

    With ``k = 1/(sigma^2 R_min^2)`` and ``p = 1/30`` the information is ``p I + k sum_j P_j``
    when every landmark sits at ``R_min``. Minimizing ``sum 1/eig`` over the spectrum of
    ``sum_j P_j = m I - sum_j u_j u_j^T`` (convex, trace fixed) spreads it evenly: two
    landmarks at right angles give ``2/(p + k) + 1/(p + 2k)``, three orthogonal ones
    ``3/(p + 2k)``. Landmarks farther away only lose information.
    """
    sigma, r_min, p = 0.1, 5.0, 1.0 / 30.0
    k = 1.0 / (sigma**2 * r_min**2)
    expected = 2.0 / (p + k) + 1.0 / (p + 2.0 * k) if m == 2 else 3.0 / (p + 2.0 * k)
    problem = make_problem(np.zeros((1, 3)), m, sigma, 30.0, r_min, 60.0)
    result = solve_ipopt(problem, seed=1, starts=3)
    assert result.objective == pytest.approx(expected, rel=1e-6)
    z = result.landmarks_ned
    np.testing.assert_allclose(np.linalg.norm(z, axis=1), r_min, rtol=1e-6)
    u = z / np.linalg.norm(z, axis=1)[:, None]
    np.testing.assert_allclose(u @ u.T, np.eye(m), atol=1e-4)


def test_ipopt_is_seeded_and_reuses_solvers() -> None:
    problem = _ball_problem(6)
    placer = IpoptPlacer()
    a = placer.solve(problem, seed=3, starts=2)
    b = placer.solve(problem, seed=3, starts=2)
    np.testing.assert_array_equal(a.landmarks_ned, b.landmarks_ned)
    assert len(placer._solvers) == 1
    assert constraint_violation(problem, a.landmarks_ned) <= 1e-6


def test_ipopt_beats_or_matches_greedy_and_isres() -> None:
    problem = _ball_problem(7, n=6, m=3)
    ipopt = solve_ipopt(problem, seed=0, starts=4)
    greedy = solve_greedy(problem)
    isres = solve_isres(problem, seed=0, max_evals=3000)
    assert ipopt.objective <= greedy.objective + 1e-9
    assert ipopt.objective <= isres.objective * (1.0 + 1e-3)
    for r in (ipopt, greedy, isres):
        assert constraint_violation(problem, r.landmarks_ned) <= 1e-6
        assert r.objective == pytest.approx(np.max(landmark_traces(problem, r.landmarks_ned)))


def test_isres_is_reproducible_with_a_seed() -> None:
    problem = _ball_problem(8, n=4, m=2)
    a = solve_isres(problem, seed=5, max_evals=800)
    b = solve_isres(problem, seed=5, max_evals=800)
    np.testing.assert_array_equal(a.landmarks_ned, b.landmarks_ned)


def test_greedy_first_landmark_is_the_best_candidate() -> None:
    problem = _ball_problem(9, n=4, m=1)
    result = solve_greedy(problem, spacing_m=8.0)
    grid = candidate_points(problem, 8.0)
    worst = [np.max(landmark_traces(problem, c[None])) for c in grid]
    assert result.objective == pytest.approx(min(worst), rel=1e-12)


def test_infeasible_geometry_is_a_problem_error() -> None:
    axes = np.vstack([np.zeros(3), 4.0 * np.eye(3), -4.0 * np.eye(3)])
    with pytest.raises(ProblemError, match="infeasible"):
        make_problem(axes, 2, 0.1, 30.0, 5.0, 6.0)
    with pytest.raises(ProblemError, match="r_max"):
        make_problem(axes, 2, 0.1, 30.0, 5.0, 4.0)
    with pytest.raises(ProblemError, match="non-finite"):
        make_problem([[0.0, np.nan, 0.0]], 2, 0.1, 30.0, 1.0, 4.0)


def test_ipopt_failure_is_reported_not_swallowed() -> None:
    problem = _ball_problem(10)
    with pytest.raises(PlannerError, match="Maximum_Iterations_Exceeded"):
        solve_ipopt(problem, seed=0, starts=2, max_iter=2)


def test_ipopt_reports_an_infeasible_field_of_view() -> None:
    """High setpoints and a narrow cone: no ground landmark within R_max can be seen."""
    x = np.array([[0.0, 0.0, -50.0], [10.0, 0.0, -50.0]])
    problem = make_problem(x, 2, 0.1, 30.0, 2.0, 60.0, fov_deg=10.0)
    with pytest.raises(PlannerError, match="ipopt found no feasible placement"):
        solve_ipopt(problem, seed=0, starts=2, max_iter=200)


def test_fov_solution_sees_every_landmark() -> None:
    x = np.array([[-10.0, 0.0, -5.0], [10.0, 0.0, -5.0], [0.0, 10.0, -5.0]])
    headings = [0.0, np.nan, np.nan]
    problem = make_problem(x, 2, 0.1, 30.0, 2.0, 40.0, fov_deg=90.0, headings_deg=headings)
    result = solve_ipopt(problem, seed=2, starts=3)
    z = result.landmarks_ned
    assert result.headings_rad is not None
    assert result.headings_rad[0] == pytest.approx(0.0)
    np.testing.assert_allclose(z[:, 2], 0.0)
    r = z[None] - x[:, None]
    n = np.stack([np.cos(result.headings_rad), np.sin(result.headings_rad), 0 * x[:, 0]], -1)
    cos_angle = np.einsum("nk,nmk->nm", n, r) / np.linalg.norm(r, axis=-1)
    assert np.all(cos_angle >= math.cos(math.radians(45.0)) - 1e-6)


def test_greedy_fov_needs_fixed_headings() -> None:
    x = np.array([[-10.0, 0.0, -5.0], [10.0, 0.0, -5.0]])
    problem = make_problem(x, 1, 0.1, 30.0, 2.0, 40.0, fov_deg=90.0)
    with pytest.raises(ProblemError, match="heading_deg"):
        solve_greedy(problem)
    fixed = make_problem(x, 1, 0.1, 30.0, 2.0, 40.0, fov_deg=120.0, headings_deg=[0.0, 180.0])
    result = solve_greedy(fixed)
    assert constraint_violation(fixed, result.landmarks_ned, fixed.headings_rad) == 0.0
