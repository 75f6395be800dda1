"""Landmark placement planner (paper 004): where to put a few well-localized vehicles so the
others, localizing by bearings to them, are as certain as possible at their setpoints.

Modules: ``problem`` (data, validation, numpy evaluation), ``symbolic`` (casadi expressions),
``hessian`` (the structured exact Hessian of eq. 11), ``ipopt`` (Problem 3, the main method),
``greedy`` and ``isres`` (baselines), ``setpoints`` (TOML files), ``plot`` (figure),
``validation`` (EKF along a mission: planned vs random landmarks), ``team`` (paper 004
Fig. 9: a team of missions planned for together). Solvers import casadi /
nlopt / matplotlib lazily.
"""

from __future__ import annotations

from groundstation.planner.problem import (
    PlacementProblem,
    PlacementResult,
    PlannerError,
    ProblemError,
    make_problem,
)

__all__ = ["PlacementProblem", "PlacementResult", "PlannerError", "ProblemError", "make_problem"]
