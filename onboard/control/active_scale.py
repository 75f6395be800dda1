"""Active scale estimation: maximize the SfM convergence rate by moving (paper 000 Sect. IV).

The observer of reciprocal edge ``k = (i, j)`` converges at a rate set by its excitation
``lambda_k = u_ij^T P_ij u_ij`` (:func:`onboard.estimation.sfm_observer.excitation`). The team
maximizes the differentiable soft minimum (eq. 11)

    lambdabar = (sum_{E_u} lambda_k^p)^(1/p),        p = -5,

whose partial derivative is ``d lambdabar / d lambda_k = (lambda_k / lambdabar)^(p - 1)``, in
``[0, 1]`` because ``lambdabar <= min_k lambda_k`` for ``p < 0``. With ``u_ij = iR_j u_j - u_i``,
``d lambda_ij / d u_i = -2 u_ij^T P_ij`` (row, ``i``'s body frame); the same number seen from
the other end is ``+2 u_ji^T P_ji jR_i``, identical because ``beta_ji = -jR_i beta_ij``, so each
agent can use its own bearing (equations.md, "Scale from motion").

* Unconstrained (eq. 12), ``nu_i = |u_i|^2 / 2``:
  ``u_i' = -k_nu (nu_i - nu*)/(2 nu_i) u_i + k_l (I - u_i u_i^T / (2 nu_i)) (d lambdabar/d u_i)^T``.
* Bearing-constrained (eq. 13-16): the only formation-preserving motion with ``lambdabar > 0`` is
  the rotation ``n3`` about the vertical through the barycenter, so
  ``u_i = u_i^F + w_l R_i^T S (p_i - pbar)``, ``w_i = w_i^F + w_l`` with
  ``w_l' = -k_w w_l + k_l0 k_E(E) gamma / (gamma + lambdabar) d lambdabar / d w_l`` and
  ``d lambdabar / d w_l = sum_i (d lambdabar / d u_i) R_i^T S (p_i - pbar)`` (a network sum).

All functions are pure float math on 3-tuples (called every 2 ms per agent).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

Vec3 = tuple[float, float, float]

P_NORM = -5.0
K_NU = 10.0
NU_STAR = 0.25
K_LAMBDA = 15.0
K_W = 1.0
GAMMA = 0.05
K_LAMBDA0 = 2.0
E_LOW = 1e-4
E_HIGH = 1e-3
W_L_SIGN = 0.02
"""rad/s: below this ``|w_l|`` the start-up bias of :func:`rotation_rate_derivative` fades out
(``tanh``), so its direction follows the sign of ``w_l`` smoothly."""
LAMBDA_FLOOR = 1e-3
"""Excitations are floored here before the negative power. It bounds ``lambda^p`` (1e15), so a
momentary loss of excitation on one edge cannot swamp the network average for long."""


def lambda_bar_term(lam: float, p: float = P_NORM) -> float:
    """One edge's ``lambda_k^p`` in eq. 11, the excitation floored at :data:`LAMBDA_FLOOR`."""
    return max(lam, LAMBDA_FLOOR) ** p


def lambda_bar_of_sum(power_sum: float, p: float = P_NORM) -> float:
    """``(sum_k lambda_k^p)^(1/p)`` (eq. 11) from the sum of :func:`lambda_bar_term`."""
    return power_sum ** (1.0 / p)


def lambda_bar(excitations: Sequence[float], p: float = P_NORM) -> float:
    """Observability index ``(sum_k lambda_k^p)^(1/p)`` (eq. 11); 0 for an empty edge set."""
    if not excitations:
        return 0.0
    return lambda_bar_of_sum(sum(lambda_bar_term(lam, p) for lam in excitations), p)


def lambda_bar_from_power_mean(mean_power: float, n_agents: int, p: float = P_NORM) -> float:
    """``lambdabar`` from the consensus estimate of ``(1/N) sum_i phi_i``, ``phi_i = sum_k lambda_k^p``
    over the edges agent ``i`` runs."""
    return max(n_agents * mean_power, 1e-300) ** (1.0 / p)


def soft_min_weight(lam: float, lam_bar: float, p: float = P_NORM) -> float:
    """``d lambdabar / d lambda_k = (lambda_k / lambdabar)^(p-1)``, clipped to its exact range [0, 1]
    so that a consensus estimate of ``lambdabar`` that is momentarily too high cannot blow up."""
    if lam_bar <= 0.0:
        return 0.0
    lam = max(lam, LAMBDA_FLOOR)
    return 1.0 if lam <= lam_bar else (lam / lam_bar) ** (p - 1.0)


def excitation_gradient(beta_ij: Vec3, u_ij: Vec3) -> Vec3:
    """``d lambda_ij / d u_i = -2 (P_ij u_ij)^T`` in ``i``'s body frame."""
    bu = beta_ij[0] * u_ij[0] + beta_ij[1] * u_ij[1] + beta_ij[2] * u_ij[2]
    return (
        -2.0 * (u_ij[0] - beta_ij[0] * bu),
        -2.0 * (u_ij[1] - beta_ij[1] * bu),
        -2.0 * (u_ij[2] - beta_ij[2] * bu),
    )


