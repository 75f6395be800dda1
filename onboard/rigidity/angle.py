"""Angle rigidity: the angle rigidity matrix, its eigenvalue, and that eigenvalue's gradient.

Paper 003 ("Angle-based Localization and Rigidity Maintenance Control for Multi-Robot
Networks"); its equations lost their symbols in extraction, so everything here follows the
restatement in ``docs/equations.md`` ("Angle rigidity") and is re-derived below.

**Angles.** Agent ``i`` measures the bearings ``b_ij``, ``b_ik`` to two neighbours; the angle
measurement is ``f_ijk = b_ij . b_ik`` (frame-free: the same in body and world frames). The
angle set ``A = {(i, j, k): (i, j), (i, k) in E, j < k}`` (paper 003 sec. 2.2).

**Rigidity matrix** (paper 003 eq. 3). With ``D b(r)[delta] = P delta / d`` the derivative of
the unit vector ``b(r) = r / |r|`` (``P = I - b b^T``),

    ``df/dp_j = b_ik^T P_ij / d_ij``,  ``df/dp_k = b_ij^T P_ik / d_ik``,
    ``df/dp_i = -(df/dp_j + df/dp_k)``.

Trivial motions (which change no angle, paper 003 eq. 4): ``d`` translations, ``d(d-1)/2``
rotations and one scaling, 4 in 2-D and 7 in 3-D. A framework is infinitesimally angle rigid (IAR) iff
``rank R_A = dN - 4`` (2-D) or ``3N - 7`` (3-D). The rigidity eigenvalue is the smallest
eigenvalue of ``M = R_A^T R_A`` beyond the trivial ones: the 5th (2-D) or 8th (3-D) smallest
(paper 003 eq. 9).

**Weighted eigenvalue** (paper 003 eq. 16-18). ``M_w = R_A^T W R_A`` with
``W_a = w_ij w_ik s_ijk``, ``w_ij`` the sensing weights of :mod:`onboard.rigidity.weights` and
``s_ijk = d_ij d_ik``. Every row of ``R_A`` scales like ``1/scale`` when all positions are
scaled, so ``r_a r_a^T`` scales like ``1/scale^2`` and ``s_ijk`` cancels it exactly. The fov
weight depends on directions only and is scale invariant; the range weight is a physical limit
and is scale invariant only where it is saturated (``d < (1 - range_transition) range``).

**Gradient** (paper 003 eq. 20-21). For a simple eigenvalue with unit eigenvector ``v``,
``lambda = v^T M_w v = sum_a W_a g_a^2`` with ``g_a = r_a . v`` and
``d lambda / dx = sum_a [dW_a/dx g_a^2 + 2 W_a g_a dg_a/dx]``. Writing
``delta_j = v_j - v_i``, ``delta_k = v_k - v_i``,

    ``g = b_ik . Db_ij[delta_j] + b_ij . Db_ik[delta_k]``,

which depends on ``p`` only through ``r_ij = p_j - p_i`` and ``r_ik = p_k - p_i``. With the
second derivative of the unit bearing
``D2b[delta, eps] = -(1/d^2)[(b.delta) P eps + (b.eps) P delta + (delta^T P eps) b]``,

    ``dg/dr_ij = -(1/d_ij^2)[(b_ij.delta_j) P_ij b_ik + (b_ik^T P_ij delta_j) b_ij
                             + (b_ij.b_ik) P_ij delta_j] + P_ij Db_ik[delta_k] / d_ij``

and symmetrically for ``r_ik`` (swap ``j`` and ``k``). ``W_a = h_ij h_ik`` factors into edge terms
``h_ij = w_range(d_ij) w_fov(c_i . b_ij) d_ij`` with
``dh/dr = (w_range' w_fov d + w_range w_fov) b + w_range w_fov' P c_i`` and, since
``dc_i/dpsi_i = S c_i`` (``S = hat(e3)``), ``dh/dpsi_i = w_range w_fov' d (S c_i . b)``.
All sums run vectorized over angles and are scattered to agents with ``np.bincount`` /
``np.add.at``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import FloatArray, IntArray, camera_axis_ned
from onboard.graph import angle_set_with_rows, normalize_edges
from onboard.rigidity.rank import RANK_RTOL, numerical_rank
from onboard.rigidity.weights import EdgeWeights, SensingModel, edge_weights


def trivial_motion_count(dim: int) -> int:
    """Motions that change no angle: ``d`` translations, ``d(d-1)/2`` rotations, 1 scaling."""
    if dim not in (2, 3):
        raise ValueError(f"angle rigidity is defined here in 2-D and 3-D, got d = {dim}")
    return dim + dim * (dim - 1) // 2 + 1


def expected_angle_rank(n: int, dim: int) -> int:
    """Rank of ``R_A`` for an IAR framework of ``n`` agents: ``2N - 4`` (2-D), ``3N - 7`` (3-D)."""
    if n < 3:
        raise ValueError(f"angle rigidity needs at least 3 agents, got {n}")
    return dim * n - trivial_motion_count(dim)


# --------------------------------------------------------------------------- input checks


def _positions(p: ArrayLike) -> FloatArray:
    arr = np.asarray(p, dtype=float)
    if arr.ndim != 2 or arr.shape[1] not in (2, 3):
        raise ValueError(f"positions must be (N, 2) or (N, 3), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("positions contain NaN or inf")
    return arr


def _angles(angles: ArrayLike, n: int) -> IntArray:
    a = np.asarray(angles)
    if a.size == 0:
        return np.zeros((0, 3), dtype=np.int64)
    if a.ndim != 2 or a.shape[1] != 3 or not np.issubdtype(a.dtype, np.integer):
        raise ValueError(f"angles must be an (A, 3) integer array, got {a.dtype} {a.shape}")
    a = a.astype(np.int64)
    if a.min() < 0 or a.max() >= n:
        raise ValueError(f"angle vertex index out of range 0..{n - 1}")
    if np.any((a[:, 0] == a[:, 1]) | (a[:, 0] == a[:, 2]) | (a[:, 1] == a[:, 2])):
        raise ValueError("an angle (i, j, k) needs three distinct vertices")
    return a


def _edges(edges: ArrayLike, n: int) -> IntArray:
    e = np.asarray(edges)
    if e.size and (not np.issubdtype(e.dtype, np.integer) or e.ndim != 2 or e.shape[1] != 2):
        raise ValueError(f"edges must be an (E, 2) integer array, got {e.dtype} {e.shape}")
    e = normalize_edges(e)
    if len(e) and (e.min() < 0 or e.max() >= n):
        raise ValueError(f"edge vertex index out of range 0..{n - 1}")
    return e


# --------------------------------------------------------------------------- geometry


@dataclass(frozen=True)
class _AngleGeometry:
    """Per-angle bearings, distances and the two non-trivial blocks of each row of ``R_A``."""

    ijk: IntArray
    b_ij: FloatArray
    b_ik: FloatArray
    d_ij: FloatArray
    d_ik: FloatArray
    cos_jk: FloatArray  # f_ijk = b_ij . b_ik
    row_j: FloatArray  # df/dp_j = P_ij b_ik / d_ij
    row_k: FloatArray  # df/dp_k = P_ik b_ij / d_ik


def _angle_geometry(p: FloatArray, angles: IntArray) -> _AngleGeometry:
    i, j, k = angles.T
    r_ij = p[j] - p[i]
    r_ik = p[k] - p[i]
    d_ij = np.linalg.norm(r_ij, axis=1)
    d_ik = np.linalg.norm(r_ik, axis=1)
    if np.any(d_ij == 0.0) or np.any(d_ik == 0.0):
        raise ValueError("coincident agents: a bearing of some angle is undefined")
    b_ij = r_ij / d_ij[:, None]
    b_ik = r_ik / d_ik[:, None]
    cos_jk = np.einsum("ad,ad->a", b_ij, b_ik)
    row_j = (b_ik - cos_jk[:, None] * b_ij) / d_ij[:, None]
    row_k = (b_ij - cos_jk[:, None] * b_ik) / d_ik[:, None]
    return _AngleGeometry(angles, b_ij, b_ik, d_ij, d_ik, cos_jk, row_j, row_k)


def angle_function(p: ArrayLike, angles: ArrayLike) -> FloatArray:
    """Angle measurements ``f_ijk = b_ij . b_ik`` (cosines), shape ``(A,)`` (paper 003 sec. 2.2)."""
    pos = _positions(p)
    return _angle_geometry(pos, _angles(angles, len(pos))).cos_jk


def _row_blocks(geo: _AngleGeometry) -> FloatArray:
    """Rows of ``R_A`` as ``(A, 3, d)`` blocks at ``(p_i, p_j, p_k)``."""
    return np.stack([-(geo.row_j + geo.row_k), geo.row_j, geo.row_k], axis=1)


def _row_columns(geo: _AngleGeometry, dim: int) -> IntArray:
    """Column of every entry of :func:`_row_blocks`, flattened to ``(A, 3 d)``."""
    return (dim * geo.ijk[:, :, None] + np.arange(dim)).reshape(len(geo.ijk), 3 * dim)


def angle_rigidity_matrix(p: ArrayLike, angles: ArrayLike) -> FloatArray:
    """Angle rigidity matrix ``R_A = df/dp``, shape ``(A, d N)`` (paper 003 eq. 3).

    Columns are ``(p_0, ..., p_{N-1})`` with ``d`` coordinates each; row ``a = (i, j, k)`` holds
    ``b_ik^T P_ij / d_ij`` at ``p_j``, ``b_ij^T P_ik / d_ik`` at ``p_k`` and minus their sum at ``p_i``.
    """
    pos = _positions(p)
    n, dim = pos.shape
    geo = _angle_geometry(pos, _angles(angles, n))
    out = np.zeros((len(geo.ijk), dim * n))
    rows = np.arange(len(geo.ijk))[:, None]
    out[rows, _row_columns(geo, dim)] = _row_blocks(geo).reshape(len(geo.ijk), 3 * dim)
    return out


def _weighted_gram(geo: _AngleGeometry, n: int, dim: int, w_angle: FloatArray | None) -> FloatArray:
    """``R_A^T W R_A`` assembled block by block (never forms the dense ``A x dN`` matrix)."""
    rows = _row_blocks(geo).reshape(len(geo.ijk), 3 * dim)
    cols = _row_columns(geo, dim)
    scaled = rows if w_angle is None else rows * w_angle[:, None]
    outer = scaled[:, :, None] * rows[:, None, :]
    flat = cols[:, :, None] * (dim * n) + cols[:, None, :]
    gram = np.bincount(flat.ravel(), weights=outer.ravel(), minlength=(dim * n) ** 2)
    return gram.reshape(dim * n, dim * n)


SUBSET_EIGH_MIN = 120
"""Coordinates (``dN``, 40 agents in 3-D) from which :func:`_eigenpairs` computes only the
smallest pairs (SciPy's ``?syevr``) instead of the full spectrum: below it numpy's full
``?syevd`` is as fast or faster (measured on this machine, issue 27: 18 coordinates 26 us
against 45 us, 30 coordinates 67 against 76 us)."""


def _eigenpair(m: FloatArray, index: int) -> tuple[float, FloatArray]:
    """The ``index``-th smallest (0-based) eigenvalue of symmetric ``m`` and a unit eigenvector."""
    vals, vecs = _eigenpairs(m, index, 1)
    return float(vals[0]), vecs[:, 0]


def _eigenpairs(m: FloatArray, index: int, count: int) -> tuple[FloatArray, FloatArray]:
    """The ``index``-th to ``(index + count - 1)``-th smallest (0-based) eigenvalues of symmetric
    ``m`` ``(count,)`` and unit eigenvectors ``(dN, count)``.

    Up to :data:`SUBSET_EIGH_MIN` coordinates (every team a daemon flies) the full
    ``numpy.linalg.eigh`` is faster than a partial solve and keeps SciPy off the daemon's import
    path (issue 27: SciPy's linear algebra costs a daemon about 27 MB resident); larger matrices
    (studies, planners) import ``scipy.linalg`` here and compute only the pairs they need.
    """
    last = index + count - 1
    if m.shape[0] <= last:
        raise ValueError(f"need more than {last} coordinates for this eigenvalue, got {m.shape[0]}")
    if m.shape[0] < SUBSET_EIGH_MIN:
        vals, vecs = np.linalg.eigh(m)
        return vals[index : last + 1], vecs[:, index : last + 1]
    import scipy.linalg  # here: only for large teams, never on a daemon's path

    try:
        vals, vecs = scipy.linalg.eigh(m, subset_by_index=[0, last], check_finite=False)
    except np.linalg.LinAlgError:  # LAPACK ?syevr can fail ("Internal Error") on rare inputs
        vals, vecs = np.linalg.eigh(m)
    return vals[index : last + 1], vecs[:, index : last + 1]


# --------------------------------------------------------------------------- rank and eigenvalue


def angle_rigidity_rank(p: ArrayLike, edges: ArrayLike, tol: float = RANK_RTOL) -> int:
    """Numerical rank of ``R_A``: singular values above ``tol * sigma_max`` (see :data:`RANK_RTOL`)."""
    pos = _positions(p)
    e = _edges(edges, len(pos))
    angles, _, _ = angle_set_with_rows(e)
    if len(angles) == 0:
        return 0
    return numerical_rank(angle_rigidity_matrix(pos, angles), tol)


def is_infinitesimally_angle_rigid(p: ArrayLike, edges: ArrayLike, tol: float = RANK_RTOL) -> bool:
    """True iff ``rank R_A`` reaches ``dN - 4`` (2-D) or ``3N - 7`` (3-D) (paper 003 def. 2)."""
    pos = _positions(p)
    return angle_rigidity_rank(pos, edges, tol) == expected_angle_rank(*pos.shape)


def angle_rigidity_eigenvalue(p: ArrayLike, angles: ArrayLike) -> float:
    """Rigidity eigenvalue: 5th (2-D) or 8th (3-D) smallest eigenvalue of ``R_A^T R_A`` (eq. 9)."""
    pos = _positions(p)
    n, dim = pos.shape
    geo = _angle_geometry(pos, _angles(angles, n))
    return _eigenpair(_weighted_gram(geo, n, dim, None), trivial_motion_count(dim))[0]


# --------------------------------------------------------------------------- gradients


def _rotation_term(geo: _AngleGeometry, v: FloatArray, coef: FloatArray) -> FloatArray:
    """``sum_a coef_a dg_a/dp`` as an ``(N, d)`` array, ``g_a = r_a . v`` (module docstring).

    ``v`` (the eigenvector, ``(N, d)``) is held fixed: for a simple eigenvalue its derivative
    does not enter ``d lambda/dx``.
    """
    i, j, k = geo.ijk.T
    delta_j = v[j] - v[i]
    delta_k = v[k] - v[i]
    bj, bk, dj, dk, cos_jk = geo.b_ij, geo.b_ik, geo.d_ij[:, None], geo.d_ik[:, None], geo.cos_jk

    def proj(b: FloatArray, x: FloatArray) -> FloatArray:
        return x - np.einsum("ad,ad->a", b, x)[:, None] * b

    p_j_delta = proj(bj, delta_j)  # P_ij delta_j
    p_k_delta = proj(bk, delta_k)  # P_ik delta_k
    # dg/dr_ij = -(1/d_ij^2)[(b_ij.delta_j) P_ij b_ik + (b_ik.P_ij delta_j) b_ij
    #            + (b_ij.b_ik) P_ij delta_j] + P_ij (P_ik delta_k / d_ik) / d_ij
    grad_rj = -(
        np.einsum("ad,ad->a", bj, delta_j)[:, None] * geo.row_j * dj
        + np.einsum("ad,ad->a", bk, p_j_delta)[:, None] * bj
        + cos_jk[:, None] * p_j_delta
    ) / dj**2 + proj(bj, p_k_delta) / (dj * dk)
    grad_rk = -(
        np.einsum("ad,ad->a", bk, delta_k)[:, None] * geo.row_k * dk
        + np.einsum("ad,ad->a", bj, p_k_delta)[:, None] * bk
        + cos_jk[:, None] * p_k_delta
    ) / dk**2 + proj(bk, p_j_delta) / (dj * dk)
    out = np.zeros_like(v)
    np.add.at(out, j, coef[:, None] * grad_rj)
    np.add.at(out, k, coef[:, None] * grad_rk)
    np.add.at(out, i, -coef[:, None] * (grad_rj + grad_rk))
    return out


def _projections(geo: _AngleGeometry, v: FloatArray) -> FloatArray:
    """``g_a = r_a . v`` for every angle."""
    i, j, k = geo.ijk.T
    return np.einsum("ad,ad->a", geo.row_j, v[j] - v[i]) + np.einsum(
        "ad,ad->a", geo.row_k, v[k] - v[i]
    )


def angle_eigenvalue_gradient(p: ArrayLike, angles: ArrayLike) -> tuple[float, FloatArray]:
    """Unweighted rigidity eigenvalue and its gradient ``d lambda / dp``, shape ``(N, d)``.

    ``d lambda/dp = sum_a 2 g_a dg_a/dp`` (paper 003 eq. 21 with ``W = I``); valid while the
    eigenvalue is simple. Note the unweighted eigenvalue scales like ``1/scale^2``, so its
    gradient pulls agents together; controllers should use the weighted version.
    """
    pos = _positions(p)
    n, dim = pos.shape
    geo = _angle_geometry(pos, _angles(angles, n))
    lam, v = _eigenpair(_weighted_gram(geo, n, dim, None), trivial_motion_count(dim))
    vv = v.reshape(n, dim)
    return lam, _rotation_term(geo, vv, 2.0 * _projections(geo, vv))


@dataclass(frozen=True)
class _WeightedProblem:
    geo: _AngleGeometry
    edges: IntArray
    rows_ij: IntArray
    rows_ik: IntArray
    weights: EdgeWeights
    d_edge: FloatArray
    h_edge: FloatArray  # w_ij d_ij per edge
    w_angle: FloatArray  # W_a = h_ij h_ik


def _weighted_problem(
    p: ArrayLike, yaw_rad: ArrayLike, edges: ArrayLike, model: SensingModel
) -> tuple[_WeightedProblem, FloatArray, FloatArray]:
    pos = _positions(p)
    yaw = np.asarray(yaw_rad, dtype=float)
    if yaw.shape != (len(pos),) or not np.all(np.isfinite(yaw)):
        raise ValueError(f"yaw_rad must be {len(pos)} finite angles, got shape {yaw.shape}")
    e = _edges(edges, len(pos))
    angles, rows_ij, rows_ik = angle_set_with_rows(e)
    geo = _angle_geometry(pos, angles)
    d_edge = np.linalg.norm(pos[e[:, 1]] - pos[e[:, 0]], axis=1)
    if np.any(d_edge == 0.0):
        raise ValueError("coincident agents: the bearing of some edge is undefined")
    ew = edge_weights(pos, yaw, e, model)
    h_edge = ew.w * d_edge
    w_angle = h_edge[rows_ij] * h_edge[rows_ik]
    problem = _WeightedProblem(geo, e, rows_ij, rows_ik, ew, d_edge, h_edge, w_angle)
    return problem, pos, yaw


def weighted_angle_rigidity_matrix(
    p: ArrayLike, yaw_rad: ArrayLike, edges: ArrayLike, model: SensingModel
) -> FloatArray:
    """``M_w = R_A^T W R_A`` with ``W_a = w_ij w_ik d_ij d_ik`` (paper 003 eq. 16-18), ``(dN, dN)``.

    Angles are formed from all of ``edges`` (e.g. the complete graph); edges outside range or
    view get weight 0 and drop out smoothly.
    """
    prob, pos, _ = _weighted_problem(p, yaw_rad, edges, model)
    return _weighted_gram(prob.geo, *pos.shape, prob.w_angle)


def weighted_angle_rigidity_eigenvalue(
    p: ArrayLike, yaw_rad: ArrayLike, edges: ArrayLike, model: SensingModel
) -> tuple[float, FloatArray]:
    """Weighted rigidity eigenvalue (8th smallest in 3-D, 5th in 2-D) and its unit eigenvector.

    The eigenvector has shape ``(d N,)`` (agent-major). Invariant to translations, to rotations
    (turning the yaws with the positions) and, while no range weight is in its transition zone,
    to scaling all positions.
    """
    prob, pos, _ = _weighted_problem(p, yaw_rad, edges, model)
    gram = _weighted_gram(prob.geo, *pos.shape, prob.w_angle)
    return _eigenpair(gram, trivial_motion_count(pos.shape[1]))


def weighted_eigenvalue_gradient(
    p: ArrayLike, yaw_rad: ArrayLike, edges: ArrayLike, model: SensingModel
) -> tuple[float, FloatArray, FloatArray]:
    """Weighted rigidity eigenvalue and its analytic gradient w.r.t. positions and yaws.

    ``d lambda/dx = sum_a [dW_a/dx g_a^2 + 2 W_a g_a dg_a/dx]`` (paper 003 eq. 20-21; derivation in
    the module docstring). Returns ``(lambda, grad_p (N, d), grad_yaw (N,))``. Valid where the
    eigenvalue is simple; at a repeated eigenvalue the result is one element of the
    subdifferential that depends on the eigenvector the solver returns.
    """
    lam, grad_p, grad_yaw = weighted_eigenvalues_gradients(p, yaw_rad, edges, model, 1)
    return float(lam[0]), grad_p[0], grad_yaw[0]


def weighted_eigenvalues_gradients(
    p: ArrayLike, yaw_rad: ArrayLike, edges: ArrayLike, model: SensingModel, count: int
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The ``count`` smallest non-trivial weighted eigenvalues ``(count,)`` and the gradient of
    each, as :func:`weighted_eigenvalue_gradient`: ``(lambdas, grad_p (count, N, d),
    grad_yaw (count, N))``. For a smooth minimum over nearly equal modes
    (:func:`onboard.control.rigidity.softmin_weights`)."""
    prob, pos, yaw = _weighted_problem(p, yaw_rad, edges, model)
    n, dim = pos.shape
    gram = _weighted_gram(prob.geo, n, dim, prob.w_angle)
    lams, vecs = _eigenpairs(gram, trivial_motion_count(dim), count)
    grads = [_form_gradient(prob, pos, yaw, v.reshape(n, dim))[1:] for v in vecs.T]
    return lams, np.array([g[0] for g in grads]), np.array([g[1] for g in grads])


def weighted_form_gradient(
    p: ArrayLike, yaw_rad: ArrayLike, edges: ArrayLike, model: SensingModel, v: ArrayLike
) -> tuple[float, FloatArray, FloatArray]:
    """Quadratic form ``v^T M_w v`` at a *given* ``v`` and its gradient w.r.t. positions and yaws.

    The same expression as :func:`weighted_eigenvalue_gradient` (paper 003 eq. 21) with ``v``
    held fixed instead of taken from an eigen-solver: what an agent evaluates with its share of
    a distributed eigenvector estimate. ``v`` is ``(N, d)`` or ``(d N,)``, not necessarily unit.
    Returns ``(v^T M_w v, grad_p (N, d), grad_yaw (N,))``.
    """
    prob, pos, yaw = _weighted_problem(p, yaw_rad, edges, model)
    vv = np.asarray(v, dtype=float).reshape(pos.shape)
    return _form_gradient(prob, pos, yaw, vv)


def weighted_gram_and_form_gradient(
    p: ArrayLike, yaw_rad: ArrayLike, edges: ArrayLike, model: SensingModel, v: ArrayLike
) -> tuple[FloatArray, float, FloatArray, FloatArray]:
    """``M_w`` and :func:`weighted_form_gradient` from one evaluation of the geometry.

    What a distributed estimator needs per step: ``M_w v`` for the power iteration and the
    gradient of ``v^T M_w v`` for the controller. Returns ``(M_w, value, grad_p, grad_yaw)``.
    """
    prob, pos, yaw = _weighted_problem(p, yaw_rad, edges, model)
    gram = _weighted_gram(prob.geo, *pos.shape, prob.w_angle)
    vv = np.asarray(v, dtype=float).reshape(pos.shape)
    return (gram, *_form_gradient(prob, pos, yaw, vv))


def _form_gradient(
    prob: _WeightedProblem, pos: FloatArray, yaw: FloatArray, vv: FloatArray
) -> tuple[float, FloatArray, FloatArray]:
    """``v^T M_w v`` and ``d(v^T M_w v)/d(p, yaw)`` at fixed ``v`` (module docstring)."""
    n, dim = pos.shape
    geo = prob.geo
    g = _projections(geo, vv)
    grad_p = _rotation_term(geo, vv, 2.0 * prob.w_angle * g)

    # Weight term: dW_a = h_ik dh_ij + h_ij dh_ik, gathered per edge first.
    g2 = g * g
    n_edges = len(prob.edges)
    coef = np.bincount(prob.rows_ij, g2 * prob.h_edge[prob.rows_ik], minlength=n_edges)
    coef += np.bincount(prob.rows_ik, g2 * prob.h_edge[prob.rows_ij], minlength=n_edges)
    tail, head = prob.edges.T
    ew, d = prob.weights, prob.d_edge
    b = (pos[head] - pos[tail]) / d[:, None]
    c_axis = camera_axis_ned(yaw[tail])[:, :dim]
    s_c = np.stack([-c_axis[:, 1], c_axis[:, 0], *([np.zeros(n_edges)] * (dim - 2))], axis=1)
    p_c = c_axis - ew.cos_axis[:, None] * b
    dh_dr = ((ew.dw_range_dd * d + ew.w_range) * ew.w_fov)[:, None] * b + (
        ew.w_range * ew.dw_fov_dcos
    )[:, None] * p_c
    dh_dyaw = ew.w_range * ew.dw_fov_dcos * d * np.einsum("ed,ed->e", s_c, b)
    np.add.at(grad_p, head, coef[:, None] * dh_dr)
    np.add.at(grad_p, tail, -coef[:, None] * dh_dr)
    grad_yaw = np.bincount(tail, coef * dh_dyaw, minlength=n)
    return float(np.dot(prob.w_angle, g2)), grad_p, grad_yaw
