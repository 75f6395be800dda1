"""The generic distributed gradient flow of paper 002 (eq. 5-8) and its discrete update.

Graph: ``edges`` is an ``(E, 2)`` int array of directed edges ``(i, j)`` over ``N`` agents. Each
pairwise cost ``phi_ij(x_i, x_j, y_ij)`` (eq. 5) returns its partial gradients per edge as an
:class:`EdgeGradients`: ``g_src[e] = grad_{x_i} phi_ij``, ``g_dst[e] = grad_{x_j} phi_ij`` (both
``(E, n)``) and ``g_edge[e] = grad_{y_ij} phi_ij`` (``(E, m)``, or ``None`` without edge states).

The flow (eq. 7-8)::

    x_i' = -k sum_{j:(i,j) in E} (grad_{x_i} phi_ij + grad_{x_i} phi_ji),   y_ij' = -k grad_{y_ij} phi_ij

is assembled by :func:`node_gradient`: agent ``i`` sums the gradients of the edges it is an
endpoint of, nothing else (a distributed update: its neighbours' states and the edge's measurement
are all it reads). Discretized with step ``h``: ``x <- x - h k g`` on ``R^n``
(:func:`euclidean_step`), ``R_i <- R_i exp(-h k hat(g_i))`` on SO(3) with ``g_i`` in body
coordinates (:func:`so3_step`, paper 002 side panel on rotations, eq. 29), and for yaws
``psi_i <- wrap(psi_i - h k g_i)`` (:func:`so2_step`). Edge constraints such
as ``lambda_ij >= 1`` (eq. 17) are kept by projecting after each step (:func:`project_lower`):
the projected gradient update of eq. 17 (``lambda' = 0`` on the active constraint).

Step size (:func:`lipschitz_step`): for an ``L``-smooth cost, ``h k <= 1 / L`` decreases ``phi`` at
every step (``phi+ <= phi - (h k / 2) |g|^2``); each cost module provides a Gershgorin bound ``L``
from its reshaping function's curvature and the maximum agent degree (a number the agents agree on
once, e.g. by max-consensus). Where the cost is not globally smooth (formation control, whose
curvature grows like ``1 / distance``) :func:`displacement_step` bounds the motion per step by a
fraction of the minimum separation instead.

Acceleration (:func:`momentum_weight`, not in the paper): a convex cost (localization with
``f_T = x^2`` and a quadratic ``f_D``, a convex constraint) may take the projected step from the
extrapolated point ``y = x_k + w_k (x_k - x_{k-1})`` with ``w_k = k / (k + 3)`` (FISTA with
Chambolle and Dossal's weights, "On the convergence of the iterates of FISTA", JOTA 2015): the
cost then falls like ``1 / k^2`` instead of ``1 / k`` and the iterates still converge to a
minimizer. Each agent extrapolates its own states with the shared round counter ``k``: still a
distributed update. Measured on paper 002's localization: docs/distributed.md.

Leader (:func:`apply_leaders`): an agent whose state is driven from outside (an operator, a
waypoint list, or a fixed anchor) ignores its gradient and follows a given velocity; the others
keep descending, so they follow it through their edges.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import FloatArray, IntArray, so3_exp, wrap_angle


@dataclass(frozen=True)
class EdgeGradients:
    """Partial gradients of every pairwise cost (paper 002 eq. 7-8), one row per edge."""

    g_src: FloatArray
    g_dst: FloatArray
    g_edge: FloatArray | None = None


def check_edges(edges: ArrayLike, n_agents: int) -> IntArray:
    """``(E, 2)`` int edges with endpoints in ``[0, N)`` and no self loops, or ``ValueError``."""
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    if e.size and (e.min() < 0 or e.max() >= n_agents):
        raise ValueError(f"edge endpoints must be in [0, {n_agents})")
    if np.any(e[:, 0] == e[:, 1]):
        raise ValueError("self loops are not edges")
    return e


def node_gradient(edges: IntArray, n_agents: int, g: EdgeGradients) -> FloatArray:
    """``sum_j grad_{x_i} phi_ij + grad_{x_i} phi_ji`` per agent (paper 002 eq. 7): ``(N, n)``.

    Agent ``i`` receives ``g_src`` of its out-edges and ``g_dst`` of its in-edges.
    """
    src = g.g_src.reshape(len(edges), -1)
    dst = g.g_dst.reshape(len(edges), -1)
    cols = [
        np.bincount(edges[:, 0], weights=src[:, k], minlength=n_agents)
        + np.bincount(edges[:, 1], weights=dst[:, k], minlength=n_agents)
        for k in range(src.shape[1])
    ]
    return np.stack(cols, axis=1).reshape(n_agents, *g.g_src.shape[1:])


def euclidean_step(x: FloatArray, grad: FloatArray, h_k: float) -> FloatArray:
    """``x - h k grad`` (paper 002 eq. 7-8, forward Euler); any shape."""
    return x - h_k * grad


def so3_step(rot: FloatArray, grad_body: FloatArray, h_k: float) -> FloatArray:
    """``R_i exp(-h k hat(g_i))``: the flow of eq. 7 on SO(3) discretized with the exponential map
    (paper 002 eq. 29). ``rot`` ``(N, 3, 3)``, ``grad_body`` ``(N, 3)`` in the local coordinates
    ``R exp(hat(delta))``."""
    return rot @ so3_exp(-h_k * grad_body)


def so2_step(psi_rad: FloatArray, grad: FloatArray, h_k: float) -> FloatArray:
    """``wrap(psi_i - h k g_i)``: :func:`so3_step` for rotations about the vertical, where
    ``R_z(psi) exp(hat(delta e3)) = R_z(psi + delta)`` makes the exponential map an angle addition
    (paper 002 eq. 29 on SO(2); :mod:`onboard.distributed.yaw`). ``psi_rad``, ``grad`` ``(N,)``;
    result in ``[-pi, pi)``."""
    return wrap_angle(psi_rad - h_k * grad)


def project_lower(y: FloatArray, lower: float | None) -> FloatArray:
    """Projection on ``y >= lower`` (paper 002 eq. 17); ``None`` leaves ``y`` unconstrained."""
    return y if lower is None else np.maximum(y, lower)


def momentum_weight(k: int) -> float:
    """The extrapolation weight ``w_k = k / (k + 3)`` of round ``k >= 0`` (module docstring)."""
    if k < 0:
        raise ValueError("the round counter must be >= 0")
    return k / (k + 3.0)


def lipschitz_step(lipschitz: float, safety: float = 1.0) -> float:
    """``h k = safety / L`` (descent for an ``L``-smooth cost when ``safety <= 1``)."""
    if not (np.isfinite(lipschitz) and lipschitz > 0):
        raise ValueError("the Lipschitz bound must be a positive number")
    if not 0 < safety <= 1.0:
        raise ValueError("safety must be in (0, 1]")
    return safety / lipschitz


def displacement_step(
    gradient_bound: float, max_degree: int, min_separation_m: float, fraction: float = 0.05
) -> float:
    """``h k`` such that no agent moves more than ``fraction * min_separation_m`` per step:
    ``h k * gradient_bound * max_degree <= fraction * min_separation_m`` (so every bearing turns
    by at most about ``2 * fraction`` rad per step)."""
    if gradient_bound <= 0 or max_degree <= 0 or min_separation_m <= 0:
        raise ValueError("bounds and the separation must be positive")
    return fraction * min_separation_m / (gradient_bound * max_degree)


def max_degree(edges: IntArray, n_agents: int) -> int:
    """Largest number of edges (in + out) any agent is an endpoint of."""
    deg = np.bincount(edges.ravel(), minlength=n_agents)
    return int(deg.max()) if deg.size else 0


def apply_leaders(
    x_new: FloatArray,
    x_old: FloatArray,
    leader_mask: ArrayLike | None,
    leader_velocity: ArrayLike | None,
    h: float,
) -> FloatArray:
    """Replace the leaders' descent step by ``x_old + h v_ext`` (a fixed anchor when ``v_ext = 0``).

    ``x_new, x_old`` ``(N, n)``, ``leader_mask`` ``(N,)`` bool, ``leader_velocity`` ``(N, n)`` or
    ``None`` (anchors). Euclidean states only (a rotation leader is held by masking its gradient).
    """
    if leader_mask is None:
        return x_new
    m = np.asarray(leader_mask, dtype=bool)
    if not m.any():
        return x_new
    out = x_new.copy()
    v = np.zeros_like(x_old) if leader_velocity is None else np.asarray(leader_velocity, float)
    out[m] = x_old[m] + h * v[m]
    return out


def mask_gradient(grad: FloatArray, leader_mask: ArrayLike | None) -> FloatArray:
    """Zero the gradient of the leaders (held fixed by the flow)."""
    if leader_mask is None:
        return grad
    out = grad.copy()
    out[np.asarray(leader_mask, dtype=bool)] = 0.0
    return out
