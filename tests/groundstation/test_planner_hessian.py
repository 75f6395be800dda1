"""The structured Hessian of the Lagrangian (paper 004 eq. 11) against casadi AD and FD."""

from __future__ import annotations

import numpy as np
import pytest

from groundstation.planner.hessian import lagrangian_hessian, trace_hessian
from groundstation.planner.ipopt import IpoptPlacer
from groundstation.planner.problem import PlacementProblem, landmark_traces, make_problem
from groundstation.planner.symbolic import (
    Params,
    decision_symbols,
    parameter_values,
    symbolic_constraints,
    symbolic_landmarks,
    symbolic_traces,
)


def _problem(fov: bool) -> PlacementProblem:
    rng = np.random.default_rng(21)
    x = rng.uniform(-15.0, 15.0, (4, 3))
    x[:, 2] = -np.abs(x[:, 2]) - 3.0
    if fov:
        headings = [20.0, np.nan, np.nan, -60.0]
        return make_problem(x, 3, 0.1, 30.0, 2.0, 40.0, fov_deg=100.0, headings_deg=headings)
    return make_problem(x, 3, 0.1, 30.0, 2.0, 40.0)


def _lagrangian(problem: PlacementProblem):  # type: ignore[no-untyped-def]
    """Symbols, the Lagrangian of Problem 3 and the structured Hessian Function."""
    import casadi as ca

    par, v = Params.symbols(problem.n_setpoints)
    t = ca.SX.sym("t")
    z_vars, psi_vars = decision_symbols(problem)
    landmarks = symbolic_landmarks(problem, z_vars, par)
    g = [tr / par.scale - t for tr in symbolic_traces(problem, landmarks, par)]
    g = ca.vertcat(*g, *symbolic_constraints(problem, landmarks, psi_vars, par))
    w = ca.vertcat(t, z_vars, psi_vars)
    lam_f = ca.SX.sym("lam_f")
    lam_g = ca.SX.sym("lam_g", g.numel())
    lagrangian = lam_f * t + ca.dot(lam_g, g)
    return w, v, lam_f, lam_g, lagrangian, lagrangian_hessian(problem, w, z_vars, par, v, g)


def _random_point(problem: PlacementProblem, n_w: int, n_g: int, seed: int):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(seed)
    w = np.concatenate([[0.7], rng.uniform(-25.0, 25.0, n_w - 1)])
    return w, parameter_values(problem, 3.0), 1.0, rng.uniform(0.1, 2.0, n_g)


@pytest.mark.parametrize("fov", [False, True])
def test_structured_hessian_equals_automatic_differentiation(fov: bool) -> None:
    import casadi as ca

    problem = _problem(fov)
    w, v, lam_f, lam_g, lagrangian, hess_fn = _lagrangian(problem)
    auto = ca.Function("auto", [w, v, lam_f, lam_g], [ca.triu(ca.hessian(lagrangian, w)[0])])
    args = _random_point(problem, w.numel(), lam_g.numel(), seed=3)
    structured = np.asarray(ca.densify(hess_fn(*args)))
    reference = np.asarray(ca.densify(auto(*args)))
    assert np.abs(reference).max() > 1e-3  # a non-trivial point
    np.testing.assert_allclose(
        structured, reference, rtol=1e-10, atol=1e-12 * np.abs(reference).max()
    )
    if fov:  # the headings couple to the landmarks through the cone constraints
        n_z = 2 * problem.n_landmarks
        assert np.abs(structured[1 : 1 + n_z, 1 + n_z :]).max() > 0.0


def test_structured_hessian_against_finite_differences() -> None:
    import casadi as ca

    problem = _problem(False)
    w, v, lam_f, lam_g, lagrangian, hess_fn = _lagrangian(problem)
    grad = ca.Function("grad", [w, v, lam_f, lam_g], [ca.gradient(lagrangian, w)])
    w0, pv, lf, lg = _random_point(problem, w.numel(), lam_g.numel(), seed=4)
    upper = np.asarray(ca.densify(hess_fn(w0, pv, lf, lg)))
    full = upper + np.triu(upper, 1).T
    eps = 1e-5
    fd = np.zeros_like(full)
    for k in range(w0.size):
        step = np.zeros_like(w0)
        step[k] = eps
        plus = np.asarray(grad(w0 + step, pv, lf, lg)).ravel()
        minus = np.asarray(grad(w0 - step, pv, lf, lg)).ravel()
        fd[:, k] = (plus - minus) / (2.0 * eps)
    np.testing.assert_allclose(full, fd, rtol=1e-6, atol=1e-6 * np.abs(fd).max())


def test_trace_hessian_traces_match_numpy() -> None:
    import casadi as ca

    problem = _problem(False)
    par, v = Params.symbols(problem.n_setpoints)
    z_vars, _ = decision_symbols(problem)
    _, traces = trace_hessian(problem, z_vars, par, ca.SX.ones(problem.n_setpoints))
    fn = ca.Function("traces", [z_vars, v], [ca.vertcat(*traces)])
    z = np.random.default_rng(5).uniform(-20.0, 20.0, (3, 3))
    values = np.asarray(fn(z.ravel(), parameter_values(problem, 1.0))).ravel()
    np.testing.assert_allclose(values, landmark_traces(problem, z), rtol=1e-12)


def test_structured_and_automatic_hessians_give_the_same_placement() -> None:
    problem = _problem(False)
    a = IpoptPlacer(structured_hessian=True).solve(problem, seed=2, starts=2)
    b = IpoptPlacer(structured_hessian=False).solve(problem, seed=2, starts=2)
    assert a.objective == pytest.approx(b.objective, rel=1e-6)
