"""One agent's star of angles: everything an agent needs from its own angles, from one geometry.

Agent ``i`` forms the angles ``(i, j, k)``, ``j < k``, between every two neighbours it may
see (paper 003 sec. 2.2). With ``r_j = p_j - p_i``, ``d_j = |r_j|``, ``b_j = r_j / d_j`` and
``C_jk = b_j . b_k`` (the angle measurement ``f_ijk``), the row of the angle rigidity matrix
(paper 003 eq. 3) has the blocks

    ``R_jk = P_j b_k / d_j = (b_k - C_jk b_j) / d_j``  at ``p_j``,  ``R_kj`` at ``p_k``,

and minus their sum at ``p_i``. Every per-angle quantity is therefore an entry of an ``M x M``
matrix over ordered neighbour pairs, and every sum over angles is a matrix product: this
module never loops over angles and never forms the ``3 (M + 1)`` square local Gram matrix
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

from onboard.geometry import E3, FloatArray, IntArray
from onboard.rigidity.weights import SensingModel, sensing_weights


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
    """Agent ``i``'s star from its estimate, its yaw and its ``M`` neighbours' estimates ``(M, 3)``.

    Raises ``ValueError`` when a neighbour coincides with ``i`` (a bearing is undefined).
    """
    p_i = np.asarray(p_own_ned, dtype=float)
    r = np.asarray(p_nbr_ned, dtype=float).reshape(-1, 3) - p_i
    d = np.sqrt(np.einsum("md,md->m", r, r))
    if len(d) and not (d.min() > 0.0 and d.max() < np.inf):
        raise ValueError("a neighbour estimate coincides with the agent's (or is not finite)")
    b = r / d[:, None]
    c_axis = np.array([np.cos(yaw_own_rad), np.sin(yaw_own_rad), 0.0])
    s_c = np.array([-c_axis[1], c_axis[0], 0.0])
    cos_axis = b @ c_axis
    w_r, dw_r, w_f, dw_f = sensing_weights(d, cos_axis, model)
    mask = _off_diagonal(len(d))
    dh_dr = ((dw_r * d + w_r) * w_f)[:, None] * b + (w_r * dw_f)[:, None] * (
        c_axis - cos_axis[:, None] * b
    )
    h = w_r * w_f * d
    return Star(
        r=r,
        d=d,
        b=b,
        cos=b @ b.T,
        mask=mask,
        h=h,
        w=h[:, None] * h[None, :] * mask,
        dh_dr=dh_dr,
        dh_dyaw=w_r * dw_f * d * (b @ s_c),
    )


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


def _row_sums(s: Star, coef: FloatArray) -> FloatArray:
    """``sum_k coef_jk R_jk`` for every ``j``, ``(M, 3)``."""
    return (coef @ s.b - (coef * s.cos).sum(axis=1)[:, None] * s.b) / s.d[:, None]


def _with_own(blocks: FloatArray) -> FloatArray:
    """Stack ``-sum_j blocks_j`` (agent ``i``'s block) on top of the neighbours' ``(M + 1, 3)``."""
    return np.concatenate((-blocks.sum(axis=0, keepdims=True), blocks))


def _projections(s: Star, delta: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``a_j = b_j . delta_j`` and ``g_jk = R_jk . delta_j + R_kj . delta_k`` ``(M, M)``."""
    a = np.einsum("md,md->m", s.b, delta)
    g1 = (delta @ s.b.T - s.cos * a[:, None]) / s.d[:, None]
    return a, g1 + g1.T


def weighted_matvec(s: Star, v_own: ArrayLike, v_nbr: ArrayLike) -> FloatArray:
    """The star's part of ``M_w V`` (paper 003 eq. 16), own block first.

    ``v_own`` is ``V_i``, ``(3,)`` or ``(3, k)`` for ``k`` vectors at once; ``v_nbr`` the
    neighbours' blocks, ``(M, 3)`` or ``(M, 3, k)``. Returns ``(M + 1, 3)`` or ``(M + 1, 3, k)``.
    """
    own = np.asarray(v_own, dtype=float)
    cols = own.shape[1:]
    own = own.reshape(3, -1)
    k = own.shape[1]
    if s.size < 2:
        return np.zeros((s.size + 1, 3, *cols))
    # layout (j, column, l): every sum over neighbours l is a matrix product
    delta = (np.asarray(v_nbr, dtype=float).reshape(s.size, 3, k) - own).transpose(0, 2, 1)
    a = (delta * s.b[:, None, :]).sum(axis=2)  # a_jc = b_j . delta_jc
    g1 = (delta @ s.b.T - s.cos[:, None, :] * a[:, :, None]) / s.d[:, None, None]
    q = s.w[:, None, :] * (g1 + g1.transpose(2, 1, 0))
    rows = (q @ s.b - (q * s.cos[:, None, :]).sum(axis=2)[:, :, None] * s.b[:, None, :]) / s.d[
        :, None, None
    ]
    out = np.concatenate((-rows.sum(axis=0, keepdims=True), rows)).transpose(0, 2, 1)
    return out.reshape(s.size + 1, 3, *cols)


def form_gradient(
    s: Star, v_own: ArrayLike, v_nbr: ArrayLike
) -> tuple[float, FloatArray, FloatArray, float]:
    """The star's part of ``v^T M_w v``, of ``M_w v`` and of its gradient at fixed ``v``.

    Returns ``(value, mv (M + 1, 3), grad_p (M + 1, 3), d/dpsi_i)`` (own block first; paper 003
    eq. 16 and 21; derivation in the module docstring).
    """
    delta = np.asarray(v_nbr, dtype=float).reshape(-1, 3) - np.asarray(v_own, dtype=float)
    m = s.size
    if m < 2:
        return 0.0, np.zeros((m + 1, 3)), np.zeros((m + 1, 3)), 0.0
    a, g = _projections(s, delta)
    q = s.w * g
    mv = _with_own(_row_sums(s, q))
    grad_p, grad_yaw = _form_gradient_terms(s, delta, a, g, q)
    value = 0.5 * float((q * g).sum())
    return value, mv, grad_p, grad_yaw


def form_gradient_only(s: Star, v_own: ArrayLike, v_nbr: ArrayLike) -> tuple[FloatArray, float]:
    """:func:`form_gradient`'s ``(grad_p (M + 1, 3), d/dpsi_i)`` alone (paper 003 eq. 21), for
    a caller that needs neither the value nor ``M_w v`` (the rigidity layer's Ritz vector)."""
    delta = np.asarray(v_nbr, dtype=float).reshape(-1, 3) - np.asarray(v_own, dtype=float)
    m = s.size
    if m < 2:
        return np.zeros((m + 1, 3)), 0.0
    a, g = _projections(s, delta)
    return _form_gradient_terms(s, delta, a, g, s.w * g)


def _form_gradient_terms(
    s: Star, delta: FloatArray, a: FloatArray, g: FloatArray, q: FloatArray
) -> tuple[FloatArray, float]:
    """``dF/dp`` ``(M + 1, 3)`` and ``dF/dpsi_i`` from ``delta``, ``a``, ``g`` and ``q = W * g``
    (module docstring, "Form gradient")."""
    coef = (g * g * s.mask) @ s.h  # c_j = sum_k h_k g_jk^2
    big_q = 2.0 * q
    pd = delta - a[:, None] * s.b  # P_j delta_j
    e = pd @ s.b.T  # E_jk = b_k . Pd_j
    inv_d = 1.0 / s.d
    inv_d2 = inv_d**2
    qc = (big_q * s.cos).sum(axis=1)  # sum_k Q_jk C_jk
    grad_r = (
        -(a * inv_d)[:, None] * ((big_q @ s.b - qc[:, None] * s.b) / s.d[:, None])  # _row_sums
        - ((big_q * e).sum(axis=1) * inv_d2)[:, None] * s.b
        - (qc * inv_d2)[:, None] * pd
        + inv_d[:, None] * (big_q @ (pd * inv_d[:, None]) - ((big_q * e.T) @ inv_d)[:, None] * s.b)
        + coef[:, None] * s.dh_dr
    )
    return _with_own(grad_r), float(coef @ s.dh_dyaw)


def weighted_degree(s: Star) -> FloatArray:
    """The star's part of ``s_v = sum_{a touching v} W_a |r_a|^2`` per vertex ``(M + 1,)``, own
    first. The network's ``max_v s_v`` bounds ``lambda_max(M_w)`` (module docstring)."""
    c = s.cos
    inv_d = 1.0 / s.d
    inv_d2 = inv_d**2
    r2 = (
        2.0
        * (1.0 - c * c)
        * (inv_d2[:, None] + inv_d2[None, :] - c * (inv_d[:, None] * inv_d[None, :]))
    )
    per_angle = s.w * r2
    per_nbr = per_angle.sum(axis=1)
    return np.concatenate([[0.5 * per_nbr.sum()], per_nbr])


def angle_gradient(s: Star, beta_nbr_body: ArrayLike, k_angle: float) -> tuple[float, FloatArray]:
    """Angle-localization terms ``k_A sum_a (f_a(phat) - f_a)^2`` of the star and their gradient
    ``(M + 1, 3)`` (paper 003 eq. 10-11); ``beta_nbr_body`` are the measured unit bearings."""
    beta = np.asarray(beta_nbr_body, dtype=float).reshape(-1, 3)
    if len(beta) != s.size:
        raise ValueError(f"{s.size} neighbour estimates for {len(beta)} bearings")
    if s.size < 2:
        return 0.0, np.zeros((s.size + 1, 3))
    e = (s.cos - beta @ beta.T) * s.mask
    return 0.5 * k_angle * float((e * e).sum()), _with_own(2.0 * k_angle * _row_sums(s, e))


def vertical_gradient(
    s: Star, beta_nbr_body: ArrayLike, k_vertical: float
) -> tuple[float, FloatArray]:
    """Gravity term ``k_z sum_j (b_j . e3 - beta_j . e3)^2`` and its gradient ``(M + 1, 3)``
    (as :func:`onboard.estimation.angle_localization.local_vertical_gradient`)."""
    beta = np.asarray(beta_nbr_body, dtype=float).reshape(-1, 3)
    if len(beta) != s.size:
        raise ValueError(f"{s.size} neighbour estimates for {len(beta)} bearings")
    e = s.b[:, 2] - beta[:, 2]
    db = (E3 - s.b[:, 2:3] * s.b) / s.d[:, None]
    return k_vertical * float(e @ e), _with_own(2.0 * k_vertical * e[:, None] * db)
