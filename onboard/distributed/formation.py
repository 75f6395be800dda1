"""Bearing (+ distance) formation control (paper 002 eq. 18-21 and 23), general ``f_C``.

Rotations are known, so bearings are world-frame unit vectors (``t = R_i beta``). Project
notation (as :mod:`onboard.control.formation`): ``t_ij`` the measured bearing, ``t*_ij`` the
desired one (paper 002 writes ``t~_ij`` and ``t_ij``), ``d_ij = |p_j - p_i|``,
``c_ij = t_ij . t*_ij``. Pairwise cost (eq. 18-19, plus eq. 23 on edges with a range)::

    phi_ij = d_ij f_C(c_ij) + [range] f_D(d_ij c_ij - d*_ij)

and its gradient (eq. 20; ``d_ij c_ij = (p_j - p_i) . t*_ij``)::

    grad_{p_i} phi_ij = -f_C(c) t_ij - f_C'(c) (I - t_ij t_ij^T) t*_ij - [range] f_D'(d c - d*) t*_ij
    grad_{p_j} phi_ij = -grad_{p_i} phi_ij

uses measured bearings (and the measured range ``d_ij`` where there is one) only. ``f_C``
must satisfy eq. 21 (:func:`onboard.distributed.reshaping.fc_condition`); with ``f_C(c) = 1 - c``
the gradient is ``t*_ij - t_ij``, the law :func:`onboard.control.formation.formation_velocity`
flies today (the tests check the two agree). ``d*_ij`` is the desired distance of a ranged edge:
with one range the flow fixes the formation's scale, without any it can only shrink it.

A bearing that cannot be measured (agents at the same point) is ``nan``; its edge contributes
nothing (:func:`formation_gradients` reports how many were dropped).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from onboard.control.formation import bearing_error_deg
from onboard.distributed.flow import EdgeGradients, check_edges
from onboard.distributed.reshaping import F_C, F_D, ReshapeC, ReshapeD
from onboard.geometry import FloatArray

__all__ = [
    "bearing_error_deg",
    "bearings_from_positions",
    "formation_costs",
    "formation_gradients",
]


def bearings_from_positions(p: ArrayLike, edges: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Ideal measured bearings ``t_ij`` ``(E, d)`` (``nan`` for coincident agents) and distances
    ``d_ij`` ``(E,)`` from positions ``(N, d)``."""
    pp = np.asarray(p, dtype=float)
    e = check_edges(edges, len(pp))
    v = pp[e[:, 1]] - pp[e[:, 0]]
    d = np.linalg.norm(v, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.where(d[:, None] > 1e-12, v / d[:, None], np.nan)
    return t, d


def _ranges(x: ArrayLike | None, n: int, name: str) -> FloatArray:
    if x is None:
        return np.full(n, np.nan)
    r = np.asarray(x, dtype=float).reshape(-1)
    if r.shape != (n,):
        raise ValueError(f"{name} must have one entry per edge ({n})")
    return r


def formation_costs(
    p: ArrayLike,
    edges: ArrayLike,
    t_des: ArrayLike,
    d_des_m: ArrayLike | None = None,
    f_c: ReshapeC = F_C,
    f_d: ReshapeD = F_D,
) -> FloatArray:
    """``phi_ij`` of paper 002 eq. 18 (+ 23) from true positions ``(N, d)``: ``(E,)``.
    ``d_des_m`` is ``nan`` on edges without a range term."""
    t, d = bearings_from_positions(p, edges)
    td = np.asarray(t_des, dtype=float)
    c = np.clip(np.nan_to_num(np.sum(t * td, axis=1), nan=1.0), -1.0, 1.0)
    out = d * f_c.value(c)
    dd = _ranges(d_des_m, len(d), "d_des_m")
    has = np.isfinite(dd)
    out[has] += f_d.value(d[has] * c[has] - dd[has])
    return out


def formation_gradients(
    t_meas: ArrayLike,
    t_des: ArrayLike,
    range_m: ArrayLike | None = None,
    d_des_m: ArrayLike | None = None,
    f_c: ReshapeC = F_C,
    f_d: ReshapeD = F_D,
) -> tuple[EdgeGradients, int]:
    """Gradient of paper 002 eq. 18 (+ 23), eq. 20, from measurements only.

    ``t_meas, t_des`` ``(E, d)`` unit bearings (``nan`` rows are dropped), ``range_m`` ``(E,)``
    measured distances and ``d_des_m`` ``(E,)`` desired ones (``nan`` where absent; the distance
    term needs both). Returns the edge gradients and the number of dropped edges."""
    t = np.asarray(t_meas, dtype=float)
    td = np.asarray(t_des, dtype=float)
    if t.shape != td.shape or t.ndim != 2:
        raise ValueError("t_meas and t_des must both be (E, d)")
    ok = np.all(np.isfinite(t), axis=1)
    t0 = np.where(ok[:, None], t, 0.0)
    c = np.clip(np.sum(t0 * td, axis=1), -1.0, 1.0)
    proj = td - np.sum(t0 * td, axis=1)[:, None] * t0  # (I - t t^T) t*
    g_src = -f_c.value(c)[:, None] * t0 - f_c.deriv(c)[:, None] * proj
    rg = _ranges(range_m, len(t), "range_m")
    dd = _ranges(d_des_m, len(t), "d_des_m")
    has = np.isfinite(rg) & np.isfinite(dd) & ok
    g_src[has] -= f_d.deriv(rg[has] * c[has] - dd[has])[:, None] * td[has]
    g_src[~ok] = 0.0
    return EdgeGradients(g_src=g_src, g_dst=-g_src), int(np.count_nonzero(~ok))
