"""Rigidity maintenance, collision avoidance and target tracking as potentials (paper 003).

Paper 003 sec. 4.3-5.1 steers every robot with the negative gradient of a sum of potentials
(eq. 14): a barrier on the weighted angle rigidity eigenvalue (eq. 19), a pairwise collision
potential (eq. 30) and a mission potential (eq. 32, target tracking). The equations lost their
symbols in extraction; the forms below follow ``docs/equations.md`` ("Angle rigidity")
and are chosen here:

**Rational barrier.** For a quantity ``x`` that must stay above ``x_min`` and is harmless above
``x_safe``, with ``a = x_safe - x``, ``b = x - x_min``, ``c = x_safe - x_min``,

    ``B(x) = k a^2 / (b c)``  for ``x_min < x < x_safe``,   ``0`` for ``x >= x_safe``,

    ``B'(x) = -k a (a + 2 b) / (c b^2)``.

``B`` and ``B'`` vanish at ``x_safe`` (C^1 there) and ``B -> inf`` as ``x -> x_min``. Below
``x_min + floor c`` the derivative is evaluated at that floor (a saturated, finite push).

* rigidity (eq. 19): ``V_R = B(lambda)`` on the weighted eigenvalue, control
  ``-V_R'(lambda) grad lambda`` (eq. 21-23);
* collision (eq. 30): ``V_C = sum_{pairs} B(d_ij)`` with ``x_min = r_coll``, ``x_safe = r_safe``.

**Target tracking** (eq. 32, form chosen here). For robot ``i`` and target ``t`` at distance
``d`` and world bearing ``b = (p_t - p_i) / d``, camera axis ``c_i = R_z(psi_i) e1``,

    ``V_T = (k_r / 2) (d - r_T)^2 + k_c (1 - c_i . b)``,

    ``dV_T/dp_i = -k_r (d - r_T) b + k_c P c_i / d``,  ``dV_T/dpsi_i = -k_c (S c_i) . b``,

with ``P = I - b b^T``, ``S = hat(e3)``. The first term holds the tracking radius ``r_T``, the
second turns the camera toward the target. In the body frame (``c = e1``) the control is
``u = k_r (d - r_T) beta - k_c (e1 - beta_x beta) / d`` and ``w = k_c beta_y``: it needs only the
target's body-frame bearing ``beta`` and its distance (paper 003 eq. 33).

**Body frame.** A multicopter's camera is body x and it steers it by yaw only (the default):
``u_i = -R_z(psi_i)^T grad_p V``, ``w_i = -dV/dpsi_i``. A gimballed camera with a full
rotation ``R_i`` (optional variant) gets the body angular velocity
``omega_i = -(e1 x R_i^T dV/dc_i)``, which reduces to ``w = -(S c_i) . dV/dc_i`` for yaw.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import FloatArray, camera_axis_ned, rot_z

BARRIER_FLOOR = 1e-3
"""Fraction of ``x_safe - x_min`` above ``x_min`` where the barrier's slope saturates."""


def rational_barrier(
    x: ArrayLike, x_min: float, x_safe: float, gain: float = 1.0
) -> tuple[FloatArray, FloatArray]:
    """``B(x)`` and ``B'(x)``: zero above ``x_safe``, unbounded as ``x -> x_min`` (module docstring).

    Vectorized. At or below ``x_min`` the value is ``inf`` and the slope is the (finite)
    slope at ``x_min + BARRIER_FLOOR (x_safe - x_min)``.
    """
    if not (np.isfinite(x_min) and np.isfinite(x_safe) and x_safe > x_min):
        raise ValueError(f"barrier needs finite x_min < x_safe, got {x_min!r}, {x_safe!r}")
    if gain < 0.0:
        raise ValueError(f"barrier gain must be >= 0, got {gain!r}")
    xs = np.asarray(x, dtype=float)
    c = x_safe - x_min
    inside = xs > x_min
    xv = np.clip(xs, np.nextafter(x_min, np.inf), x_safe)
    value = np.where(inside, gain * (x_safe - xv) ** 2 / ((xv - x_min) * c), np.inf)
    xc = np.clip(xs, x_min + BARRIER_FLOOR * c, x_safe)
    a = x_safe - xc
    b = xc - x_min
    slope = -gain * a * (a + 2.0 * b) / (c * b * b)
    return value, slope


