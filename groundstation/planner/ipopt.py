"""Landmark placement by interior point (paper 004 Problem 3, solved with IPOPT through casadi).

The minimax Problem 2 is written in epigraph form (Problem 3):

    min t  s.t.  tr(Sigma_delta(x_i; z)) <= t,  |z_j| <= R_max,  |z_j - x_i| >= R_min,

plus, for the field-of-view variant, the cone constraints of eq. 20 with one heading variable
per free setpoint. casadi builds the expressions symbolically and hands IPOPT exact first and
second derivatives (the paper passes the analytic ones of eq. 10-11): the constraint Jacobian by
automatic differentiation, the Hessian of the Lagrangian in the chain-rule form of eq. 11
(:mod:`groundstation.planner.hessian`), which is exact and cheaper than differentiating twice. The problem is non-convex (paper Fig. 4), so
the solver is restarted from ``starts`` seeded random feasible points and the best result is
kept. Traces are divided by their value at the first starting point so that ``t`` is O(1).

casadi is imported inside the functions so that importing this module stays cheap.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from groundstation.planner.hessian import lagrangian_hessian
from groundstation.planner.problem import (
    FEASIBILITY_TOL,
    PlacementProblem,
    PlacementResult,
    PlannerError,
    constraint_violation,
    headings_for,
    initial_headings,
    landmark_traces,
    random_feasible_landmarks,
    result_from_landmarks,
)
from groundstation.planner.symbolic import (
    Params,
    decision_symbols,
    landmark_dims,
    parameter_values,
    shape_key,
    symbolic_constraints,
    symbolic_landmarks,
    symbolic_traces,
)

ACCEPTED_STATUSES = ("Solve_Succeeded", "Solved_To_Acceptable_Level")


@dataclass(frozen=True)
class _Nlp:
    solver: Any
    n_z: int
    lbx_psi: np.ndarray


DERIVATIVES = ("nlp_grad_f", "nlp_jac_g", "nlp_hess_l")
"""The functions IPOPT evaluates at every iteration, and the ``nlpsol`` options that take them."""
DERIVATIVE_OPTIONS = ("grad_f", "jac_g", "hess_lag")


def _build(
    problem: PlacementProblem,
    max_iter: int,
    structured_hessian: bool = True,
    compiled: bool = False,
    cache_dir: Path | None = None,
) -> _Nlp:
    """Problem 3 (and eq. 19-20) as a casadi ``nlpsol`` with IPOPT and exact Hessians.

    With ``structured_hessian`` the Hessian of the Lagrangian is the chain-rule form of eq. 11
    (:mod:`groundstation.planner.hessian`, about 30% fewer operations and a faster build);
    without it casadi differentiates the trace expressions twice. Both are exact. With
    ``compiled`` the gradient, the constraint Jacobian and the Hessian are the same functions
    compiled to C (:mod:`groundstation.planner.compiled`).
    """
    import casadi as ca

    par, v = Params.symbols(problem.n_setpoints)
    t = ca.SX.sym("t")
    z_vars, psi_vars = decision_symbols(problem)
    landmarks = symbolic_landmarks(problem, z_vars, par)
    g = [tr / par.scale - t for tr in symbolic_traces(problem, landmarks, par)]
    g += symbolic_constraints(problem, landmarks, psi_vars, par)
    w = ca.vertcat(t, z_vars, psi_vars)
    g_all = ca.vertcat(*g)
    opts: dict[str, Any] = {
        "print_time": False,
        "ipopt.print_level": 0,
        "ipopt.sb": "yes",
        "ipopt.max_iter": int(max_iter),
        # Trust MUMPS' solution of the 151 x 151 KKT system (N = M = 10) instead of computing
        # its residual at every step: 8% less CPU per solve at M = 10, same minima (interleaved
        # A/B over 36 solves; docs/planner.md). Every result is re-checked with numpy anyway.
        "ipopt.fast_step_computation": "yes",
    }
    if structured_hessian:
        opts["hess_lag"] = lagrangian_hessian(problem, w, z_vars, par, v, g_all)
    nlp = {"x": w, "p": v, "f": t, "g": g_all}
    solver = ca.nlpsol("landmarks", "ipopt", nlp, opts)
    if compiled:
        from groundstation.planner.compiled import compile_functions

        functions = compile_functions(
            [solver.get_function(name) for name in DERIVATIVES], cache_dir=cache_dir
        )
        opts.update(zip(DERIVATIVE_OPTIONS, functions, strict=True))
        solver = ca.nlpsol("landmarks", "ipopt", nlp, opts)
    return _Nlp(solver, int(z_vars.numel()), np.full(int(psi_vars.numel()), -np.inf))


class IpoptPlacer:
    """IPOPT placement with its compiled solvers kept for problems of the same shape.

    Building the casadi expressions and their exact Hessian costs more than one solve for
    small problems; a placer reuses the solver when only the numbers (setpoints, noise,
    radii, fixed headings) change. :func:`solve_ipopt` uses a fresh placer (cold start).
    With ``compiled`` its derivatives are compiled to C the first time a shape is seen (or
    loaded from ``cache_dir``): each solve is then about 1.8x faster.
    """

    def __init__(
        self,
        max_iter: int = 3000,
        *,
        structured_hessian: bool = True,
        compiled: bool = False,
        cache_dir: Path | None = None,
    ) -> None:
        self.max_iter = int(max_iter)
        self.structured_hessian = bool(structured_hessian)
        self.compiled = bool(compiled)
        self.cache_dir = cache_dir
        self._solvers: dict[tuple[object, ...], _Nlp] = {}

    def _nlp(self, problem: PlacementProblem) -> _Nlp:
        key = shape_key(problem)
        if key not in self._solvers:
            self._solvers[key] = _build(
                problem, self.max_iter, self.structured_hessian, self.compiled, self.cache_dir
            )
        return self._solvers[key]

    def prepare(self, problem: PlacementProblem) -> None:
        """Build (and compile, if asked) the solver for ``problem``'s shape ahead of a solve."""
        self._nlp(problem)

    def solve(
        self, problem: PlacementProblem, *, seed: int = 0, starts: int = 5
    ) -> PlacementResult:
        """Best of ``starts`` IPOPT runs on Problem 3 from seeded random feasible points.

        A run counts only if IPOPT reports success and the returned point satisfies every
        constraint to :data:`FEASIBILITY_TOL` when checked again with numpy. Raises
        :class:`PlannerError` naming the IPOPT statuses if no run counts.
        """
        if starts < 1:
            raise ValueError("starts must be at least 1")
        t_start = time.perf_counter()
        rng = np.random.default_rng(seed)
        nlp = self._nlp(problem)
        dims = landmark_dims(problem)
        r_max = problem.r_max_m
        lbx = np.concatenate([[0.0], np.full(nlp.n_z, -r_max), nlp.lbx_psi])
        ubx = np.concatenate([[np.inf], np.full(nlp.n_z, r_max), -nlp.lbx_psi])
        best: tuple[float, np.ndarray, np.ndarray | None] | None = None
        statuses: list[str] = []
        iterations = 0
        scale = 0.0
        pv = np.zeros(0)
        for _ in range(starts):
            z0 = random_feasible_landmarks(problem, rng)
            traces0 = landmark_traces(problem, z0)
            if scale == 0.0:
                scale = float(np.max(traces0))
                pv = parameter_values(problem, scale)
            t0 = [np.max(traces0) / scale]
            x0 = np.concatenate([t0, z0[:, :dims].ravel(), initial_headings(problem, z0)])
            sol = nlp.solver(x0=x0, p=pv, lbx=lbx, ubx=ubx, lbg=-np.inf, ubg=0.0)
            stats = nlp.solver.stats()
            status = str(stats.get("return_status", "unknown"))
            statuses.append(status)
            iterations += int(stats.get("iter_count", 0))
            w = np.asarray(sol["x"]).ravel()
            z = w[1 : 1 + nlp.n_z].reshape(-1, dims)
            if problem.planar:
                z = np.column_stack([z, np.full(z.shape[0], problem.ground_down_m)])
            psi = None
            if problem.fov_rad is not None:
                psi = np.mod(headings_for(problem, w[1 + nlp.n_z :]) + np.pi, 2.0 * np.pi) - np.pi
            if status not in ACCEPTED_STATUSES or not np.all(np.isfinite(w)):
                continue
            if constraint_violation(problem, z, psi) > FEASIBILITY_TOL:
                statuses[-1] = f"{status} (but infeasible when re-checked)"
                continue
            objective = float(np.max(landmark_traces(problem, z)))
            if best is None or objective < best[0]:
                best = (objective, z, psi)
        if best is None:
            raise PlannerError(
                f"ipopt found no feasible placement in {starts} start(s): " + ", ".join(statuses)
            )
        details = {"starts": starts, "statuses": statuses, "iterations": iterations}
        seconds = time.perf_counter() - t_start
        return result_from_landmarks(problem, "ipopt", best[1], seconds, best[2], details)


def solve_ipopt(
    problem: PlacementProblem,
    *,
    seed: int = 0,
    starts: int = 5,
    max_iter: int = 3000,
    compiled: bool = False,
) -> PlacementResult:
    """Cold-start :meth:`IpoptPlacer.solve` (the reported time includes building the solver,
    and compiling it unless the cache holds it)."""
    return IpoptPlacer(max_iter, compiled=compiled).solve(problem, seed=seed, starts=starts)
