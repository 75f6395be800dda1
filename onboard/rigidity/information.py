"""Bearing landmarks as a source of position information (paper 004, Sections IV-V).

A vehicle at a setpoint ``x`` (world frame, metres) measures unit bearings to landmarks at
``z_1..z_M`` with isotropic noise ``sigma_m``. One EKF update from a Gaussian prior with
covariance ``Sigmabar`` leaves it with the information matrix (paper 004 eq. 4 and 7)

    J_delta(x; z) = Sigmabar^-1 + sigma_m^-2 sum_j (dh_delta/dx)^T (dh_delta/dx),

where ``h_delta(x, z) = (z - x) / sqrt(|z - x|^2 + delta^2)`` is the smoothed bearing (eq. 6);
``delta = 0`` is the true bearing model. The localization uncertainty of the setpoint is the
trace of the covariance ``tr(J_delta^-1)``, the quantity the landmark planner minimizes.

Every function is vectorized over setpoints ``x`` of shape ``(N, 3)`` and landmarks ``z`` of
shape ``(M, 3)``; ``M = 0`` (no landmarks) is allowed and leaves the prior.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import FloatArray

PAPER_ZETA_SQUARED = 2e9
"""``zeta^2`` the paper derives from its "physically reasonable" values (paper 004 eq. 18)."""

ZETA_CAP = 1e5
"""Upper bound on ``zeta`` "out of concern for numerical precision" (paper 004, after eq. 18)."""


def _offsets(x: ArrayLike, z: ArrayLike) -> FloatArray:
    """``r_ij = z_j - x_i`` of shape ``(N, M, 3)`` from ``x (N, 3)`` and ``z (M, 3)``."""
    x = np.asarray(x, dtype=float).reshape(-1, 3)
    z = np.asarray(z, dtype=float).reshape(-1, 3)
    return z[None, :, :] - x[:, None, :]


def prior_information(prior_cov: ArrayLike) -> FloatArray:
    """``Sigmabar^-1`` from a scalar variance (``Sigmabar = s I``) or a ``(3, 3)`` SPD covariance."""
    cov = np.asarray(prior_cov, dtype=float)
    if cov.ndim == 0:
        if not (np.isfinite(cov) and cov > 0.0):
            raise ValueError("prior_cov must be finite and positive definite")
        return np.eye(3) / float(cov)
    if cov.shape != (3, 3):
        raise ValueError(f"prior_cov must be a scalar or a 3x3 matrix, got shape {cov.shape}")
    sym = 0.5 * (cov + cov.T)
    if not np.all(np.isfinite(sym)) or np.any(np.linalg.eigvalsh(sym) <= 0.0):
        raise ValueError("prior_cov must be finite and positive definite")
    return np.linalg.inv(sym)


def smoothed_bearing(x: ArrayLike, z: ArrayLike, delta: float) -> FloatArray:
    """``h_delta(x_i, z_j) = (z_j - x_i) / sqrt(|z_j - x_i|^2 + delta^2)``, shape ``(N, M, 3)``.

    Paper 004 eq. 6; ``delta = 0`` gives the unit bearing ``h`` of eq. 1.
    """
    r = _offsets(x, z)
    s = np.sqrt(np.sum(r * r, axis=-1) + delta**2)
    return r / s[..., None]


def bearing_information_terms(x: ArrayLike, z: ArrayLike, delta: float) -> FloatArray:
    """``S_delta(x_i; z_j) = (dh_delta/dx)^T (dh_delta/dx)``, shape ``(N, M, 3, 3)``.

    Closed form (paper 004 eq. 34), with ``r = z - x`` and ``D = |r|``:
    ``S = (I - (D^2 + 2 delta^2) / (D^2 + delta^2)^2 r r^T) / (D^2 + delta^2)``.
    """
    r = _offsets(x, z)
    s2 = np.sum(r * r, axis=-1) + delta**2
    a = 1.0 / s2
    b = (s2 + delta**2) / s2**3
    rr = r[..., :, None] * r[..., None, :]
    return a[..., None, None] * np.eye(3) - b[..., None, None] * rr


def bearing_information(
    x: ArrayLike, z: ArrayLike, sigma_m: float, prior_cov: ArrayLike, delta: float
) -> FloatArray:
    """Information matrices ``J_delta(x_i; z_1:M)`` of every setpoint, shape ``(N, 3, 3)``.

    Paper 004 eq. 7: ``Sigmabar^-1 + sigma_m^-2 sum_j S_delta(x_i; z_j)`` with ``S_delta`` of
    eq. 34 summed in place: ``sum_j S = (sum_j a_j) I - sum_j b_j r_j r_j^T``.
    """
    r = _offsets(x, z)
    s2 = np.sum(r * r, axis=-1) + delta**2
    a = np.sum(1.0 / s2, axis=1)
    b = (s2 + delta**2) / s2**3
    outer = np.swapaxes(r * b[..., None], 1, 2) @ r
    sum_terms = a[:, None, None] * np.eye(3) - outer
    return prior_information(prior_cov) + sum_terms / sigma_m**2


def trace_of_inverse_3x3(j: ArrayLike) -> FloatArray:
    """``tr(J^-1)`` of symmetric ``(..., 3, 3)`` matrices: sum of principal 2x2 minors over det."""
    j = np.asarray(j, dtype=float)
    a, b, c = j[..., 0, 0], j[..., 1, 1], j[..., 2, 2]
    d, e, f = j[..., 0, 1], j[..., 0, 2], j[..., 1, 2]
    minors = (b * c - f * f) + (a * c - e * e) + (a * b - d * d)
    det = a * (b * c - f * f) - d * (d * c - f * e) + e * (d * f - b * e)
    return minors / det


def covariance_trace(
    x: ArrayLike, z: ArrayLike, sigma_m: float, prior_cov: ArrayLike, delta: float
) -> FloatArray:
    """``tr(Sigma_delta(x_i; z_1:M)) = tr(J_delta^-1)`` per setpoint, shape ``(N,)`` (eq. 7, 9)."""
    return trace_of_inverse_3x3(bearing_information(x, z, sigma_m, prior_cov, delta))


def covariance_trace_gradient(
    x: ArrayLike, z: ArrayLike, sigma_m: float, prior_cov: ArrayLike, delta: float
) -> FloatArray:
    """``d tr(J_delta(x_i)^-1) / d z_j``, shape ``(N, M, 3)``.

    Paper 004 eq. 10: ``d tr(J^-1)/d theta = -tr(J^-2 dJ/d theta)``. Only the ``j``-th term of
    ``J(x_i)`` depends on ``z_j``; writing ``S = a(u) I - b(u) r r^T`` with ``u = |r|^2``,
    ``a = 1/(u + delta^2)``, ``b = (u + 2 delta^2)/(u + delta^2)^3``, ``W = J^-2`` gives

        tr(W dS/dr) = 2 r (a' tr W - b' r^T W r) - 2 b W r,
        a' = -1/(u + delta^2)^2,  b' = -(2u + 5 delta^2)/(u + delta^2)^4,

    and ``d tr(J^-1)/d z_j = -sigma_m^-2 tr(W dS/dr)`` since ``dr/dz_j = I``.
    """
    r = _offsets(x, z)
    j_inv = np.linalg.inv(bearing_information(x, z, sigma_m, prior_cov, delta))
    w = j_inv @ j_inv  # (N, 3, 3), symmetric
    u = np.sum(r * r, axis=-1)
    s2 = u + delta**2
    b = (s2 + delta**2) / s2**3
    da = -1.0 / s2**2
    db = -(2.0 * u + 5.0 * delta**2) / s2**4
    wr = np.einsum("nab,nmb->nma", w, r)
    rwr = np.sum(r * wr, axis=-1)
    tr_w = np.trace(w, axis1=-2, axis2=-1)[:, None]
    tr_w_ds = 2.0 * r * (da * tr_w - db * rwr)[..., None] - 2.0 * b[..., None] * wr
    return -tr_w_ds / sigma_m**2


def smoothing_zeta_squared(
    r_tol_m: float, r_min_m: float, n_landmarks: int, sigma_m: float, eta: float
) -> float:
    """``zeta^2 = (R_tol / R_min)^2 M sigma_m^-2 (2 / eta)`` (paper 004 eq. 16).

    Chosen so that every covariance trace below ``s_0 >= R_tol^2`` (eq. 12, 15) is within a
    factor ``1 + eta`` of the unsmoothed one (Theorem V.1). Note: the paper's example values
    (eq. 17: ratio 10, M 10, sigma_m 1e-2, eta 0.1) give 2e8 by this formula, while eq. 18
    states 2e9; :data:`PAPER_ZETA_SQUARED` keeps the paper's (more conservative) number.
    """
    return (r_tol_m / r_min_m) ** 2 * n_landmarks / sigma_m**2 * 2.0 / eta


def smoothing_delta(
    r_min_m: float,
    zeta_squared: float = PAPER_ZETA_SQUARED,
    zeta_cap: float = ZETA_CAP,
    fraction: float = 0.5,
) -> float:
    """Smoothing ``delta`` inside the interval ``(0, R_min / zeta)`` of Theorem V.1.

    ``zeta = min(sqrt(zeta^2), zeta_cap)`` (paper 004 eq. 18 and the cap of 1e5 after it) and
    ``delta = fraction * R_min / zeta`` with ``0 < fraction < 1`` so the bound is strict.
    """
    if not (r_min_m > 0.0 and zeta_squared > 1.0 and 0.0 < fraction < 1.0):
        raise ValueError("need r_min_m > 0, zeta_squared > 1 and 0 < fraction < 1")
    zeta = min(float(np.sqrt(zeta_squared)), zeta_cap)
    return fraction * r_min_m / zeta
