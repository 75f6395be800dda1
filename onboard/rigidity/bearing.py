"""Bearing rigidity: rigidity matrices, their trivial motions and rank tests.

A framework is a directed sensing graph ``G = (V, E)`` (edge ``(i, j)``: ``i`` measures the
bearing to ``j``) together with a configuration of the agents. The *bearing rigidity matrix*
is the Jacobian of the stacked bearings with respect to the configuration, written in some
choice of coordinates; one block row of 3 (or ``d``) rows per edge. A framework is
*infinitesimally bearing rigid* (IBR) when the only motions that leave every bearing unchanged
to first order are the trivial ones, i.e. when the rank of the matrix reaches
``columns - trivial motions`` (equations.md, "Bearing rigidity" items 1-3):

=====================  =========================  ======================  ===============
configuration          columns                    trivial motions         IBR rank
=====================  =========================  ======================  ===============
positions in ``R^d``   ``p_1..p_N``               ``d`` transl., scaling  ``dN - d - 1``
``R^3 x S^1`` (body)   ``u_1..u_N, w_1..w_N``     3 transl., scaling,     ``4N - 5``
``R^3 x S^1`` (world)  ``p_1..p_N, psi_1..psi_N``  vertical rotation
``SE(3)``              ``p_1..p_N, R_1..R_N``     3 transl., 3 rot.,      ``6N - 7``
                                                  scaling
=====================  =========================  ======================  ===============

``SE(3)`` rotation columns are local coordinates: the curve ``R_i exp(t hat(delta_i))`` has
coordinates ``delta_i`` (a body-frame angular velocity), as in paper 001 sec. II-C.

Every matrix is assembled without a Python loop over edges: the per-edge blocks are computed
as ``(E, r, c)`` arrays and scattered into place with one fancy-indexed assignment per block
kind (:func:`_scatter`).

Rank tests use :data:`onboard.rigidity.rank.RANK_RTOL` (the reasoning is documented there).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import S_E3, FloatArray, IntArray, hat, projector, rot_z
from onboard.rigidity.rank import RANK_RTOL, numerical_rank, rigidity_eigenvalue

_MIN_DISTANCE = 1e-9
"""Agents closer than this (in the position unit) make bearings undefined: rejected."""


@dataclass(frozen=True)
class RigidityResult:
    """Outcome of an infinitesimal bearing rigidity test.

    ``eigenvalue`` is the rigidity eigenvalue: the smallest eigenvalue of ``B^T B`` that does
    not belong to a trivial motion (the ``(k+1)``-th smallest with ``k`` trivial motions). It
    is positive exactly when the framework is IBR and measures how far it is from flexible.
    """

    rank: int
    expected_rank: int
    is_rigid: bool
    eigenvalue: float


# ---------------------------------------------------------------------------------------------
# Input checks and assembly helpers
# ---------------------------------------------------------------------------------------------


def _check_positions(p: ArrayLike, dims: tuple[int, ...]) -> FloatArray:
    arr = np.asarray(p, dtype=float)
    if arr.ndim != 2 or arr.shape[1] not in dims:
        raise ValueError(f"positions must have shape (N, d) with d in {dims}, got {arr.shape}")
    if arr.shape[0] < 2:
        raise ValueError(f"a framework needs at least 2 agents, got {arr.shape[0]}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("positions contain NaN or inf")
    return arr


def _check_edges(edges: ArrayLike, n: int, p: FloatArray) -> IntArray:
    e = np.asarray(edges)
    if e.size == 0:
        raise ValueError("the sensing graph has no edges")
    if not np.issubdtype(e.dtype, np.integer):
        raise ValueError(f"edges must be integer vertex indices, got dtype {e.dtype}")
    e = e.astype(np.int64).reshape(-1, 2)
    if np.any(e < 0) or np.any(e >= n):
        raise ValueError(f"edge endpoints must lie in 0..{n - 1}")
    if np.any(e[:, 0] == e[:, 1]):
        raise ValueError("self loops (i, i) have no bearing")
    d = np.linalg.norm(p[e[:, 1]] - p[e[:, 0]], axis=1)
    if np.any(d < _MIN_DISTANCE):
        k = int(np.argmin(d))
        raise ValueError(f"agents {e[k, 0]} and {e[k, 1]} coincide: bearing undefined")
    return e


def _check_rotations(rot: ArrayLike, n: int) -> FloatArray:
    r = np.asarray(rot, dtype=float)
    if r.shape != (n, 3, 3):
        raise ValueError(f"rotations must have shape ({n}, 3, 3), got {r.shape}")
    if not np.all(np.isfinite(r)):
        raise ValueError("rotations contain NaN or inf")
    if not np.allclose(r @ np.swapaxes(r, -1, -2), np.eye(3), atol=1e-6) or np.any(
        np.linalg.det(r) < 0.0
    ):
        raise ValueError("rotations must be orthonormal with determinant +1")
    return r


def _check_yaw(yaw: ArrayLike, n: int) -> FloatArray:
    y = np.asarray(yaw, dtype=float)
    if y.shape != (n,):
        raise ValueError(f"yaw must have shape ({n},), got {y.shape}")
    if not np.all(np.isfinite(y)):
        raise ValueError("yaw contains NaN or inf")
    return y


def _scatter(n_cols: int, placements: list[tuple[IntArray, FloatArray, int]]) -> FloatArray:
    """Assemble a block-row matrix from per-edge blocks.

    Each placement is ``(vertex, blocks, offset)``: ``vertex`` is ``(E,)``, ``blocks`` is
    ``(E, r, c)``, and edge ``k``'s block lands in rows ``r k .. r k + r - 1`` and columns
    ``offset + c vertex[k] .. + c - 1``. Blocks of one placement never overlap (one per edge
    row); different placements add up.
    """
    n_edges, n_rows = placements[0][1].shape[:2]
    out = np.zeros((n_edges, n_rows, n_cols))
    k = np.arange(n_edges)[:, None, None]
    m = np.arange(n_rows)[None, :, None]
    for vertex, blocks, offset in placements:
        width = blocks.shape[2]
        cols = offset + vertex[:, None, None] * width + np.arange(width)[None, None, :]
        out[k, m, cols] += blocks
    return out.reshape(n_edges * n_rows, n_cols)


def _body_bearings(
    p: FloatArray, rot: FloatArray, e: IntArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``beta_ij = R_i^T (p_j - p_i)/d_ij`` (paper 001 eq. 3), ``d_ij`` and ``R_i`` per edge."""
    r = p[e[:, 1]] - p[e[:, 0]]
    d = np.linalg.norm(r, axis=1)
    rot_i = rot[e[:, 0]]
    beta = np.einsum("eki,ek->ei", rot_i, r) / d[:, None]
    return beta, d, rot_i


