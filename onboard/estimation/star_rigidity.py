"""One agent's star of angles: everything an agent needs from its own angles, from one geometry.

Agent ``i`` forms the angles ``(i, j, k)``, ``j < k``, between every two neighbours it may
see (paper 003 sec. 2.2). With ``r_j = p_j - p_i``, ``d_j = |r_j|``, ``b_j = r_j / d_j`` and
``C_jk = b_j . b_k`` (the angle measurement ``f_ijk``), the row of the angle rigidity matrix
(paper 003 eq. 3) has the blocks

    ``R_jk = P_j b_k / d_j = (b_k - C_jk b_j) / d_j``  at ``p_j``,  ``R_kj`` at ``p_k``,

and minus their sum at ``p_i``. Every per-angle quantity is therefore an entry of an ``M x M``
matrix over ordered neighbour pairs; the sums run in :mod:`onboard.rigidity.kernels` (the one
implementation the compiled team engine runs too), which never forms the ``3 (M + 1)`` square
local Gram matrix
(:mod:`onboard.rigidity.angle` evaluates the same quantities for whole frameworks; the tests
check one against the other and against finite differences).

**Weighted matrix-vector product** (paper 003 eq. 16-18). ``W_jk = h_j h_k`` with
``h_j = w_range(d_j) w_fov(c_i . b_j) d_j``. For a vector ``v`` with blocks ``v_i, v_j`` and
``delta_j = v_j - v_i``, ``a_j = b_j . delta_j``,

    ``g_jk = R_jk . delta_j + R_kj . delta_k``,  ``G1_jk = R_jk . delta_j = (b_k . delta_j - C_jk a_j) / d_j``,

and with ``q = W * g`` the star's part of ``M_w v`` is ``(M_w v)_j = sum_k q_jk R_jk``,
``(M_w v)_i = -sum_j (M_w v)_j``.

**Form gradient** (paper 003 eq. 21 with ``v`` fixed). ``F = sum_{j<k} W_jk g_jk^2``;
``dF/dr_j = c_j dh_j/dr_j + sum_k Q_jk dg_jk/dr_j`` with ``c_j = sum_k h_k g_jk^2``,
``Q = 2 W * g``, and, writing ``Pd_j = P_j delta_j``, ``E_jk = b_k . Pd_j``,

    ``dg_jk/dr_j = -(a_j / d_j) R_jk - (E_jk / d_j^2) b_j - (C_jk / d_j^2) Pd_j
                  + (Pd_k - E_kj b_j) / (d_j d_k)``

(the second derivative of the unit bearing, :mod:`onboard.rigidity.angle`). ``dF/dp_i`` is
``-sum_j dF/dr_j``; the yaw enters through the field-of-view weights only:
``dF/dpsi_i = sum_j c_j dh_j/dpsi_i``.

**Weighted degree** (a bound on ``lambda_max``). For any unit ``x``,
``x^T M_w x = sum_a W_a (r_a . x)^2 <= sum_a W_a |r_a|^2 |x_a|^2 <= max_v s_v`` with
``s_v = sum_{a touching v} W_a |r_a|^2`` (Cauchy-Schwarz, then each angle's three blocks).
Per angle ``|r_a|^2 = 2 (1 - C_jk^2)(1/d_j^2 + 1/d_k^2 - C_jk / (d_j d_k))``. Like twice the
maximum degree for a graph Laplacian, ``max_v s_v`` is a local, cheap and safe step-size scale
for the distributed power iteration (:mod:`onboard.estimation.distributed_eigen`).

**Angle localization** (paper 003 eq. 10-11). With measured cosines ``Cm_jk`` (from body
bearings: angles are frame-free) and residuals ``e_jk = C_jk - Cm_jk``, the star's part of
``k_A sum_a e_a^2`` has gradient ``2 k_A sum_k e_jk R_jk`` at ``p_j``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import FloatArray, IntArray
from onboard.rigidity import kernels as kn
from onboard.rigidity.weights import SensingModel


@dataclass(frozen=True, slots=True)
class Star:
    """Geometry of agent ``i`` and its ``M`` neighbours (module docstring), all estimated."""

    r: FloatArray  # (M, 3) r_j = p_j - p_i
    d: FloatArray  # (M,)
    b: FloatArray  # (M, 3) unit bearings b_j
    cos: FloatArray  # (M, M) C_jk = b_j . b_k
    mask: FloatArray  # (M, M) 1 off the diagonal
    h: FloatArray  # (M,) h_j = w_j d_j
    w: FloatArray  # (M, M) W_jk = h_j h_k off the diagonal, 0 on it
    dh_dr: FloatArray  # (M, 3)
    dh_dyaw: FloatArray  # (M,)

    @property
    def size(self) -> int:
        """Number of neighbours ``M``."""
        return len(self.d)


@cache
def _off_diagonal(m: int) -> FloatArray:
    """``1 - I_m`` (read-only, shared by every star of ``m`` neighbours)."""
    mask = 1.0 - np.eye(m)
    mask.flags.writeable = False
    return mask


def star(
    p_own_ned: ArrayLike, yaw_own_rad: float, p_nbr_ned: ArrayLike, model: SensingModel
) -> Star:
    """Agent ``i``'s star from its estimate, its yaw and its ``M`` neighbours' estimates ``(M, 3)``
    (:func:`onboard.rigidity.kernels.star`).

    Raises ``ValueError`` when a neighbour coincides with ``i`` (a bearing is undefined).
    """
    p_i = np.asarray(p_own_ned, dtype=float).reshape(3)
    p_nbr = np.asarray(p_nbr_ned, dtype=float).reshape(-1, 3)
    r, d, b, cos, h, w, dh_dr, dh_dyaw = kn.star(p_i, float(yaw_own_rad), p_nbr, *model.steps)
    return Star(r, d, b, cos, _off_diagonal(len(d)), h, w, dh_dr, dh_dyaw)


def restrict(s: Star, idx: IntArray) -> Star:
    """The star over the neighbours ``idx`` only (e.g. those seen now, out of the candidates)."""
    col = np.asarray(idx)
    ix = (col[:, None], col)  # np.ix_(idx, idx)
    return Star(
        s.r[idx],
        s.d[idx],
        s.b[idx],
        s.cos[ix],
        s.mask[ix],
        s.h[idx],
        s.w[ix],
        s.dh_dr[idx],
        s.dh_dyaw[idx],
    )


def weighted_matvec(s: Star, v_own: ArrayLike, v_nbr: ArrayLike) -> FloatArray:
    """The star's part of ``M_w V`` (paper 003 eq. 16), own block first
    (:func:`onboard.rigidity.kernels.weighted_matvec`).

    ``v_own`` is ``V_i``, ``(3,)`` or ``(3, k)`` for ``k`` vectors at once; ``v_nbr`` the
    neighbours' blocks, ``(M, 3)`` or ``(M, 3, k)``. Returns ``(M + 1, 3)`` or ``(M + 1, 3, k)``.
    """
    own = np.asarray(v_own, dtype=float)
    cols = own.shape[1:]
    own = own.reshape(3, -1)
    nbr = np.asarray(v_nbr, dtype=float).reshape(s.size, 3, own.shape[1])
    out = kn.weighted_matvec(s.b, s.d, s.cos, s.w, own, nbr)
    return out.reshape(s.size + 1, 3, *cols)


def form_gradient(
    s: Star, v_own: ArrayLike, v_nbr: ArrayLike
) -> tuple[float, FloatArray, FloatArray, float]:
    """The star's part of ``v^T M_w v``, of ``M_w v`` and of its gradient at fixed ``v``.

    Returns ``(value, mv (M + 1, 3), grad_p (M + 1, 3), d/dpsi_i)`` (own block first; paper 003
    eq. 16 and 21; derivation in the module docstring).
    """
    own = np.asarray(v_own, dtype=float).reshape(3)
    nbr = np.asarray(v_nbr, dtype=float).reshape(-1, 3)
    mv = weighted_matvec(s, own, nbr)
    value = float(own @ mv[0] + (nbr * mv[1:]).sum())  # = sum_{j<k} W_jk g_jk^2 of the star
    grad_p, grad_yaw = form_gradient_only(s, own, nbr)
    return value, mv, grad_p, grad_yaw


def form_gradient_only(s: Star, v_own: ArrayLike, v_nbr: ArrayLike) -> tuple[FloatArray, float]:
    """:func:`form_gradient`'s ``(grad_p (M + 1, 3), d/dpsi_i)`` alone (paper 003 eq. 21), for
    a caller that needs neither the value nor ``M_w v`` (the rigidity layer's Ritz vector;
    :func:`onboard.rigidity.kernels.form_gradient_only`)."""
    own = np.asarray(v_own, dtype=float).reshape(3)
    nbr = np.asarray(v_nbr, dtype=float).reshape(-1, 3)
    grad_p, grad_yaw = kn.form_gradient_only(
        s.b, s.d, s.cos, s.h, s.w, s.dh_dr, s.dh_dyaw, own, nbr
    )
    return grad_p, float(grad_yaw)


def weighted_degree(s: Star) -> FloatArray:
    """The star's part of ``s_v = sum_{a touching v} W_a |r_a|^2`` per vertex ``(M + 1,)``, own
    first. The network's ``max_v s_v`` bounds ``lambda_max(M_w)`` (module docstring)."""
    return kn.weighted_degree(s.d, s.cos, s.w)


