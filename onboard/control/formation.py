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
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
from numpy.typing import ArrayLike

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