def lambda_bar_gradient(
    edges: Iterable[tuple[Vec3, Vec3, float]], lam_bar: float, p: float = P_NORM
) -> Vec3:
    """``d lambdabar / d u_i = sum_j (lambda_ij / lambdabar)^(p-1) d lambda_ij / d u_i``.

    ``edges`` yields ``(beta_ij, u_ij, lambda_ij)`` for agent ``i``'s reciprocal edges.
    """
    g: Vec3 = (0.0, 0.0, 0.0)
    for beta, u_ij, lam in edges:
        g = lambda_bar_gradient_term(g, beta, u_ij, lam, lam_bar, p)
    return g


def lambda_bar_gradient_term(
    acc: Vec3, beta_ij: Vec3, u_ij: Vec3, lam: float, lam_bar: float, p: float = P_NORM
) -> Vec3:
    """``acc + (lambda_ij / lambdabar)^(p-1) d lambda_ij / d u_i``: one edge of eq. 12's gradient."""
    w = soft_min_weight(lam, lam_bar, p)
    d = excitation_gradient(beta_ij, u_ij)
    return (acc[0] + w * d[0], acc[1] + w * d[1], acc[2] + w * d[2])


def active_velocity_rate(
    u_i: Vec3,
    grad_u: Vec3,
    k_nu: float = K_NU,
    nu_star: float = NU_STAR,
    k_l: float = K_LAMBDA,
) -> Vec3:
    """Eq. 12: keep ``|u_i|^2 / 2 = nu*`` and turn ``u_i`` up the gradient of ``lambdabar``."""
    nu = 0.5 * (u_i[0] * u_i[0] + u_i[1] * u_i[1] + u_i[2] * u_i[2])
    if nu <= 1e-12:
        return (k_l * grad_u[0], k_l * grad_u[1], k_l * grad_u[2])
    a = -k_nu * (nu - nu_star) / (2.0 * nu)
    ug = (u_i[0] * grad_u[0] + u_i[1] * grad_u[1] + u_i[2] * grad_u[2]) / (2.0 * nu)
    return (
        a * u_i[0] + k_l * (grad_u[0] - u_i[0] * ug),
        a * u_i[1] + k_l * (grad_u[1] - u_i[1] * ug),
        a * u_i[2] + k_l * (grad_u[2] - u_i[2] * ug),
    )


def rotation_velocity_body(p_i_ned: Vec3, yaw_i_rad: float, p_bar_ned: Vec3) -> Vec3:
    """``R_z(psi_i)^T S (p_i - pbar)``: body velocity of the unit-rate rotation ``n3`` (eq. 13)."""
    a, b = p_i_ned[0] - p_bar_ned[0], p_i_ned[1] - p_bar_ned[1]
    c, s = math.cos(yaw_i_rad), math.sin(yaw_i_rad)
    # S (a, b, z) = (-b, a, 0); then R^T
    return (c * -b + s * a, -s * -b + c * a, 0.0)


def convergence_gain(e_index: float, e_low: float = E_LOW, e_high: float = E_HIGH) -> float:
    """``k_E(E)`` (eq. 16): a C^1 smooth step, 0 below ``E_low``, 1 above ``E_high``."""
    s = (e_index - e_low) / (e_high - e_low)
    if s <= 0.0:
        return 0.0
    if s >= 1.0:
        return 1.0
    return s * s * (3.0 - 2.0 * s)


def rotation_rate_derivative(
    w_l: float,
    dlam_dwl: float,
    lam_bar: float,
    k_e: float,
    k_w: float = K_W,
    k_l0: float = K_LAMBDA0,
    gamma: float = GAMMA,
    w_l_start: float = 0.0,
) -> float:
    """Eq. 15 with ``k_lambda = k_l0 k_E(E)``: ``w_l' = -k_w w_l + k_l gamma/(gamma + lambdabar) dlambdabar/dw_l``.

    ``w_l_start`` (not in the paper; 0 gives eq. 15): the damping pulls ``w_l`` towards
    ``max(2 k_E(E) - 1, 0) w_l_start tanh(w_l / W_L_SIGN)`` instead of 0 (on while the gate
    is mostly on, ``k_E > 0.5``, as the paper's Sect. V-B reads it). ``w_l = 0`` becomes an unstable
    equilibrium: the first push of the gradient decides the direction, and the rotation
    reaches ``w_l_start`` within ``1 / k_w`` while the formation converges instead of after
    the formation motion has settled; it stops with the gate ``k_E``."""
    target = max(2.0 * k_e - 1.0, 0.0) * w_l_start * math.tanh(w_l / W_L_SIGN)
    return -k_w * (w_l - target) + k_l0 * k_e * gamma / (gamma + max(lam_bar, 0.0)) * dlam_dwl
