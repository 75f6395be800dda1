"""Rotation estimation from relative rotations (paper 002 eq. 13-15), on SO(3).

Project convention (docs/equations.md, "Conventions"): ``R_i`` maps body to world, the relative
rotation is ``iR_j = R_i^T R_j`` (paper 002 eq. 2 writes ``R_i R_j^T`` with ``R_i`` world to body:
the same quantity). The measurement ``Rt_ij`` (``(E, 3, 3)``) estimates ``iR_j``; the pairwise cost
(eq. 13) is

    phi_ij = f_R(theta_ij),   theta_ij = d(R_i^T R_j, Rt_ij) = |w_ij|,   w_ij = log(Rt_ij^T R_i^T R_j).

Gradients in the body coordinates ``R exp(hat(delta))`` (right perturbation of ``R_j``, left
perturbation ``exp(-hat(Rt^T delta_i))`` of the error for ``R_i``; ``w^T J^{-1}(w) = w^T`` for both
Jacobians of the log)::

    grad_{delta_j} phi_ij = (f_R'(theta) / theta) w_ij,
    grad_{delta_i} phi_ij = -(f_R'(theta) / theta) Rt_ij w_ij,

with ``f_R'(x) / x = b^2 exp(-b x)`` for eq. 15 (smooth at 0). The flow is discretized by
:func:`onboard.distributed.flow.so3_step`. The global rotation is unobservable (a gauge): hold one
agent fixed as an anchor (leader mask) or compare modulo it (:mod:`.metrics`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from onboard.distributed.flow import EdgeGradients, check_edges
from onboard.distributed.reshaping import F_R, ReshapeR
from onboard.geometry import FloatArray, so3_log


def _errors(rot: FloatArray, edges: np.ndarray, rel_meas: FloatArray) -> FloatArray:
    ri, rj = rot[edges[:, 0]], rot[edges[:, 1]]
    return so3_log(np.swapaxes(rel_meas, -1, -2) @ np.swapaxes(ri, -1, -2) @ rj)


def rotation_costs(
    rot: ArrayLike, edges: ArrayLike, rel_meas: ArrayLike, f: ReshapeR = F_R
) -> FloatArray:
    """``phi_ij = f_R(d(R_i^T R_j, Rt_ij))`` per edge (paper 002 eq. 13, 15): ``(E,)``.

    ``rot`` ``(N, 3, 3)`` body-to-world, ``rel_meas`` ``(E, 3, 3)``."""
    r = np.asarray(rot, dtype=float)
    e = check_edges(edges, len(r))
    w = _errors(r, e, np.asarray(rel_meas, dtype=float))
    return f.value(np.linalg.norm(w, axis=-1))


def rotation_gradients(
    rot: ArrayLike, edges: ArrayLike, rel_meas: ArrayLike, f: ReshapeR = F_R
) -> EdgeGradients:
    """Body-coordinate gradients of eq. 13 per edge: ``g_src, g_dst`` ``(E, 3)``."""
    r = np.asarray(rot, dtype=float)
    e = check_edges(edges, len(r))
    rm = np.asarray(rel_meas, dtype=float)
    w = _errors(r, e, rm)
    scale = f.deriv_over_x(np.linalg.norm(w, axis=-1))[:, None]
    g_dst = scale * w
    g_src = -np.einsum("eab,eb->ea", rm, g_dst)
    return EdgeGradients(g_src=g_src, g_dst=g_dst)


def rotation_lipschitz(f: ReshapeR, max_degree: int) -> float:
    """Gershgorin bound ``L = 2 c_f deg_max`` on the Hessian of ``sum phi_ij``: each edge's Hessian
    in ``(delta_i, delta_j)`` is bounded by ``c_f = max(|f''|, |f'/x|)`` per block
    (:meth:`ReshapeR.curvature_bound`), and an agent's block row touches ``deg`` edges twice."""
    return 2.0 * f.curvature_bound() * max(max_degree, 1)


def relative_rotations(rot: ArrayLike, edges: ArrayLike) -> FloatArray:
    """Ideal measurements ``iR_j = R_i^T R_j`` per edge: ``(E, 3, 3)``."""
    r = np.asarray(rot, dtype=float)
    e = check_edges(edges, len(r))
    return np.swapaxes(r[e[:, 0]], -1, -2) @ r[e[:, 1]]
