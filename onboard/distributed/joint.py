"""Joint rotation + bearing localization: the third stage of paper 002's mutual localization
(eq. 13 plus eq. 16, rotations, translations and scales together), and the three-stage run.

Measurements per directed edge ``(i, j)``: the relative rotation ``Rt_ij`` (estimates
``R_i^T R_j``) and the unit bearing ``beta_ij`` to ``j`` in ``i``'s body frame. The bearings in the
world now depend on the estimated rotations, ``u_ij = R_i beta_ij`` (paper 002 eq. 16 writes
``R_i^T t~_ij`` with its world-to-body ``R_i``). Pairwise cost::

    phi_ij = w_R f_R(d(R_i^T R_j, Rt_ij)) + f_T(|r_ij|),   r_ij = T_j - T_i - lambda_ij R_i beta_ij

with ``lambda_ij >= 1`` (eq. 17). Both terms and their gradients in ``T`` and ``lambda`` are those
of :mod:`.rotation` and :mod:`.localization`, evaluated at ``u = R_i beta``; the new piece is the
gradient of the translation term in ``R_i`` (body coordinates ``R_i exp(hat(delta))``):
``exp(hat(delta)) beta ~ beta - hat(beta) delta``, so ``dr/d delta = lambda R_i hat(beta)`` and

    grad_{delta_i} f_T(|r|) = lambda hat(beta)^T R_i^T g_r = lambda (R_i^T g_r) x beta,

with ``g_r = f_T'(|r|) / |r| r`` (the ``T_j`` gradient of :func:`.localization_gradients`).

Steps (:func:`joint_steps`): per variable, the inverse of a block Gershgorin row sum of the
Hessian at the current state (each agent computes its own from its edges): the translation
Jacobian of an edge is ``[I, -I, -u, lambda R_i hat(beta)]`` in ``(T_j, T_i, lambda, delta_i)``,
so ``2 A^T A`` contributes ``2 a_X (3 + lambda)`` to the row of a block of norm ``a_X``, plus the
curvature of ``exp`` (``2 lambda |r|`` in ``delta``, ``2 |r|`` between ``delta`` and ``lambda``),
plus ``2 w_R c_f`` per incident rotation edge (:func:`.rotation_lipschitz`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from onboard.distributed.flow import check_edges, node_gradient, project_lower, so3_step
from onboard.distributed.localization import (
    LAMBDA_MIN,
    localization_costs,
    localization_gradients,
)
from onboard.distributed.reshaping import F_R, F_T, ReshapeR, ReshapeT
from onboard.distributed.rotation import rotation_costs, rotation_gradients
from onboard.distributed.solvers import (
    LocalizationResult,
    RotationResult,
    estimate_rotations,
    localize,
)
from onboard.geometry import FloatArray


def world_bearings(rot: ArrayLike, edges: ArrayLike, beta_body: ArrayLike) -> FloatArray:
    """``u_ij = R_i beta_ij`` per edge: ``(E, 3)`` (``rot`` body to world)."""
    r = np.asarray(rot, dtype=float)
    e = check_edges(edges, len(r))
    return np.einsum("eab,eb->ea", r[e[:, 0]], np.asarray(beta_body, dtype=float))


def joint_costs(
    rot: ArrayLike,
    t: ArrayLike,
    lam: ArrayLike,
    edges: ArrayLike,
    rel_meas: ArrayLike,
    beta_body: ArrayLike,
    w_rot: float = 1.0,
    f_r: ReshapeR = F_R,
    f_t: ReshapeT = F_T,
) -> FloatArray:
    """``phi_ij = w_R f_R(theta_ij) + f_T(|r_ij|)`` per edge (paper 002 eq. 13 + 16): ``(E,)``."""
    u = world_bearings(rot, edges, beta_body)
    return w_rot * rotation_costs(rot, edges, rel_meas, f_r) + localization_costs(
        t, lam, edges, u, f_t=f_t
    )


@dataclass(frozen=True)
class JointGradients:
    """Per-agent and per-edge gradients of ``sum phi_ij`` (eq. 7-8 assembled)."""

    g_rot: FloatArray
    """``(N, 3)`` body coordinates ``R_i exp(hat(delta_i))``."""
    g_t: FloatArray
    """``(N, 3)``."""
    g_lam: FloatArray
    """``(E,)``."""


def joint_gradients(
    rot: ArrayLike,
    t: ArrayLike,
    lam: ArrayLike,
    edges: ArrayLike,
    rel_meas: ArrayLike,
    beta_body: ArrayLike,
    w_rot: float = 1.0,
    f_r: ReshapeR = F_R,
    f_t: ReshapeT = F_T,
) -> JointGradients:
    """Gradients of paper 002 eq. 13 + 16 (module docstring), each agent summing its edges."""
    r = np.asarray(rot, dtype=float)
    e = check_edges(edges, len(r))
    beta = np.asarray(beta_body, dtype=float)
    lm = np.asarray(lam, dtype=float)
    n = len(r)
    g_r = rotation_gradients(r, e, rel_meas, f_r)
    g_rot = w_rot * node_gradient(e, n, g_r)
    g_l = localization_gradients(t, lm, e, world_bearings(r, e, beta), f_t=f_t)
    g_t = node_gradient(e, n, g_l)
    body = np.einsum("eba,eb->ea", r[e[:, 0]], g_l.g_dst)  # R_i^T g_r
    g_src_rot = lm[:, None] * np.cross(body, beta)
    g_rot = g_rot + np.stack(
        [np.bincount(e[:, 0], weights=g_src_rot[:, k], minlength=n) for k in range(3)], axis=1
    )
    assert g_l.g_edge is not None
    return JointGradients(g_rot=g_rot, g_t=g_t, g_lam=g_l.g_edge)


def joint_steps(
    rot: ArrayLike,
    t: ArrayLike,
    lam: ArrayLike,
    edges: ArrayLike,
    beta_body: ArrayLike,
    w_rot: float = 1.0,
    f_r: ReshapeR = F_R,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Per-variable steps ``(h_rot (N,), h_t (N,), h_lam (E,))``: inverse block Gershgorin row
    sums of the Hessian of eq. 13 + 16 at the current state (module docstring), ``f_T = x^2``."""
    r = np.asarray(rot, dtype=float)
    e = check_edges(edges, len(r))
    lm = np.asarray(lam, dtype=float)
    tt = np.asarray(t, dtype=float)
    u = world_bearings(r, e, beta_body)
    res = np.linalg.norm(tt[e[:, 1]] - tt[e[:, 0]] - lm[:, None] * u, axis=1)
    n = len(r)
    row_t = 2.0 * (3.0 + lm)
    d_t = np.bincount(e[:, 0], weights=row_t, minlength=n) + np.bincount(
        e[:, 1], weights=row_t, minlength=n
    )
    d_lam = 2.0 * (3.0 + lm) + 2.0 * res
    row_rot = 2.0 * lm * (3.0 + lm) + 2.0 * lm * res + 2.0 * res
    deg = np.bincount(e.ravel(), minlength=n).astype(float)
    d_rot = np.bincount(e[:, 0], weights=row_rot, minlength=n) + 2.0 * w_rot * (
        f_r.curvature_bound() * deg
    )
    return 1.0 / np.maximum(d_rot, 1e-12), 1.0 / np.maximum(d_t, 1e-12), 1.0 / d_lam


