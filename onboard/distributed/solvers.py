"""Synchronous discrete-time runs of the estimation flows (paper 002 eq. 7-8 with
:mod:`.flow`'s update): every agent updates from its neighbours' states of the previous round.

Each solver returns the final states and a per-round history of the total cost ``phi`` (eq. 5).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from onboard.distributed.flow import (
    check_edges,
    lipschitz_step,
    mask_gradient,
    max_degree,
    momentum_weight,
    node_gradient,
    project_lower,
    so2_step,
    so3_step,
)
from onboard.distributed.localization import (
    LAMBDA_MIN,
    localization_costs,
    localization_gradients,
    localization_steps,
)
from onboard.distributed.reshaping import F_D, F_R, ReshapeD, ReshapeR
from onboard.distributed.rotation import rotation_costs, rotation_gradients, rotation_lipschitz
from onboard.distributed.yaw import yaw_costs, yaw_gradients
from onboard.geometry import FloatArray


@dataclass(frozen=True)
class LocalizationResult:
    t: FloatArray
    """``(N, d)`` translations."""
    lam: FloatArray
    """``(E,)`` edge scales."""
    cost: FloatArray
    """``(rounds + 1,)`` total cost before each round and at the end."""
    lam_min_seen: float
    """Smallest ``lambda_ij`` over the whole run (eq. 17 says ``>= 1`` when constrained)."""
    rounds: int
    """Rounds run (fewer than asked when the gradient fell below ``grad_tol``)."""


@dataclass(frozen=True)
class RotationResult:
    rot: FloatArray
    """``(N, 3, 3)`` body-to-world rotations."""
    cost: FloatArray
    rounds: int


@dataclass(frozen=True)
class YawResult:
    psi_rad: FloatArray
    """``(N,)`` yaws in ``[-pi, pi)``."""
    cost: FloatArray
    rounds: int


def localize(
    edges: ArrayLike,
    u_world: ArrayLike,
    t0: ArrayLike,
    lam0: ArrayLike,
    rounds: int,
    ranges_m: ArrayLike | None = None,
    f_d: ReshapeD = F_D,
    safety: float = 1.0,
    anchor: int | None = None,
    grad_tol: float = 0.0,
    record_cost: bool = True,
    accelerated: bool = True,
) -> LocalizationResult:
    """Bearing-only (``ranges_m is None``: ``lambda >= 1``, eq. 16-17) or bearing + distance
    (eq. 22, unconstrained) localization by projected gradient descent with the per-agent steps of
    :func:`onboard.distributed.localization.localization_steps` (``safety <= 1`` scales them).

    ``accelerated`` (default): the step is taken from the extrapolated point of
    :func:`onboard.distributed.flow.momentum_weight` (the cost is convex with the shipped ``f_D``;
    a non-convex ``f_D`` voids the guarantee). Without it, plain projected descent, whose cost
    falls every round but whose weak scale mode takes tens of thousands of rounds
    (docs/distributed.md). The states stay feasible (``lambda >= 1``) every round; only the
    extrapolated point where the gradient is read may lie outside. ``grad_tol`` stops on the
    projected gradient at that point. ``record_cost=False`` leaves the per-round costs ``nan``
    (only the final one is computed)."""
    t = np.array(t0, dtype=float)
    lam = np.array(lam0, dtype=float).reshape(-1)
    e = check_edges(edges, len(t))
    u = np.asarray(u_world, dtype=float)
    lower = LAMBDA_MIN if ranges_m is None else None
    lam = project_lower(lam, lower)
    h_t, h_l = localization_steps(e, len(t), f_d, t.shape[1])
    h_t, h_l = safety * h_t[:, None], safety * h_l
    mask = None
    if anchor is not None:
        mask = np.zeros(len(t), dtype=bool)
        mask[anchor] = True
    cost = np.empty(rounds + 1)
    lam_min = float(lam.min()) if lam.size else np.inf
    t_prev, lam_prev = t, lam
    for k in range(rounds):
        cost[k] = (
            float(np.sum(localization_costs(t, lam, e, u, ranges_m, f_d=f_d)))
            if record_cost
            else np.nan
        )
        w = momentum_weight(k) if accelerated else 0.0
        yt, yl = t + w * (t - t_prev), lam + w * (lam - lam_prev)
        g = localization_gradients(yt, yl, e, u, ranges_m, f_d=f_d)
        gt = mask_gradient(node_gradient(e, len(t), g), mask)
        assert g.g_edge is not None
        g_l = g.g_edge
        if lower is not None:  # the projected gradient: zero where the constraint is active
            g_l = np.where((yl <= lower) & (g_l > 0), 0.0, g_l)
        if grad_tol > 0 and max(np.abs(gt).max(), np.abs(g_l).max()) < grad_tol:
            rounds = k
            break
        t_prev, lam_prev = t, lam
        t = yt - h_t * gt
        lam = project_lower(yl - h_l * g.g_edge, lower)
        lam_min = min(lam_min, float(lam.min()))
    cost[rounds] = float(np.sum(localization_costs(t, lam, e, u, ranges_m, f_d=f_d)))
    return LocalizationResult(
        t=t, lam=lam, cost=cost[: rounds + 1], lam_min_seen=lam_min, rounds=rounds
    )


def estimate_rotations(
    edges: ArrayLike,
    rel_meas: ArrayLike,
    rot0: ArrayLike,
    rounds: int,
    f: ReshapeR = F_R,
    safety: float = 1.0,
    anchor: int | None = None,
    grad_tol: float = 0.0,
) -> RotationResult:
    """Rotation estimation (eq. 13-15) by gradient descent on SO(3), exponential-map steps."""
    rot = np.array(rot0, dtype=float)
    e = check_edges(edges, len(rot))
    rm = np.asarray(rel_meas, dtype=float)
    rot, cost, rounds = _rotation_descent(
        rot, e, lambda x: rotation_costs(x, e, rm, f), lambda x: rotation_gradients(x, e, rm, f),
        so3_step, f, safety, anchor, rounds, grad_tol,
    )  # fmt: skip
    return RotationResult(rot=rot, cost=cost, rounds=rounds)


def _rotation_descent(
    x: np.ndarray,
    e: np.ndarray,
    costs: Callable[[np.ndarray], np.ndarray],
    edge_gradients: Callable[[np.ndarray], np.ndarray],
    step: Callable[[np.ndarray, np.ndarray, float], np.ndarray],
    f: ReshapeR,
    safety: float,
    anchor: int | None,
    rounds: int,
    grad_tol: float,
) -> tuple[np.ndarray, np.ndarray, int]:
    """The descent both rotation solvers run (eq. 13-15): ``rounds`` steps of ``step`` with
    ``h k = safety / L``, the ``anchor`` agent held, stopping early below ``grad_tol``;
    returns the final states, the cost before each step and after the last, and the rounds."""
    hk = lipschitz_step(rotation_lipschitz(f, max_degree(e, len(x))), safety)
    mask = None
    if anchor is not None:
        mask = np.zeros(len(x), dtype=bool)
        mask[anchor] = True
    cost = np.empty(rounds + 1)
    for k in range(rounds):
        cost[k] = float(np.sum(costs(x)))
        g = mask_gradient(node_gradient(e, len(x), edge_gradients(x)), mask)
        if grad_tol > 0 and np.abs(g).max() < grad_tol:
            rounds = k
            break
        x = step(x, g, hk)
    cost[rounds] = float(np.sum(costs(x)))
    return x, cost[: rounds + 1], rounds


def estimate_yaws(
    edges: ArrayLike,
    psi_meas_rad: ArrayLike,
    psi0_rad: ArrayLike,
    rounds: int,
    f: ReshapeR = F_R,
    safety: float = 1.0,
    anchor: int | None = None,
    grad_tol: float = 0.0,
) -> YawResult:
    """Yaw-only rotation estimation (paper 002 eq. 13-15 on SO(2), :mod:`onboard.distributed.yaw`):
    :func:`estimate_rotations` with ``R_z`` rotations, angle-addition steps
    (:func:`onboard.distributed.flow.so2_step`) and the same step rule ``h k = safety / L``.
    ``edges`` ``(E, 2)``, ``psi_meas_rad`` ``(E,)`` (``psi_j - psi_i``), ``psi0_rad`` ``(N,)``."""
    psi = np.array(psi0_rad, dtype=float).reshape(-1)
    e = check_edges(edges, len(psi))
    pm = np.asarray(psi_meas_rad, dtype=float).reshape(-1)
    psi, cost, rounds = _rotation_descent(
        psi, e, lambda x: yaw_costs(x, e, pm, f), lambda x: yaw_gradients(x, e, pm, f),
        so2_step, f, safety, anchor, rounds, grad_tol,
    )  # fmt: skip
    return YawResult(psi_rad=psi, cost=cost, rounds=rounds)
