"""Bearing formation control (paper 002 eq. 18-21, used as ``(u^F, w^F)`` in paper 000 eq. 13).

Positions: with measured world bearings ``t_ij``, desired ones ``t*_ij`` and ``f_C(c) = 1 - c``,
the pairwise cost ``phi_ij = d_ij f_C(t_ij . t*_ij) = d_ij - (p_j - p_i) . t*_ij`` has gradient
(paper 002 eq. 20) ``grad_{p_i} phi_ij = t*_ij - t_ij`` and ``grad_{p_i} phi_ji = t_ji - t*_ji``:
the distances cancel, so the law uses measured bearings only. Its condition (eq. 21),
``f_C + (1 - c) f_C' = 0 <= 0``, holds. The gradient flow ``p_i' = -k_F grad_{p_i} phi`` is

    p_i' = k_F [ sum_{(i,j) in E} (t_ij - t*_ij) - sum_{(j,i) in E} (t_ji - t*_ji) ].

A desired formation is given as body-frame bearings ``beta*_ij`` and yaws ``psi*_i`` (so it is
defined up to the trivial motions, eq. 5). With ``t*_ij = R_i beta*_ij``, expressed in ``i``'s
body frame (``R_i^T t_ij = beta_ij``, ``R_i^T t_ji = iR_j beta_ji``) the law reads

    u_i^F = k_F [ sum_out (beta_ij - beta*_ij) - sum_in iR_j (beta_ji - beta*_ji) ],

where ``iR_j = R_z(psihat_j - psihat_i)`` comes from the estimated yaws (the common frame of the
localization filter). Yaws are aligned by the gradient flow of ``sum (1 - cos e_ij)``,
``e_ij = (psi_j - psi_i) - (psi*_j - psi*_i)``: ``w_i^F = k_psi sum_j sin(e_ij)``. At the
equilibrium body bearings and relative yaws equal the desired ones: the formation is bearing
congruent to the desired one. (The flow does not fix the scale; it can only shrink it, since
``d/dt sum |p_i - pbar|^2 = -2 k_F phi`` by homogeneity.)

Distances (paper 002 eq. 23; docs/equations.md, "Formation control and vision"): on an edge with a desired distance ``d*_ij`` the cost adds
``f_D(d_ij c_ij - d*_ij)``, ``c_ij = t_ij . t*_ij``, whose gradient is
``grad_{p_i} = -f_D'(d c - d*) t*_ij = -grad_{p_j}`` (:mod:`onboard.distributed.formation`). In
body frames (:func:`formation_distance_velocity`) the flow adds

    u_i^D = k_F [ sum_out f_D'(d_ij c_ij - d*_ij) beta*_ij - sum_in f_D'(d_ji c_ji - d*_ji) iR_j beta*_ji ]

with ``d`` the agent's distance *estimate* of the edge; ``f_D`` is the shipped pseudo-Huber
(:class:`onboard.distributed.reshaping.ReshapeD`), so each edge adds at most ``k_F w delta``.
A desired formation changes in flight through a ramp (:func:`ramp_fraction`,
:func:`slerp_bearing`): the desired bearings turn along great circles and the desired
distances move linearly from the old to the new ones over the ramp time.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
from numpy.typing import ArrayLike

from onboard.distributed.reshaping import ReshapeD
from onboard.geometry import FloatArray, bearings_world, rot_z

Vec3 = tuple[float, float, float]

K_FORMATION = 0.5
K_YAW = 1.0


def formation_out_term(acc: Vec3, beta_ij: Vec3, beta_des_ij: Vec3) -> Vec3:
    """``acc + (beta_ij - beta*_ij)``: one bearing the agent measures, in its body frame."""
    return (
        acc[0] + beta_ij[0] - beta_des_ij[0],
        acc[1] + beta_ij[1] - beta_des_ij[1],
        acc[2] + beta_ij[2] - beta_des_ij[2],
    )


def formation_in_term(acc: Vec3, psi_ij: float, beta_ji: Vec3, beta_des_ji: Vec3) -> Vec3:
    """``acc - iR_j (beta_ji - beta*_ji)``: one bearing a neighbour measures to the agent, with
    ``iR_j = R_z(psi_ij)``, ``psi_ij = psihat_j - psihat_i``."""
    e0, e1, e2 = (
        beta_ji[0] - beta_des_ji[0],
        beta_ji[1] - beta_des_ji[1],
        beta_ji[2] - beta_des_ji[2],
    )
    c, s = math.cos(psi_ij), math.sin(psi_ij)
    return (acc[0] - (c * e0 - s * e1), acc[1] - (s * e0 + c * e1), acc[2] - e2)


def formation_velocity(
    out_edges: Iterable[tuple[Vec3, Vec3]],
    in_edges: Iterable[tuple[float, Vec3, Vec3]],
    k_f: float = K_FORMATION,
) -> Vec3:
    """Body-frame ``u_i^F`` of the gradient law above (paper 002 eq. 20): the out terms
    (:func:`formation_out_term`), then the in terms (:func:`formation_in_term`), times ``k_F``.

    ``out_edges``: ``(beta_ij, beta*_ij)``; ``in_edges``: ``(psi_ij, beta_ji, beta*_ji)`` with
    ``psi_ij = psihat_j - psihat_i``.
    """
    a: Vec3 = (0.0, 0.0, 0.0)
    for beta, des in out_edges:
        a = formation_out_term(a, beta, des)
    for psi_ij, beta, des in in_edges:
        a = formation_in_term(a, psi_ij, beta, des)
    return (k_f * a[0], k_f * a[1], k_f * a[2])


def formation_distance_velocity(
    out_edges: Iterable[tuple[Vec3, Vec3, float, float]],
    in_edges: Iterable[tuple[float, Vec3, Vec3, float, float]],
    k_f: float,
    f_d: ReshapeD,
) -> Vec3:
    """Body-frame ``u_i^D``: the distance terms of paper 002 eq. 23 (module docstring).

    ``out_edges``: ``(beta_ij, beta*_ij, d_ij, d*_ij)``; ``in_edges``:
    ``(psi_ij, beta_ji, beta*_ji, d_ji, d*_ji)`` with ``psi_ij = psihat_j - psihat_i``; ``d``
    the estimated distance (m), ``d*`` the desired one."""
    a0 = a1 = a2 = 0.0
    for beta, des, d, d_des in out_edges:
        c = beta[0] * des[0] + beta[1] * des[1] + beta[2] * des[2]
        g = float(f_d.deriv(d * c - d_des))
        a0, a1, a2 = a0 + g * des[0], a1 + g * des[1], a2 + g * des[2]
    for psi_ij, beta, des, d, d_des in in_edges:
        c = beta[0] * des[0] + beta[1] * des[1] + beta[2] * des[2]
        g = float(f_d.deriv(d * c - d_des))
        cs, sn = math.cos(psi_ij), math.sin(psi_ij)
        a0 -= g * (cs * des[0] - sn * des[1])
        a1 -= g * (sn * des[0] + cs * des[1])
        a2 -= g * des[2]
    return (k_f * a0, k_f * a1, k_f * a2)


def ramp_fraction(elapsed_s: float, ramp_s: float) -> float:
    """How far a formation switch of ``ramp_s`` seconds has come after ``elapsed_s``: the
    smoothstep ``3 x^2 - 2 x^3`` of ``x = elapsed / ramp`` clipped to ``[0, 1]`` (``1`` for a
    ramp of 0 s). Its slope is 0 at both ends, so the desired formation, and with it the
    formation law's velocity, starts and ends its change without a kink."""
    if ramp_s <= 0.0 or elapsed_s >= ramp_s:
        return 1.0
    if elapsed_s <= 0.0:
        return 0.0
    x = elapsed_s / ramp_s
    return x * x * (3.0 - 2.0 * x)