@dataclass(frozen=True)
class JointResult:
    rot: FloatArray
    """``(N, 3, 3)`` body-to-world rotations."""
    t: FloatArray
    """``(N, 3)`` translations."""
    lam: FloatArray
    """``(E,)`` edge scales."""
    cost: FloatArray
    """``(rounds + 1,)`` total cost of eq. 13 + 16 before each round and at the end."""
    lam_min_seen: float
    """Smallest ``lambda_ij`` over the run (``>= 1`` by the projection of eq. 17)."""
    rounds: int


def localize_joint(
    edges: ArrayLike,
    rel_meas: ArrayLike,
    beta_body: ArrayLike,
    rot0: ArrayLike,
    t0: ArrayLike,
    lam0: ArrayLike,
    rounds: int,
    w_rot: float = 1.0,
    f_r: ReshapeR = F_R,
    safety: float = 1.0,
    grad_tol: float = 0.0,
) -> JointResult:
    """Projected gradient descent on eq. 13 + 16 over ``(R, T, lambda)`` (paper 002's third
    stage): synchronous rounds, ``R_i <- R_i exp(-h hat(g_i))``, ``T <- T - h g``,
    ``lambda <- max(lambda - h g, 1)``, with the per-variable steps of :func:`joint_steps`
    (``safety <= 1`` scales them). Plain descent (the cost is not convex in ``R``)."""
    if not 0 < safety <= 1.0:
        raise ValueError("safety must be in (0, 1]")
    rot = np.array(rot0, dtype=float)
    e = check_edges(edges, len(rot))
    rm = np.asarray(rel_meas, dtype=float)
    beta = np.asarray(beta_body, dtype=float)
    t = np.array(t0, dtype=float)
    lam = project_lower(np.array(lam0, dtype=float).reshape(-1), LAMBDA_MIN)
    lam_min = float(lam.min()) if lam.size else np.inf
    cost = np.empty(rounds + 1)
    for k in range(rounds):
        cost[k] = float(np.sum(joint_costs(rot, t, lam, e, rm, beta, w_rot, f_r)))
        g = joint_gradients(rot, t, lam, e, rm, beta, w_rot, f_r)
        g_l = np.where((lam <= LAMBDA_MIN) & (g.g_lam > 0), 0.0, g.g_lam)
        if grad_tol > 0 and max(np.abs(g.g_rot).max(), np.abs(g.g_t).max(), np.abs(g_l).max()) < (
            grad_tol
        ):
            rounds = k
            break
        h_r, h_t, h_l = joint_steps(rot, t, lam, e, beta, w_rot, f_r)
        rot = so3_step(rot, safety * h_r[:, None] * g.g_rot, 1.0)
        t = t - safety * h_t[:, None] * g.g_t
        lam = project_lower(lam - safety * h_l * g.g_lam, LAMBDA_MIN)
        lam_min = min(lam_min, float(lam.min()))
    cost[rounds] = float(np.sum(joint_costs(rot, t, lam, e, rm, beta, w_rot, f_r)))
    return JointResult(
        rot=rot, t=t, lam=lam, cost=cost[: rounds + 1], lam_min_seen=lam_min, rounds=rounds
    )