@dataclass(frozen=True)
class MaintenanceGains:
    """Levels and gains of the three potentials (values of the rigidity scenarios as defaults)."""

    lambda_min: float = 0.02
    """Rigidity eigenvalue level the barrier never lets the team reach."""
    lambda_safe: float = 0.2
    """Above this level the rigidity term is off."""
    k_rigidity: float = 0.05
    r_coll_m: float = 0.6
    r_safe_m: float = 1.5
    k_collision: float = 1.0
    r_track_m: float = 2.0
    k_track_range: float = 0.15
    k_track_camera: float = 0.4
    softmin_tau: float = 0.01
    """Temperature of the smooth minimum whose gradient the rigidity action follows
    (:func:`softmin_weights`; 0: the smallest eigenvalue's alone, paper 003 eq. 21). Half of
    ``lambda_min``: modes 0.02 above the smallest weigh 14%."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.lambda_min < self.lambda_safe:
            raise ValueError("need 0 <= lambda_min < lambda_safe")
        if not 0.0 <= self.softmin_tau < math.inf:
            raise ValueError(f"softmin_tau must be finite and >= 0, got {self.softmin_tau!r}")
        if not 0.0 < self.r_coll_m < self.r_safe_m:
            raise ValueError("need 0 < r_coll_m < r_safe_m")
        gains = (self.k_rigidity, self.k_collision, self.k_track_range, self.k_track_camera)
        if min(gains) < 0.0 or self.r_track_m < 0.0:
            raise ValueError("gains and the tracking radius must be >= 0")


def softmin_weights(theta: ArrayLike, tau: float) -> FloatArray:
    """Weights ``pi_m = exp(-(theta_m - theta_min) / tau) / sum`` of the smooth minimum
    ``L = -tau log sum_m exp(-theta_m / tau)``, whose gradient is ``sum_m pi_m grad theta_m``.

    Why the rigidity action follows ``grad L`` and not the smallest eigenvalue's gradient alone:
    ``lambda = min_m theta_m`` has a kink where two modes cross. Near the edge of a camera's
    view a mode whose eigenvalue is proportional to one fading sensing weight has a gradient
    30 times the smallest mode's; following the smallest alone, the team pushed that mode down
    until it became the smallest, was kicked back by its gradient (1.4 m/s, 4.5 rad/s in one
    2 ms step), and did so again every 80 ms (rigidity-tracking, seed 7). Blending the gradients
    of the modes within a few ``tau`` of the minimum makes the action continuous across the
    crossing. ``tau = 0`` gives the smallest mode weight 1 (the first of equal ones).
    """
    th = np.asarray(theta, dtype=float)
    if th.ndim != 1 or len(th) == 0:
        raise ValueError(f"need a non-empty 1-D array of eigenvalues, got shape {th.shape}")
    if tau == 0.0:
        out = np.zeros(len(th))
        out[int(np.argmin(th))] = 1.0
        return out
    values = th.tolist()  # a handful of eigenvalues: plain floats beat numpy's call overhead
    low = min(values)
    e = [math.exp((low - t) / tau) for t in values]
    total = math.fsum(e)
    return np.array([x / total for x in e])


def rigidity_potential(lam: float, gains: MaintenanceGains) -> tuple[float, float]:
    """``V_R(lambda)`` and ``dV_R/dlambda`` (paper 003 eq. 19, rational barrier)."""
    v, s = rational_barrier(lam, gains.lambda_min, gains.lambda_safe, gains.k_rigidity)
    return float(v), float(s)


def collision_potential(
    p_i_ned: ArrayLike, p_others_ned: ArrayLike, gains: MaintenanceGains
) -> tuple[float, FloatArray]:
    """``sum_j B(d_ij)`` over the others and its gradient w.r.t. ``p_i`` (paper 003 eq. 30-31).

    ``p_others_ned`` is ``(M, 3)`` (neighbours' estimated positions, or targets). With
    ``b_ij = (p_j - p_i) / d_ij``: ``grad = -sum_j B'(d_ij) b_ij``.
    """
    p_i = np.asarray(p_i_ned, dtype=float)
    r = np.asarray(p_others_ned, dtype=float).reshape(-1, 3) - p_i
    d = np.sqrt((r * r).sum(axis=1))  # row norms
    if (d == 0.0).any():
        raise ValueError("coincident positions: collision potential undefined")
    near = d < gains.r_safe_m
    if not near.any():
        return 0.0, np.zeros(3)
    v, s = rational_barrier(d[near], gains.r_coll_m, gains.r_safe_m, gains.k_collision)
    grad = -np.sum(s[:, None] * r[near] / d[near, None], axis=0)
    return float(np.sum(v)), grad


def tracking_potential(
    p_i_ned: ArrayLike, yaw_i_rad: float, p_target_ned: ArrayLike, gains: MaintenanceGains
) -> tuple[float, FloatArray, float]:
    """``V_T``, ``dV_T/dp_i`` and ``dV_T/dpsi_i`` in the world frame (paper 003 eq. 32)."""
    r = np.asarray(p_target_ned, dtype=float) - np.asarray(p_i_ned, dtype=float)
    d = float(np.linalg.norm(r))
    if d == 0.0:
        raise ValueError("robot on its target: tracking bearing undefined")
    b = r / d
    c = camera_axis_ned(yaw_i_rad)
    cb = float(c @ b)
    s_c = np.array([-c[1], c[0], 0.0])
    value = 0.5 * gains.k_track_range * (d - gains.r_track_m) ** 2 + gains.k_track_camera * (
        1.0 - cb
    )
    grad_p = (
        -gains.k_track_range * (d - gains.r_track_m) * b + gains.k_track_camera * (c - cb * b) / d
    )
    grad_yaw = -gains.k_track_camera * float(s_c @ b)
    return float(value), grad_p, grad_yaw


def tracking_control_body(
    beta_target_body: ArrayLike, d_target_m: float, gains: MaintenanceGains
) -> tuple[FloatArray, float]:
    """Body-frame tracking action ``(u, w)`` from the target's body bearing and distance (eq. 33).

    Equal to ``(-R^T dV_T/dp, -dV_T/dpsi)`` of :func:`tracking_potential`, written with the
    camera axis ``e1``: ``u = k_r (d - r_T) beta - k_c (e1 - beta_x beta) / d``, ``w = k_c beta_y``.
    """
    beta = np.asarray(beta_target_body, dtype=float)
    if not (d_target_m > 0.0 and np.all(np.isfinite(beta))):
        raise ValueError("tracking needs a finite bearing and a positive distance")
    e1 = np.array([1.0, 0.0, 0.0])
    u = (
        gains.k_track_range * (d_target_m - gains.r_track_m) * beta
        - gains.k_track_camera * (e1 - beta[0] * beta) / d_target_m
    )
    return u, float(gains.k_track_camera * beta[1])


def world_to_body_control(
    grad_p_ned: ArrayLike, grad_yaw: float, yaw_rad: float
) -> tuple[FloatArray, float]:
    """Negative gradient as a yaw-only multicopter's command: ``(-R_z^T grad_p, -grad_yaw)``."""
    return -(rot_z(yaw_rad).T @ np.asarray(grad_p_ned, dtype=float)), -float(grad_yaw)


def rigidity_control_body(
    lam: float,
    grad_lambda_p_ned: ArrayLike,
    grad_lambda_yaw: float,
    yaw_rad: float,
    gains: MaintenanceGains,
) -> tuple[FloatArray, float]:
    """Rigidity action ``-V_R'(lambda) grad lambda`` in the body frame (paper 003 eq. 21-23)."""
    _, slope = rigidity_potential(lam, gains)
    return world_to_body_control(
        slope * np.asarray(grad_lambda_p_ned, dtype=float), slope * grad_lambda_yaw, yaw_rad
    )


def camera_angular_velocity(grad_axis_ned: ArrayLike, r_body_to_ned: ArrayLike) -> FloatArray:
    """Full-rotation variant: body angular velocity ``-(e1 x R^T dV/dc)`` for a gimballed camera.

    ``dV/dc`` is the gradient of a potential w.r.t. the world-frame camera axis ``c = R e1``;
    with ``R' = R hat(omega)``, ``dV/dt = omega . (e1 x R^T dV/dc)``, so this ``omega`` descends.
    """
    g_body = np.asarray(r_body_to_ned, dtype=float).T @ np.asarray(grad_axis_ned, dtype=float)
    return -np.cross(np.array([1.0, 0.0, 0.0]), g_body)


def tracking_axis_gradient(
    p_i_ned: ArrayLike, axis_ned: ArrayLike, p_target_ned: ArrayLike, gains: MaintenanceGains
) -> FloatArray:
    """``dV_T/dc`` of the camera term ``k_c (1 - c . b)``: ``-k_c b`` (full-rotation variant)."""
    r = np.asarray(p_target_ned, dtype=float) - np.asarray(p_i_ned, dtype=float)
    del axis_ned  # the camera term is linear in c
    return -gains.k_track_camera * r / np.linalg.norm(r)
