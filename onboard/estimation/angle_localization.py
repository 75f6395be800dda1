"""Angle-based localization with one distance (paper 003 sec. 4.2, eq. 10-11).

The team estimates positions ``phat`` in a common frame it defines itself (up to a rotation
and a translation; one distance fixes the scale). With ``A`` the angles measured now
(switching with the sensing graph), ``f_a`` their measured cosines and ``d_ab`` one measured
(or SfM-estimated) distance, the potential of eq. 10 is

    ``J(phat) = k_A sum_A (f_a(phat) - f_a)^2 + k_d (|phat_a - phat_b| - d_ab)^2``,

and the estimator is its gradient flow ``phat' = -grad J`` (eq. 11), locally exponentially
stable for switching graphs that are each infinitesimally angle rigid (proposition 4).

**Distributed evaluation.** ``grad J = 2 k_A R_A^T e + ...`` with ``e = f(phat) - f`` and the
rows of ``R_A`` from :func:`onboard.rigidity.angle.angle_rigidity_matrix`. An angle
``(i, j, k)`` touches only ``i, j, k`` and is measured by ``i``: agent ``i`` evaluates the
residuals of its own angles from its bearings and its neighbours' estimates, keeps the block
of ``p_i`` and sends the blocks of ``p_j``, ``p_k`` to ``j`` and ``k``
(:func:`local_angle_gradient`). Each agent adds what it received to its own block; the sum
over agents is exactly ``grad J`` (tested).

**Gravity.** Angles leave the estimated frame free to rotate in 3-D; a level multicopter
also knows the vertical component of each bearing, and a small extra term
(:func:`local_vertical_gradient`) keeps the estimated frame's vertical the true one, which the
camera model (a level body-x camera) and the yaw read from bearings need.

**Moving robots.** The paper proves convergence for a fixed configuration. Robots here move,
so each estimate also integrates its own motion, ``phat_i' = R(psihat_i) u_i - grad_i J``, with
``psihat_i`` the yaw of the body frame in the estimated frame: the rotation about the vertical
that best aligns the measured body bearings with the estimated ones
(:func:`yaw_from_bearings`), held through odometry while the robot sees nobody. (It assumes
the estimated frame's vertical is the true one, which holds when the initial guess is near
the truth, or with the gravity term.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import FloatArray, IntArray
from onboard.rigidity.angle import angle_function, angle_rigidity_matrix

K_ANGLE = 4.0
K_DISTANCE = 1.0
K_VERTICAL = 4.0


def star_angles(m: int) -> IntArray:
    """Angles ``(0, j, k)``, ``1 <= j < k <= m``, of a star whose centre (index 0) sees ``m``."""
    j, k = np.triu_indices(m, 1)
    return np.stack([np.zeros_like(j), j + 1, k + 1], axis=1).astype(np.int64)


def local_angle_gradient(
    p_own_ned: ArrayLike,
    p_seen_ned: ArrayLike,
    beta_seen_body: ArrayLike,
    k_angle: float = K_ANGLE,
) -> tuple[float, FloatArray]:
    """Agent ``i``'s angle terms of eq. 10 and their gradient w.r.t. ``(p_i, p_seen...)``.

    ``p_seen_ned`` ``(M, 3)`` are the estimates of the ``M`` neighbours ``i`` measures now and
    ``beta_seen_body`` ``(M, 3)`` its unit bearings to them (body frame: angles are
    frame-free). Returns ``(k_A sum e^2, grad (M + 1, 3))``; row 0 is ``i``'s own block, row
    ``m + 1`` goes to neighbour ``m``.
    """
    p_loc = np.vstack([np.asarray(p_own_ned, dtype=float), np.asarray(p_seen_ned, dtype=float)])
    beta = np.asarray(beta_seen_body, dtype=float).reshape(-1, 3)
    m = len(beta)
    if len(p_loc) != m + 1:
        raise ValueError(f"{len(p_loc) - 1} neighbour estimates for {m} bearings")
    if m < 2:
        return 0.0, np.zeros((m + 1, 3))
    angles = star_angles(m)
    f_meas = np.einsum("ad,ad->a", beta[angles[:, 1] - 1], beta[angles[:, 2] - 1])
    e = angle_function(p_loc, angles) - f_meas
    grad = 2.0 * k_angle * (angle_rigidity_matrix(p_loc, angles).T @ e)
    return float(k_angle * e @ e), grad.reshape(m + 1, 3)


def local_vertical_gradient(
    p_own_ned: ArrayLike,
    p_seen_ned: ArrayLike,
    beta_seen_body: ArrayLike,
    k_vertical: float = K_VERTICAL,
) -> tuple[float, FloatArray]:
    """Gravity term ``k_z sum_j (bhat_ij . e3 - beta_ij . e3)^2`` and its gradient.

    A level multicopter's body z is the world's down, so the vertical component of a body
    bearing is absolute: this pins the tilt of the estimated frame that angles leave free
    (paper 003 sec. 2.2 mentions gravity as extra information). With ``bhat = r / d``:
    ``d(bhat . e3)/dp_j = P e3 / d``, and minus that for ``p_i``. Returns
    ``(value, grad (M + 1, 3))`` with rows as in :func:`local_angle_gradient`.
    """
    p_i = np.asarray(p_own_ned, dtype=float)
    r = np.asarray(p_seen_ned, dtype=float).reshape(-1, 3) - p_i
    beta = np.asarray(beta_seen_body, dtype=float).reshape(-1, 3)
    if len(r) != len(beta):
        raise ValueError(f"{len(r)} neighbour estimates for {len(beta)} bearings")
    d = np.linalg.norm(r, axis=1)
    grad = np.zeros((len(r) + 1, 3))
    if len(r) == 0 or np.any(d == 0.0):
        return 0.0, grad
    b = r / d[:, None]
    e = b[:, 2] - beta[:, 2]
    db = (np.array([0.0, 0.0, 1.0]) - b[:, 2:3] * b) / d[:, None]  # P e3 / d
    grad[1:] = 2.0 * k_vertical * e[:, None] * db
    grad[0] = -grad[1:].sum(axis=0)
    return float(k_vertical * e @ e), grad


def distance_gradient(
    p_own_ned: ArrayLike, p_other_ned: ArrayLike, d_m: float, k_distance: float = K_DISTANCE
) -> tuple[float, FloatArray]:
    """``k_d (|p_i - p_j| - d)^2`` and its gradient w.r.t. ``p_i`` (eq. 10, distance term)."""
    r = np.asarray(p_own_ned, dtype=float) - np.asarray(p_other_ned, dtype=float)
    n = float(np.linalg.norm(r))
    if n == 0.0:
        return k_distance * d_m * d_m, np.zeros(3)
    e = n - d_m
    return k_distance * e * e, 2.0 * k_distance * e * r / n


def angle_localization_gradient(
    p_hat_ned: ArrayLike,
    angles: ArrayLike,
    f_meas: ArrayLike,
    distance_pair: tuple[int, int] | None = None,
    d_meas_m: float = 0.0,
    k_angle: float = K_ANGLE,
    k_distance: float = K_DISTANCE,
) -> tuple[float, FloatArray]:
    """Centralized ``J`` (eq. 10) and ``grad J`` ``(N, 3)`` (eq. 11): the reference the
    distributed evaluation must reproduce, and a convenient batch solver for tests."""
    p = np.asarray(p_hat_ned, dtype=float)
    a = np.asarray(angles, dtype=np.int64).reshape(-1, 3)
    grad = np.zeros_like(p)
    value = 0.0
    if len(a):
        e = angle_function(p, a) - np.asarray(f_meas, dtype=float)
        grad += 2.0 * k_angle * (angle_rigidity_matrix(p, a).T @ e).reshape(p.shape)
        value += float(k_angle * e @ e)
    if distance_pair is not None:
        i, j = distance_pair
        v, g = distance_gradient(p[i], p[j], d_meas_m, k_distance)
        value += v
        grad[i] += g
        grad[j] -= g
    return value, grad


def yaw_from_bearings(beta_body: ArrayLike, b_hat_ned: ArrayLike) -> float | None:
    """Yaw ``psi`` maximizing ``sum_m b_hat_m . R_z(psi) beta_m`` (horizontal Procrustes).

    ``psi = atan2(sum (beta_x b_y - beta_y b_x), sum (beta_x b_x + beta_y b_y))``; ``None`` when
    the bearings are (near) vertical or absent and no yaw can be read from them.
    """
    beta = np.asarray(beta_body, dtype=float).reshape(-1, 3)
    b = np.asarray(b_hat_ned, dtype=float).reshape(-1, 3)
    s = float((beta[:, 0] * b[:, 1] - beta[:, 1] * b[:, 0]).sum())
    c = float((beta[:, 0] * b[:, 0] + beta[:, 1] * b[:, 1]).sum())
    if math.hypot(s, c) < 1e-3:
        return None
    return math.atan2(s, c)


@dataclass(slots=True)
class AngleLocalizer:
    """One agent's angle-based position estimate and its yaw in the estimated frame.

    ``psihat = yaw_odometry + yaw_offset``: the offset is re-read from the bearings whenever the
    agent sees someone (low-pass ``yaw_gain`` per update) and held otherwise.
    """

    p_hat_ned: FloatArray
    yaw_offset_rad: float = 0.0
    yaw_known: bool = False
    yaw_gain: float = 0.2

    def yaw_hat(self, yaw_odometry_rad: float) -> float:
        """Yaw of the body frame in the estimated frame."""
        return math.remainder(yaw_odometry_rad + self.yaw_offset_rad, math.tau)

    def update_yaw(
        self, yaw_odometry_rad: float, beta_body: ArrayLike, p_seen_ned: ArrayLike
    ) -> None:
        """Re-read the yaw offset from the current bearings and neighbour estimates."""
        r = np.asarray(p_seen_ned, dtype=float).reshape(-1, 3) - self.p_hat_ned
        n = np.sqrt((r * r).sum(axis=1, keepdims=True))  # row norms
        if len(r) == 0 or (n == 0.0).any():
            return
        psi = yaw_from_bearings(beta_body, r / n)
        if psi is None:
            return
        err = math.remainder(psi - yaw_odometry_rad - self.yaw_offset_rad, math.tau)
        gain = self.yaw_gain if self.yaw_known else 1.0
        self.yaw_offset_rad = math.remainder(self.yaw_offset_rad + gain * err, math.tau)
        self.yaw_known = True

    def step(
        self, dt: float, v_body: ArrayLike, yaw_odometry_rad: float, grad_ned: ArrayLike
    ) -> None:
        """``phat' = R_z(psihat) u - grad_i J`` (eq. 11 plus the robot's own motion)."""
        v_ned: FloatArray | float = 0.0  # no yaw, no direction to move the estimate in
        if self.yaw_known:
            psi = self.yaw_hat(yaw_odometry_rad)
            c, s = math.cos(psi), math.sin(psi)
            u_x, u_y, u_z = (float(x) for x in v_body)  # R_z(psi) u on three floats
            v_ned = np.array((c * u_x - s * u_y, s * u_x + c * u_y, u_z))
        p_new = self.p_hat_ned + dt * (v_ned - np.asarray(grad_ned, dtype=float))
        if np.isfinite(p_new).all():  # a non-finite input leaves the estimate as it was
            self.p_hat_ned = p_new