@dataclass(frozen=True)
class MutualResult:
    """The three stages of paper 002's mutual localization."""

    rotations: RotationResult
    """Stage 1: rotations alone (eq. 13-15)."""
    translations: LocalizationResult
    """Stage 2: translations and scales, rotations fixed (eq. 16-17)."""
    joint: JointResult
    """Stage 3: all variables (eq. 13 + 16)."""


def mutual_localization(
    edges: ArrayLike,
    rel_meas: ArrayLike,
    beta_body: ArrayLike,
    rot0: ArrayLike,
    t0: ArrayLike,
    lam0: ArrayLike,
    rounds: tuple[int, int, int],
    w_rot: float = 1.0,
    f_r: ReshapeR = F_R,
    grad_tol: float = 0.0,
) -> MutualResult:
    """Paper 002's three stages from relative poses only: :func:`estimate_rotations`, then
    :func:`localize` with ``u = R_i beta_ij`` from stage 1's rotations, then
    :func:`localize_joint` from stage 2's result. ``rounds``: per stage."""
    e = check_edges(edges, len(np.asarray(rot0)))
    rot = estimate_rotations(e, rel_meas, rot0, rounds[0], f_r, grad_tol=grad_tol)
    u = world_bearings(rot.rot, e, beta_body)
    loc = localize(e, u, t0, lam0, rounds[1], grad_tol=grad_tol)
    joint = localize_joint(
        e, rel_meas, beta_body, rot.rot, loc.t, loc.lam, rounds[2], w_rot, f_r, grad_tol=grad_tol
    )
    return MutualResult(rotations=rot, translations=loc, joint=joint)