# ---------------------------------------------------------------------------------------------
# Bearing functions (what the matrices differentiate)
# ---------------------------------------------------------------------------------------------


def bearings_se3(p_ned: ArrayLike, rot_ned_body: ArrayLike, edges: ArrayLike) -> FloatArray:
    """Body-frame bearings of full-attitude agents, ``beta_ij = R_i^T (p_j - p_i)/d_ij``.

    Paper 001 eq. 3. ``rot_ned_body`` is ``(N, 3, 3)``, mapping body vectors to NED. ``(E, 3)``.
    """
    p = _check_positions(p_ned, (3,))
    rot = _check_rotations(rot_ned_body, len(p))
    e = _check_edges(edges, len(p), p)
    return _body_bearings(p, rot, e)[0]


# ---------------------------------------------------------------------------------------------
# Rigidity matrices
# ---------------------------------------------------------------------------------------------


def bearing_rigidity_matrix(p_world: ArrayLike, edges: ArrayLike) -> FloatArray:
    """Bearing rigidity matrix of points in ``R^d`` (d = 2, 3), bearings in a common frame.

    Block row of edge ``(i, j)`` (equations.md item 1): ``-P_ij/d_ij`` at ``p_i`` and
    ``+P_ij/d_ij`` at ``p_j`` with ``P_ij = I - b_ij b_ij^T``. Shape ``(d E, d N)``.
    """
    p = _check_positions(p_world, (2, 3))
    e = _check_edges(edges, len(p), p)
    r = p[e[:, 1]] - p[e[:, 0]]
    d = np.linalg.norm(r, axis=1)
    block = projector(r / d[:, None]) / d[:, None, None]
    dim = p.shape[1]
    return _scatter(dim * len(p), [(e[:, 0], -block, 0), (e[:, 1], block, 0)])


