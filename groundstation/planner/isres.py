"""Evolutionary landmark placement with ISRES (the global baseline of paper 004, Section VI).

Improved Stochastic Ranking Evolution Strategy (Runarsson and Yao, paper 004 ref. [60]) as
implemented in NLopt (``GN_ISRES``), applied directly to the minimax Problem 2: the objective is
``max_i tr(Sigma_delta(x_i; z))`` and every constraint of :func:`constraint_values` is passed as
an inequality (the field-of-view variant adds the free headings as variables). Objective and
constraints are evaluated together by the compiled casadi function of
:func:`objective_and_constraints` (NLopt asks for them one after the other at the same point). The variables
are boxed by ``|z_jk| <= R_max`` (and headings in ``[-pi, pi]``). The budget is a number of
objective evaluations; NLopt's random generator is seeded for reproducibility.

nlopt is imported inside the function so that importing this module stays cheap.
"""

from __future__ import annotations

import time

import numpy as np

from groundstation.planner.problem import (
    FEASIBILITY_TOL,
    PlacementProblem,
    PlacementResult,
    PlannerError,
    constraint_violation,
    headings_for,
    initial_headings,
    random_feasible_landmarks,
    result_from_landmarks,
)
from groundstation.planner.symbolic import objective_and_constraints, parameter_values

DEFAULT_EVALS_PER_VARIABLE = 1000
"""Default budget: objective evaluations per decision variable."""

DEFAULT_POPULATION = 20
"""Population size. NLopt's default ``20 (n + 1)`` converges far too slowly for the budgets a
single core affords (at M = 10, 30000 evaluations reach a worst trace ~40% higher than with 20)."""


def solve_isres(
    problem: PlacementProblem,
    *,
    seed: int = 0,
    max_evals: int | None = None,
    population: int = DEFAULT_POPULATION,
) -> PlacementResult:
    """Minimize the worst trace with NLopt's ISRES from a seeded random feasible start.

    ``max_evals`` defaults to :data:`DEFAULT_EVALS_PER_VARIABLE` per variable; ``population``
    0 restores NLopt's default ``20 (n + 1)``. Raises :class:`PlannerError` if the best point is
    infeasible (ISRES treats constraints as penalties and may end slightly outside).
    """
    import nlopt

    t_start = time.perf_counter()
    dims = 2 if problem.planar else 3
    m = problem.n_landmarks
    free = problem.free_headings
    n_z = dims * m
    n_var = n_z + int(np.sum(free))
    budget = DEFAULT_EVALS_PER_VARIABLE * n_var if max_evals is None else int(max_evals)

    def unpack(w: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        z = w[:n_z].reshape(m, dims)
        if problem.planar:
            z = np.column_stack([z, np.full(m, problem.ground_down_m)])
        psi = headings_for(problem, w[n_z:]) if problem.fov_rad is not None else None
        return z, psi

    fg = objective_and_constraints(problem)
    pv = parameter_values(problem, 1.0)
    last: dict[str, np.ndarray] = {}

    def evaluate(w: np.ndarray) -> np.ndarray:
        if "w" not in last or not np.array_equal(last["w"], w):
            f, g = fg(w, pv)
            last["w"] = w.copy()
            last["fg"] = np.concatenate([np.asarray(f).ravel(), np.asarray(g).ravel()])
        return last["fg"]

    def objective(w: np.ndarray, grad: np.ndarray) -> float:
        return float(evaluate(w)[0])

    def constraints(result: np.ndarray, w: np.ndarray, grad: np.ndarray) -> None:
        result[:] = evaluate(w)[1:]

    rng = np.random.default_rng(seed)
    z0 = random_feasible_landmarks(problem, rng)
    w0 = np.concatenate([z0[:, :dims].ravel(), initial_headings(problem, z0)])
    n_con = int(fg.size1_out(1))

    opt = nlopt.opt(nlopt.GN_ISRES, n_var)
    bound = np.concatenate([np.full(n_z, problem.r_max_m), np.full(n_var - n_z, np.pi)])
    opt.set_lower_bounds(-bound)
    opt.set_upper_bounds(bound)
    opt.set_min_objective(objective)
    opt.add_inequality_mconstraint(constraints, np.full(n_con, 1e-9))
    opt.set_maxeval(budget)
    if population > 0:
        opt.set_population(int(population))
    nlopt.srand(int(seed))
    try:
        w = opt.optimize(w0)
    except (nlopt.RoundoffLimited, RuntimeError, ValueError) as exc:
        raise PlannerError(f"isres failed: {type(exc).__name__}: {exc}") from None
    z, psi = unpack(np.asarray(w))
    violation = constraint_violation(problem, z, psi)
    if violation > FEASIBILITY_TOL:
        raise PlannerError(
            f"isres ended infeasible (violation {violation:.2e}) after {budget} evaluations"
        )
    details = {
        "evaluations": int(opt.get_numevals()),
        "budget": budget,
        "status": opt.last_optimize_result(),
    }
    return result_from_landmarks(problem, "isres", z, time.perf_counter() - t_start, psi, details)