def _beta(beta_nbr_body: ArrayLike, s: Star) -> FloatArray:
    beta = np.asarray(beta_nbr_body, dtype=float).reshape(-1, 3)
    if len(beta) != s.size:
        raise ValueError(f"{s.size} neighbour estimates for {len(beta)} bearings")
    return beta


def angle_gradient(s: Star, beta_nbr_body: ArrayLike, k_angle: float) -> tuple[float, FloatArray]:
    """Angle-localization terms ``k_A sum_a (f_a(phat) - f_a)^2`` of the star and their gradient
    ``(M + 1, 3)`` (paper 003 eq. 10-11); ``beta_nbr_body`` are the measured unit bearings."""
    value, grad = kn.angle_gradient(s.b, s.d, s.cos, _beta(beta_nbr_body, s), k_angle)
    return float(value), grad


def vertical_gradient(
    s: Star, beta_nbr_body: ArrayLike, k_vertical: float
) -> tuple[float, FloatArray]:
    """Gravity term ``k_z sum_j (b_j . e3 - beta_j . e3)^2`` and its gradient ``(M + 1, 3)``
    (as :func:`onboard.estimation.angle_localization.local_vertical_gradient`)."""
    value, grad = kn.vertical_gradient(s.b, s.d, _beta(beta_nbr_body, s), k_vertical)
    return float(value), grad