def r3s1_rigidity_matrix_body(p_ned: ArrayLike, yaw_rad: ArrayLike, edges: ArrayLike) -> FloatArray:
    """Body-frame bearing rigidity matrix of ``R^3 x S^1`` agents (paper 000 eq. 3-4).

    Columns ``(u_1..u_N, w_1..w_N)``: body linear velocities and yaw rates, so that
    ``d beta / dt = B (u, w)``. Block row of ``(i, j)``: ``-P_ij/d_ij`` at ``u_i``,
    ``+P_ij iR_j/d_ij`` at ``u_j`` with ``iR_j = R_z(psi_j - psi_i)``, ``-S beta_ij`` at
    ``w_i`` (``S = hat(e3)``); ``P_ij``, ``beta_ij`` in ``i``'s body frame. ``(3E, 4N)``.
    """
    p = _check_positions(p_ned, (3,))
    n = len(p)
    yaw = _check_yaw(yaw_rad, n)
    e = _check_edges(edges, n, p)
    beta, d, _ = _body_bearings(p, rot_z(yaw), e)
    proj = projector(beta) / d[:, None, None]
    i_rot_j = rot_z(yaw[e[:, 1]] - yaw[e[:, 0]])
    yaw_col = -(beta @ S_E3.T)[:, :, None]
    return _scatter(
        4 * n,
        [(e[:, 0], -proj, 0), (e[:, 1], proj @ i_rot_j, 0), (e[:, 0], yaw_col, 3 * n)],
    )


def r3s1_rigidity_matrix_world(
    p_ned: ArrayLike, yaw_rad: ArrayLike, edges: ArrayLike
) -> FloatArray:
    """World-frame bearing rigidity matrix of ``R^3 x S^1`` agents (paper 000 sec. III-A).

    Jacobian of the body-frame bearings with respect to ``(p_1..p_N, psi_1..psi_N)``: block
    row of ``(i, j)``: ``-P_ij R_i^T/d_ij`` at ``p_i``, ``+P_ij R_i^T/d_ij`` at ``p_j``,
    ``-S beta_ij`` at ``psi_i``. Related to the body-frame matrix by
    ``B_body = B_world blockdiag(R_1, .., R_N, I_N)``. ``(3E, 4N)``.
    """
    p = _check_positions(p_ned, (3,))
    n = len(p)
    yaw = _check_yaw(yaw_rad, n)
    e = _check_edges(edges, n, p)
    beta, d, rot_i = _body_bearings(p, rot_z(yaw), e)
    block = projector(beta) @ np.swapaxes(rot_i, 1, 2) / d[:, None, None]
    yaw_col = -(beta @ S_E3.T)[:, :, None]
    return _scatter(4 * n, [(e[:, 0], -block, 0), (e[:, 1], block, 0), (e[:, 0], yaw_col, 3 * n)])