def slerp_bearing(a: Vec3, b: Vec3, s: float) -> Vec3:
    """The unit vector a fraction ``s`` of the way from unit ``a`` to unit ``b`` along their
    great circle (``a`` at 0, ``b`` at 1). Opposite bearings have no unique great circle: the
    result jumps from ``a`` to ``b`` at ``s = 1/2``."""
    c = max(-1.0, min(1.0, a[0] * b[0] + a[1] * b[1] + a[2] * b[2]))
    theta = math.acos(c)
    if theta < 1e-9:
        return b
    sin_t = math.sin(theta)
    if sin_t < 1e-6:  # (anti)parallel
        return a if s < 0.5 else b
    wa, wb = math.sin((1.0 - s) * theta) / sin_t, math.sin(s * theta) / sin_t
    v = (wa * a[0] + wb * b[0], wa * a[1] + wb * b[1], wa * a[2] + wb * b[2])
    n = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    return (v[0] / n, v[1] / n, v[2] / n)


def yaw_alignment_term(yaw_i_rad: float, yaw_j_rad: float, yaw_des_ij_rad: float) -> float:
    """``sin((psi_j - psi_i) - psi*_ij)``: one neighbour's term of the yaw alignment."""
    return math.sin(yaw_j_rad - yaw_i_rad - yaw_des_ij_rad)


def yaw_alignment_rate(
    yaw_i_rad: float, neighbours: Iterable[tuple[float, float]], k_psi: float = K_YAW
) -> float:
    """``w_i^F = k_psi sum_j sin((psi_j - psi_i) - psi*_ij)``; ``neighbours`` yields
    ``(psi_j, psi*_ij)`` with ``psi*_ij = psi*_j - psi*_i``."""
    return k_psi * sum(yaw_alignment_term(yaw_i_rad, yaw_j, des) for yaw_j, des in neighbours)


def formation_cost(
    p_ned: ArrayLike, yaw_rad: ArrayLike, edges: ArrayLike, beta_des_body: ArrayLike
) -> float:
    """``phi = sum_E d_ij (1 - t_ij . R_i beta*_ij)`` (paper 002 eq. 18 with ``f_C(c) = 1 - c``)."""
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    t, d = bearings_world(p_ned, e)
    t_des = np.einsum("eij,ej->ei", rot_z(np.asarray(yaw_rad, dtype=float)[e[:, 0]]), beta_des_body)
    return float(np.sum(d * (1.0 - np.sum(t * t_des, axis=1))))


def yaw_alignment_cost(yaw_rad: ArrayLike, pairs: ArrayLike, yaw_des_rad: ArrayLike) -> float:
    """``sum_{pairs} (1 - cos((psi_j - psi_i) - (psi*_j - psi*_i)))``."""
    y = np.asarray(yaw_rad, dtype=float)
    yd = np.asarray(yaw_des_rad, dtype=float)
    pr = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    e = (y[pr[:, 1]] - y[pr[:, 0]]) - (yd[pr[:, 1]] - yd[pr[:, 0]])
    return float(np.sum(1.0 - np.cos(e)))


def bearing_error_deg(beta_body: ArrayLike, beta_des_body: ArrayLike) -> FloatArray:
    """Angle between measured and desired body bearings, per edge, in degrees."""
    b = np.asarray(beta_body, dtype=float)
    bd = np.asarray(beta_des_body, dtype=float)
    c = np.clip(np.sum(b * bd, axis=-1), -1.0, 1.0)
    return np.degrees(np.arccos(c))
