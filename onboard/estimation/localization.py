"""Bearing localization in R^3 x S^1 with SfM distances as virtual measurements (paper 000 eq. 6).

Each agent ``i`` estimates its own ``qhat_i = (phat_i, psihat_i)`` in a frame the team shares
only through the estimator itself (it is defined up to a translation and a rotation about the
vertical, the trivial motions ``n1``, ``n3`` of eq. 5). The filter is the agent model plus a
gradient descent of

    J(qhat) = (k_L / 2) sum_E |betahat_ij - beta_ij|^2 + (k_d / 4) sum_{E_u} (|phat_ij|^2 - dhat_ij^2)^2,

with ``betahat_ij = R_z(psihat_i)^T phat_ij / |phat_ij|`` and ``dhat_ij = 1 / chihat_ij`` from
the SfM observers (eq. 6, reconstructed in docs/equations.md, "Scale from motion"; ``k_L = 100``,
``k_d = 1``):

    phat_i' = R_z(psihat_i) u_i - dJ/dphat_i,        psihat_i' = w_i - dJ/dpsihat_i.

``dJ/dqhat_i`` only involves edges that touch ``i``, so each agent descends its own block
with its bearings, its neighbours' shared bearings and estimates: the sum over agents is the
exact gradient of ``J``. Per-edge gradients (checked against finite differences in tests):

* ``e = (1/2)|betahat - beta|^2``, ``xi = betahat - beta``, ``Phat = I - betahat betahat^T``:
  ``de/dphat_j = R_z(psihat_i) Phat xi / dhat``, ``de/dphat_i = -de/dphat_j``,
  ``de/dpsihat_i = -xi^T S betahat`` (``d R_z^T / d psi = -S R_z^T``);
* ``e = (1/4)(|r|^2 - dhat^2)^2`` with ``r = phat_j - phat_i``: ``de/dphat_i = -(|r|^2 - dhat^2) r``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from onboard.estimation.angles import wrap_rad

Vec3 = tuple[float, float, float]

K_L = 100.0
K_D = 1.0
MIN_ESTIMATED_DISTANCE_M = 1e-6
"""Below this the estimated bearing is undefined and the term contributes nothing."""
MAX_CORRECTION_M_S = 50.0
MAX_CORRECTION_RAD_S = 10.0
"""Bounds of the gradient-descent part of ``phat_i'`` and ``psihat_i'``. The distance term's
gradient grows with the cube of the distances, so explicit Euler is stable only while
``k_d |(|r|^2 - dhat^2)| dt < 2``: with a 5 ms step and an SfM distance that has drifted to 50 m
(before the observer converges) one step overshoots and the estimate runs off to NaN. Bounding
the correction speed keeps the filter finite; near its fixed point the bounds are inactive."""


def bearing_term_gradient(
    p_i: Vec3, yaw_i_rad: float, p_j: Vec3, beta_ij: Vec3
) -> tuple[Vec3, float, Vec3]:
    """Gradient of ``(1/2)|betahat_ij - beta_ij|^2`` w.r.t. ``(phat_i, psihat_i, phat_j)``.

    ``p_*`` are world (estimated-frame) positions, ``beta_ij`` is measured in ``i``'s body frame.
    Position gradients are returned in the world frame.
    """
    r0, r1, r2 = p_j[0] - p_i[0], p_j[1] - p_i[1], p_j[2] - p_i[2]
    d = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    if not d > MIN_ESTIMATED_DISTANCE_M:  # coincident (or non-finite) estimates: no bearing
        return (0.0, 0.0, 0.0), 0.0, (0.0, 0.0, 0.0)
    c, s = math.cos(yaw_i_rad), math.sin(yaw_i_rad)
    b0, b1, b2 = (c * r0 + s * r1) / d, (-s * r0 + c * r1) / d, r2 / d  # betahat = R^T r / d
    x0, x1, x2 = b0 - beta_ij[0], b1 - beta_ij[1], b2 - beta_ij[2]
    bx = b0 * x0 + b1 * x1 + b2 * x2
    q0, q1, q2 = (x0 - b0 * bx) / d, (x1 - b1 * bx) / d, (x2 - b2 * bx) / d  # Phat xi / d (body)
    g_j = (c * q0 - s * q1, s * q0 + c * q1, q2)  # rotate to world
    g_yaw = x0 * b1 - x1 * b0
    return (-g_j[0], -g_j[1], -g_j[2]), g_yaw, g_j


def distance_term_gradient(p_i: Vec3, p_j: Vec3, d_hat_m: float) -> Vec3:
    """Gradient of ``(1/4)(|phat_j - phat_i|^2 - dhat^2)^2`` w.r.t. ``phat_i`` (world frame)."""
    r0, r1, r2 = p_j[0] - p_i[0], p_j[1] - p_i[1], p_j[2] - p_i[2]
    e = r0 * r0 + r1 * r1 + r2 * r2 - d_hat_m * d_hat_m
    return (-e * r0, -e * r1, -e * r2)


def localization_euler_step(
    p_hat_ned: Vec3,
    yaw_hat_rad: float,
    dt: float,
    v_body: Vec3,
    yaw_rate_rad_s: float,
    g_bearing: Vec3,
    g_bearing_yaw: float,
    g_distance: Vec3,
    k_l: float = K_L,
    k_d: float = K_D,
    max_correction_m_s: float = MAX_CORRECTION_M_S,
    max_correction_rad_s: float = MAX_CORRECTION_RAD_S,
) -> tuple[Vec3, float]:
    """One explicit-Euler step of agent ``i``'s block of eq. 6 (paper 000 eq. 6):
    ``phat_i' = R_z(psihat_i) u_i - f``, ``psihat_i' = w_i - f_psi`` with the correction
    ``f = k_L g_bearing + k_d g_distance`` (norm saturated at ``max_correction_m_s``) and
    ``f_psi = k_L g_bearing_yaw`` (clipped at ``max_correction_rad_s``).

    ``g_bearing``/``g_bearing_yaw``: sums of :func:`bearing_term_gradient` over the agent's
    edges (world frame), ``g_distance``: sum of :func:`distance_term_gradient`. Returns
    ``(phat_i, psihat_i)`` after the step, the yaw wrapped to ``[-pi, pi]``."""
    p = p_hat_ned
    c, s = math.cos(yaw_hat_rad), math.sin(yaw_hat_rad)
    kl, kd = k_l, k_d
    f0 = kl * g_bearing[0] + kd * g_distance[0]
    f1 = kl * g_bearing[1] + kd * g_distance[1]
    f2 = kl * g_bearing[2] + kd * g_distance[2]
    norm = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
    if norm > max_correction_m_s:
        f0 = f0 * max_correction_m_s / norm
        f1 = f1 * max_correction_m_s / norm
        f2 = f2 * max_correction_m_s / norm
    f_yaw = max(-max_correction_rad_s, min(max_correction_rad_s, kl * g_bearing_yaw))
    p_new = (
        p[0] + dt * (c * v_body[0] - s * v_body[1] - f0),
        p[1] + dt * (s * v_body[0] + c * v_body[1] - f1),
        p[2] + dt * (v_body[2] - f2),
    )
    return p_new, wrap_rad(yaw_hat_rad + dt * (yaw_rate_rad_s - f_yaw))


@dataclass(slots=True)
class LocalizationFilter:
    """Agent ``i``'s block of the localization filter (eq. 6), integrated with explicit Euler."""

    p_hat_ned: Vec3
    yaw_hat_rad: float
    k_l: float = K_L
    k_d: float = K_D
    max_correction_m_s: float = MAX_CORRECTION_M_S
    max_correction_rad_s: float = MAX_CORRECTION_RAD_S

    def step(
        self,
        dt: float,
        v_body: Vec3,
        yaw_rate_rad_s: float,
        out_edges: list[tuple[Vec3, Vec3]],
        in_edges: list[tuple[Vec3, float, Vec3]],
        distances: list[tuple[Vec3, float]],
    ) -> None:
        """Advance by ``dt``.

        ``out_edges``: ``(phat_j, beta_ij)`` for the bearings this agent measures;
        ``in_edges``: ``(phat_j, psihat_j, beta_ji)`` for bearings neighbours measure to it;
        ``distances``: ``(phat_j, dhat_ij)`` for reciprocal neighbours with an SfM estimate.
        """
        p = self.p_hat_ned
        yaw = self.yaw_hat_rad
        g0 = g1 = g2 = g_yaw = 0.0
        for p_j, beta in out_edges:
            g_i, gy, _ = bearing_term_gradient(p, yaw, p_j, beta)
            g0, g1, g2, g_yaw = g0 + g_i[0], g1 + g_i[1], g2 + g_i[2], g_yaw + gy
        for p_j, yaw_j, beta in in_edges:
            _, _, g_j = bearing_term_gradient(p_j, yaw_j, p, beta)
            g0, g1, g2 = g0 + g_j[0], g1 + g_j[1], g2 + g_j[2]
        d0 = d1 = d2 = 0.0
        for p_j, d_hat in distances:
            gd = distance_term_gradient(p, p_j, d_hat)
            d0, d1, d2 = d0 + gd[0], d1 + gd[1], d2 + gd[2]
        self.p_hat_ned, self.yaw_hat_rad = localization_euler_step(
            p, yaw, dt, v_body, yaw_rate_rad_s, (g0, g1, g2), g_yaw, (d0, d1, d2),
            self.k_l, self.k_d, self.max_correction_m_s, self.max_correction_rad_s,
        )  # fmt: skip