def _se3_blocks(
    p: FloatArray, rot: FloatArray, e: IntArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Per-edge ``beta_ij``, ``d_ij`` and the position and rotation blocks of eq. 22."""
    beta, d, rot_i = _body_bearings(p, rot, e)
    pos = projector(beta) @ np.swapaxes(rot_i, 1, 2) / d[:, None, None]
    return beta, d, pos, hat(beta)


def se3_rigidity_matrix(p_ned: ArrayLike, rot_ned_body: ArrayLike, edges: ArrayLike) -> FloatArray:
    """Bearing rigidity matrix of ``SE(3)`` agents (paper 001 eq. 18-22), ``(3E, 6N)``.

    Columns ``(p_1..p_N, delta_1..delta_N)`` with ``delta_i`` the local coordinates of
    ``R_i exp(hat(delta_i))``. Row ``m`` of edge ``(i, j)``: ``-e_m^T P_ij R_i^T/d_ij`` at
    ``p_i``, ``+e_m^T P_ij R_i^T/d_ij`` at ``p_j``, ``e_m^T hat(beta_ij)`` at ``delta_i``, 0 at
    ``delta_j``.

    Sign of the rotation block: along ``R_i exp(t hat(w))`` the bearing moves as
    ``d beta/dt = -hat(w) beta = hat(beta) w``, so row ``m`` is
    ``e_m^T hat(beta) = (e_m x beta)^T = +(vee(skew(2 beta e_m^T)))^T``. The extracted text of
    eq. 20 carries a minus sign; finite differences (tests/onboard/test_bearing_rigidity.py)
    confirm the plus sign with this exponential-map convention. The yaw column of the
    ``R^3 x S^1`` matrix, ``hat(beta) e3 = -S beta``, agrees with paper 000.
    """
    p = _check_positions(p_ned, (3,))
    n = len(p)
    rot = _check_rotations(rot_ned_body, n)
    e = _check_edges(edges, n, p)
    _, _, pos, rot_block = _se3_blocks(p, rot, e)
    return _scatter(6 * n, [(e[:, 0], -pos, 0), (e[:, 1], pos, 0), (e[:, 0], rot_block, 3 * n)])


# ---------------------------------------------------------------------------------------------
# Trivial motions (null-space bases)
# ---------------------------------------------------------------------------------------------


def position_trivial_motions(p_world: ArrayLike) -> FloatArray:
    """Trivial motions in ``R^d`` as columns: ``d`` translations, 1 scaling. ``(dN, d+1)``."""
    p = _check_positions(p_world, (2, 3))
    n, dim = p.shape
    translations = np.tile(np.eye(dim), (n, 1))
    scaling = (p - p.mean(axis=0)).reshape(-1, 1)
    return np.hstack([translations, scaling])


def r3s1_trivial_motions_world(p_ned: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Null-space basis of the world-frame ``R^3 x S^1`` matrix (paper 000 eq. 5).

    ``n1 = (1_N (x) I3, 0)`` (three translations, ``(4N, 3)``), ``n2 = (p - 1_N (x) pbar, 0)``
    (scaling about the barycenter, ``(4N,)``), ``n3 = ((I_N (x) S)(p - 1_N (x) pbar), 1_N)``
    (coordinated rotation about the vertical through the barycenter, ``(4N,)``).
    """
    p = _check_positions(p_ned, (3,))
    n = len(p)
    centred = p - p.mean(axis=0)
    n1 = np.vstack([np.tile(np.eye(3), (n, 1)), np.zeros((n, 3))])
    n2 = np.concatenate([centred.ravel(), np.zeros(n)])
    n3 = np.concatenate([(centred @ S_E3.T).ravel(), np.ones(n)])
    return n1, n2, n3


def se3_trivial_motions(p_ned: ArrayLike, rot_ned_body: ArrayLike) -> FloatArray:
    """Null-space basis of the ``SE(3)`` matrix: 3 translations, 3 rotations, 1 scaling.

    A global rotation ``p -> Q p``, ``R_i -> Q R_i`` with ``Q = exp(t hat(a))`` about the
    barycenter moves ``p_i`` by ``a x (p_i - pbar)`` and ``R_i`` with local coordinates
    ``R_i^T a`` (since ``hat(a) R_i = R_i hat(R_i^T a)``). Columns: translations ``x, y, z``,
    rotations about ``x, y, z``, scaling. ``(6N, 7)``.
    """
    p = _check_positions(p_ned, (3,))
    n = len(p)
    rot = _check_rotations(rot_ned_body, n)
    centred = p - p.mean(axis=0)
    translations = np.vstack([np.tile(np.eye(3), (n, 1)), np.zeros((3 * n, 3))])
    axes = np.eye(3)
    pos_part = np.einsum("akl,nl->nka", hat(axes), centred).reshape(3 * n, 3)
    rot_part = np.einsum("nlk,la->nka", rot, axes).reshape(3 * n, 3)
    rotations = np.vstack([pos_part, rot_part])
    scaling = np.concatenate([centred.ravel(), np.zeros(3 * n)])[:, None]
    return np.hstack([translations, rotations, scaling])


# ---------------------------------------------------------------------------------------------
# Expected ranks, numerical rank, rigidity eigenvalue and the IBR tests
# ---------------------------------------------------------------------------------------------


def expected_rank_positions(n: int, d: int) -> int:
    """IBR rank in ``R^d``: ``dN - d - 1`` (``d`` translations and a scaling are trivial)."""
    return d * n - d - 1


def expected_rank_r3s1(n: int) -> int:
    """IBR rank in ``R^3 x S^1``: ``4N - 5`` (paper 000 sec. III-A)."""
    return 4 * n - 5


def expected_rank_se3(n: int) -> int:
    """IBR rank in ``SE(3)``: ``6N - 7`` (paper 001 sec. III-C)."""
    return 6 * n - 7


def _ibr(matrix: FloatArray, expected: int, rtol: float) -> RigidityResult:
    rank = numerical_rank(matrix, rtol)
    eigenvalue = rigidity_eigenvalue(matrix, matrix.shape[1] - expected)
    return RigidityResult(
        rank=rank, expected_rank=expected, is_rigid=rank == expected, eigenvalue=eigenvalue
    )


def ibr_positions(p_world: ArrayLike, edges: ArrayLike, rtol: float = RANK_RTOL) -> RigidityResult:
    """IBR test of points in ``R^d``; eigenvalue is the ``(d+2)``-th smallest of ``B^T B``."""
    p = _check_positions(p_world, (2, 3))
    return _ibr(bearing_rigidity_matrix(p, edges), expected_rank_positions(*p.shape), rtol)


def ibr_r3s1(
    p_ned: ArrayLike,
    yaw_rad: ArrayLike,
    edges: ArrayLike,
    frame: str = "body",
    rtol: float = RANK_RTOL,
) -> RigidityResult:
    """IBR test in ``R^3 x S^1`` (``frame`` = ``"body"`` or ``"world"``); 6th eigenvalue.

    The two matrices differ by an orthogonal change of columns
    (``B_body = B_world blockdiag(R_1, .., R_N, I_N)``), so they have the same rank and the
    same eigenvalues of ``B^T B``; the body frame is the one of paper 000.
    """
    if frame == "body":
        matrix = r3s1_rigidity_matrix_body(p_ned, yaw_rad, edges)
    elif frame == "world":
        matrix = r3s1_rigidity_matrix_world(p_ned, yaw_rad, edges)
    else:
        raise ValueError(f"frame must be 'body' or 'world', got {frame!r}")
    return _ibr(matrix, expected_rank_r3s1(matrix.shape[1] // 4), rtol)


def ibr_se3(
    p_ned: ArrayLike, rot_ned_body: ArrayLike, edges: ArrayLike, rtol: float = RANK_RTOL
) -> RigidityResult:
    """IBR test in ``SE(3)``; the eigenvalue is the 8th smallest of ``B^T B``."""
    matrix = se3_rigidity_matrix(p_ned, rot_ned_body, edges)
    return _ibr(matrix, expected_rank_se3(matrix.shape[1] // 6), rtol)
