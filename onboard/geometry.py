"""Rotations and bearings: the geometry every estimator, controller and the simulator share.

Conventions (docs/equations.md, "Conventions"): the world frame is local NED, the body frame is
FRD, the camera's optical axis is body x. ``hat(v) @ w == np.cross(v, w)``. Every function is
pure and vectorized over leading axes: a ``(..., 3)`` array of vectors gives ``(..., 3, 3)``
matrices and so on.

The bearing from ``i`` to ``j`` expressed in ``i``'s body frame is
``beta_ij = R_i^T (p_j - p_i) / d_ij`` with ``d_ij = |p_j - p_i|``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

E3 = np.array([0.0, 0.0, 1.0])
S_E3 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
"""``hat(e3)``: the generator of yaw rotations, ``d R_z(psi)/d psi = S R_z(psi)``."""

_SMALL_ANGLE = 1e-4


def hat(v: ArrayLike) -> FloatArray:
    """Skew-symmetric matrix of ``v``: ``hat(v) @ w = v x w``. Shape ``(..., 3) -> (..., 3, 3)``."""
    v = np.asarray(v, dtype=float)
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def vee(m: ArrayLike) -> FloatArray:
    """Inverse of :func:`hat` applied to the skew part of ``m``: ``(..., 3, 3) -> (..., 3)``."""
    m = np.asarray(m, dtype=float)
    return 0.5 * np.stack(
        [m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]],
        axis=-1,
    )


def so3_exp(w: ArrayLike) -> FloatArray:
    """Rotation matrix ``exp(hat(w))`` by Rodrigues' formula, with Taylor series near 0.

    ``exp(hat(w)) = I + sin(t)/t hat(w) + (1 - cos t)/t^2 hat(w)^2`` with ``t = |w|``
    (equations.md, SO(3)).
    """
    w = np.asarray(w, dtype=float)
    t = np.linalg.norm(w, axis=-1)
    small = t < _SMALL_ANGLE
    t_safe = np.where(small, 1.0, t)
    t2 = t * t
    a = np.where(small, 1.0 - t2 / 6.0 + t2 * t2 / 120.0, np.sin(t_safe) / t_safe)
    b = np.where(small, 0.5 - t2 / 24.0 + t2 * t2 / 720.0, (1.0 - np.cos(t_safe)) / t_safe**2)
    k = hat(w)
    return np.eye(3) + a[..., None, None] * k + b[..., None, None] * (k @ k)


def so3_log(r: ArrayLike) -> FloatArray:
    """Rotation vector ``w`` with ``so3_exp(w) = r`` and ``|w| <= pi``; ``(..., 3, 3) -> (..., 3)``.

    Stable near 0 (series for ``t / (2 sin t)``) and near ``pi``, where the axis is read from the
    symmetric part ``(R + I) / 2 = a a^T`` and its sign from the residual skew part.
    """
    r = np.asarray(r, dtype=float)
    cos_t = np.clip((np.trace(r, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    t = np.arccos(cos_t)
    skew = vee(r)  # = sin(t) * axis
    sin_t = np.sin(t)
    small = t < _SMALL_ANGLE
    near_pi = t > np.pi - 1e-3
    regular = ~(small | near_pi)
    factor = np.where(small, 1.0 + t * t / 6.0, t / np.where(regular, sin_t, 1.0))
    w = factor[..., None] * skew
    if np.any(near_pi):
        sym = 0.5 * (r[near_pi] + np.eye(3))  # ~ (1 - cos t)/2 a a^T + cos-ish terms; a a^T at pi
        # Column with the largest diagonal entry is the best-conditioned multiple of the axis.
        idx = np.argmax(np.diagonal(sym, axis1=-2, axis2=-1), axis=-1)
        axis = np.take_along_axis(sym, idx[:, None, None], axis=-1)[..., 0]
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        sign = np.sign(np.sum(axis * skew[near_pi], axis=-1))
        sign = np.where(sign == 0.0, 1.0, sign)
        w[near_pi] = (sign * t[near_pi])[:, None] * axis
    return w


def so3_distance(r1: ArrayLike, r2: ArrayLike) -> FloatArray:
    """Geodesic distance ``arccos((tr(R1^T R2) - 1)/2)`` in radians, computed stably via the log."""
    r1 = np.asarray(r1, dtype=float)
    r2 = np.asarray(r2, dtype=float)
    return np.linalg.norm(so3_log(np.swapaxes(r1, -1, -2) @ r2), axis=-1)


def rot_z(yaw_rad: ArrayLike) -> FloatArray:
    """``R_z(psi)``: rotation about the down axis (NED: positive yaw turns the nose east)."""
    yaw = np.asarray(yaw_rad, dtype=float)
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.zeros((*yaw.shape, 3, 3))
    out[..., 0, 0] = c
    out[..., 0, 1] = -s
    out[..., 1, 0] = s
    out[..., 1, 1] = c
    out[..., 2, 2] = 1.0
    return out


def wrap_angle(a_rad: ArrayLike) -> FloatArray:
    """Wrap angles to ``[-pi, pi)``."""
    return (np.asarray(a_rad, dtype=float) + np.pi) % (2.0 * np.pi) - np.pi


def camera_axis_ned(yaw_rad: ArrayLike) -> FloatArray:
    """World-frame optical axis of a body-x camera on a level vehicle: ``R_z(psi) e1``."""
    yaw = np.asarray(yaw_rad, dtype=float)
    return np.stack([np.cos(yaw), np.sin(yaw), np.zeros_like(yaw)], axis=-1)


def bearings_world(p_ned: ArrayLike, edges: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Unit bearings ``b_ij = (p_j - p_i)/d_ij`` in the world frame and distances ``d_ij``.

    ``p_ned`` is ``(N, d)``, ``edges`` is ``(E, 2)`` of vertex indices; returns ``(E, d)``, ``(E,)``.
    """
    p = np.asarray(p_ned, dtype=float)
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    r = p[e[:, 1]] - p[e[:, 0]]
    d = np.linalg.norm(r, axis=-1)
    return r / d[:, None], d


def bearings_body(
    p_ned: ArrayLike, yaw_rad: ArrayLike, edges: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """Body-frame bearings ``beta_ij = R_z(psi_i)^T (p_j - p_i)/d_ij`` and distances (R^3 x S^1)."""
    b_world, d = bearings_world(p_ned, edges)
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    r_i = rot_z(np.asarray(yaw_rad, dtype=float)[e[:, 0]])
    return np.einsum("eji,ej->ei", r_i, b_world), d


def projector(beta: ArrayLike) -> FloatArray:
    """Orthogonal projector ``P = I - beta beta^T`` onto the plane normal to each unit bearing."""
    b = np.asarray(beta, dtype=float)
    return np.eye(b.shape[-1]) - b[..., :, None] * b[..., None, :]


def relative_yaw(beta_ij_body: ArrayLike, beta_ji_body: ArrayLike) -> FloatArray:
    """Relative yaw ``psi_j - psi_i`` from a reciprocal pair of body-frame bearings.

    Uses ``R_z(psi_j - psi_i) beta_ji = -beta_ij`` (paper 002 fig. 6:
    ``psi_21 = theta_12 + pi - theta_21``); only the horizontal components enter, so it is
    undefined for vertical bearings. Returns the angle wrapped to ``[-pi, pi)``.
    """
    bij = np.asarray(beta_ij_body, dtype=float)
    bji = np.asarray(beta_ji_body, dtype=float)
    return wrap_angle(np.arctan2(-bij[..., 1], -bij[..., 0]) - np.arctan2(bji[..., 1], bji[..., 0]))
