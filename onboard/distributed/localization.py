"""Bearing-only and bearing + distance localization (paper 002 eq. 16-17 and 22).

Rotations are known, so measured body bearings ``beta_ij`` are expressed in the world as
``u_ij = R_i beta_ij`` (paper 002 writes ``R_i^T t~_ij`` with its world-to-body ``R_i``). States:
translations ``T`` ``(N, d)`` and one scale ``lambda_ij`` per edge ``(E,)``. Pairwise cost
(eq. 16 with ``f_T(x) = x^2``, plus eq. 22 on the edges with a measured range ``lt_ij``)::

    phi_ij = f_T(|r_ij|) + [range] f_D(lambda_ij - lt_ij),   r_ij = T_j - T_i - lambda_ij u_ij

    grad_{T_j} = f_T'(|r|)/|r| r = 2 r,   grad_{T_i} = -2 r,
    grad_{lambda_ij} = -2 r . u_ij + [range] f_D'(lambda_ij - lt_ij).

Bearing-only: ``lambda_ij >= 1`` (eq. 17) by projection (``lambda_min = 1``), which fixes the
unobservable scale and excludes the trivial all-zero minimizer. With ranges the constraint is
removed (``lambda_min = None``), as the paper says. ``ranges_m`` holds ``nan`` on edges without a
range.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from onboard.distributed.flow import EdgeGradients, check_edges
from onboard.distributed.reshaping import F_D, F_T, ReshapeD, ReshapeT
from onboard.geometry import FloatArray

LAMBDA_MIN = 1.0
"""The scale constraint of paper 002 eq. 17."""


def _residuals(t: FloatArray, lam: FloatArray, e: np.ndarray, u: FloatArray) -> FloatArray:
    return t[e[:, 1]] - t[e[:, 0]] - lam[:, None] * u


def _ranges(ranges_m: ArrayLike | None, n_edges: int) -> FloatArray:
    if ranges_m is None:
        return np.full(n_edges, np.nan)
    r = np.asarray(ranges_m, dtype=float).reshape(-1)
    if r.shape != (n_edges,):
        raise ValueError(f"ranges_m must have one entry per edge ({n_edges})")
    return r


def localization_costs(
    t: ArrayLike,
    lam: ArrayLike,
    edges: ArrayLike,
    u_world: ArrayLike,
    ranges_m: ArrayLike | None = None,
    f_t: ReshapeT = F_T,
    f_d: ReshapeD = F_D,
) -> FloatArray:
    """``phi_ij`` of paper 002 eq. 16 (+ eq. 22) per edge: ``(E,)``."""
    tt = np.asarray(t, dtype=float)
    e = check_edges(edges, len(tt))
    lm = np.asarray(lam, dtype=float)
    r = _residuals(tt, lm, e, np.asarray(u_world, dtype=float))
    rg = _ranges(ranges_m, len(e))
    has = np.isfinite(rg)
    out = f_t.value(np.linalg.norm(r, axis=1))
    out[has] += f_d.value(lm[has] - rg[has])
    return out


def localization_gradients(
    t: ArrayLike,
    lam: ArrayLike,
    edges: ArrayLike,
    u_world: ArrayLike,
    ranges_m: ArrayLike | None = None,
    f_t: ReshapeT = F_T,
    f_d: ReshapeD = F_D,
) -> EdgeGradients:
    """Gradients of paper 002 eq. 16 (+ eq. 22): ``g_src, g_dst`` ``(E, d)``, ``g_edge`` ``(E,)``."""
    tt = np.asarray(t, dtype=float)
    e = check_edges(edges, len(tt))
    lm = np.asarray(lam, dtype=float)
    u = np.asarray(u_world, dtype=float)
    r = _residuals(tt, lm, e, u)
    g_dst = f_t.deriv_over_x(np.linalg.norm(r, axis=1))[:, None] * r
    g_edge = -np.sum(g_dst * u, axis=1)
    rg = _ranges(ranges_m, len(e))
    has = np.isfinite(rg)
    g_edge[has] += f_d.deriv(lm[has] - rg[has])
    return EdgeGradients(g_src=-g_dst, g_dst=g_dst, g_edge=g_edge)


def localization_lipschitz(max_degree: int, f_d: ReshapeD | None = None) -> float:
    """Gershgorin bound on the Hessian of eq. 16 (+ 22): ``2 ||A||_1 ||A||_inf + c_D`` with
    ``A`` the linear map ``(T, lambda) -> r``: rows have at most 3 unit entries, columns at most
    ``max(deg, 2)`` (a ``lambda`` column sums ``|u_k| <= sqrt(3)``)."""
    c_d = 0.0 if f_d is None else f_d.curvature_bound()
    return 2.0 * 3.0 * max(max_degree, 2) + c_d


def localization_steps(
    edges: np.ndarray, n_agents: int, f_d: ReshapeD | None = None, dim: int = 3
) -> tuple[FloatArray, FloatArray]:
    """Per-variable steps ``h k`` (Jacobi-scaled gradient descent): the inverse absolute row sums
    of the Hessian ``2 A^T A`` (+ ``f_D''``) of eq. 16 (+ 22). Agent ``i``: ``1 / (6 deg_i)``
    (``deg_i`` its incident edges); edge ``(i, j)``: ``1 / (2 + 4 sqrt(d) + c_D)``. The diagonal
    ``D`` of these row sums dominates the Hessian (``D - H`` is diagonally dominant), so the
    scaled step ``x <- x - D^{-1} g`` decreases ``phi`` every round, and every agent computes its
    own step from its own degree. Returns ``(h_T (N,), h_lambda (E,))``."""
    deg = np.bincount(edges.ravel(), minlength=n_agents).astype(float)
    c_d = 0.0 if f_d is None else f_d.curvature_bound()
    h_t = 1.0 / (6.0 * np.maximum(deg, 1.0))
    h_l = np.full(len(edges), 1.0 / (2.0 + 4.0 * np.sqrt(dim) + c_d))
    return h_t, h_l
