"""Dynamic bearing observability: when moving agents make the formation scale observable.

Paper 001 (sec. II-D, III) treats the fleet as the control-affine system
``pdot_i = R_i v_i``, ``Rdot_i = R_i hat(w_i)`` with outputs ``beta_ij = R_i^T (p_j - p_i)/d_ij``
(eq. 1-3, ``v_i``, ``w_i`` in body frame). The observability codistribution ``dOmega`` (eq.
13-15) stacks the gradients of the Lie derivatives of every bearing component. Truncated at
first order it is the *dynamic bearing observability matrix* (DBOM, eq. 16)::

    R~ = [ R~_A ]   gradients of L0 beta = beta            (the SE(3) rigidity matrix, eq. 22)
         [ R~_B ]   gradients of L1 beta = d beta/dt       (first-order Lie derivatives)

Here the first-order Lie derivative is taken along the motion the agents actually perform,
``f = sum_i (v_i . g_v_i + w_i . g_w_i)``, so that ``L1_f beta_ij = d beta_ij/dt``:

    ``betadot_ij = -hat(w_i) beta_ij + P_ij u_ij / d_ij``,  ``u_ij = iR_j v_j - v_i``

(in ``i``'s body frame, ``iR_j = R_i^T R_j``; paper 000's bearing dynamics generalised to full
attitude). Static agents give ``R~_B = 0`` and rank ``6N - 7``; agents moving with generic,
non-parallel velocities add exactly the scaling direction, rank ``6N - 6`` (paper 001 sec.
III-C: ``N = 3``, 11 -> 12). Translations and global rotations stay unobservable whatever
the motion: bearings, body velocities and relative rotations are all invariant under them.

Gradient of ``betadot`` (local coordinates ``p``, ``R_i exp(hat(delta_i))``; ``chi = 1/d``,
``A = -hat(w_i) - chi ((beta . u) I + beta u^T)``), derived here and checked against
central finite differences on the manifold in tests/onboard/test_observability.py::

    d betadot / d p_j     = chi A P R_i^T - chi^2 (P u) (R_i beta)^T      (= - d/d p_i)
    d betadot / d delta_i = A hat(beta) + chi P hat(iR_j v_j)
    d betadot / d delta_j = -chi P iR_j hat(v_j)

They contain the ``K_ij betadot`` terms that paper 001 eq. 24-26 sets aside; the rank is the
same either way (eq. 26).

Rank tolerance: ``RANK_RTOL`` of :mod:`onboard.rigidity.bearing`, applied after scaling each of
the two row blocks to unit spectral norm. Scaling a block of rows does not change the exact
rank, and it removes the units: ``R~_B`` is linear in the velocities, so without it the
relative test would depend on the speed and on the choice of seconds versus metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import FloatArray, IntArray, hat, projector, rot_z
from onboard.rigidity.bearing import (
    RANK_RTOL,
    _body_bearings,
    _check_edges,
    _check_positions,
    _check_rotations,
    _check_yaw,
    _scatter,
    expected_rank_r3s1,
    expected_rank_se3,
    numerical_rank,
    se3_rigidity_matrix,
)


@dataclass(frozen=True)
class ObservabilityReport:
    """Ranks of the static (rigidity) and dynamic (DBOM) matrices.

    ``scale_observable`` is true when the dynamic rank reaches ``expected_dynamic_rank``: every
    state is then locally observable up to the global rigid-body motions, the scale included.
    """

    static_rank: int
    dynamic_rank: int
    expected_static_rank: int
    expected_dynamic_rank: int
    scale_observable: bool


def _check_vectors(x: ArrayLike | None, n: int, name: str) -> FloatArray:
    if x is None:
        return np.zeros((n, 3))
    arr = np.asarray(x, dtype=float)
    if arr.shape != (n, 3):
        raise ValueError(f"{name} must have shape ({n}, 3), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or inf")
    return arr


def _rate_terms(
    p: FloatArray, rot: FloatArray, v: FloatArray, w: FloatArray, e: IntArray
) -> dict[str, FloatArray]:
    """Per-edge quantities shared by the bearing rates and their gradients."""
    beta, d, rot_i = _body_bearings(p, rot, e)
    i_rot_j = np.swapaxes(rot_i, 1, 2) @ rot[e[:, 1]]
    v_j_in_i = np.einsum("ekl,el->ek", i_rot_j, v[e[:, 1]])
    u = v_j_in_i - v[e[:, 0]]
    return {
        "beta": beta,
        "chi": 1.0 / d,
        "proj": projector(beta),
        "rot_i": rot_i,
        "i_rot_j": i_rot_j,
        "v_j_in_i": v_j_in_i,
        "u": u,
        "w_i": w[e[:, 0]],
    }


def bearing_rates(
    p_ned: ArrayLike,
    rot_ned_body: ArrayLike,
    v_body: ArrayLike,
    edges: ArrayLike,
    w_body: ArrayLike | None = None,
) -> FloatArray:
    """First-order Lie derivative along the motion, ``betadot_ij`` in ``i``'s body frame.

    ``betadot_ij = -hat(w_i) beta_ij + P_ij (iR_j v_j - v_i)/d_ij`` (paper 001 eq. 1-3; paper
    000 bearing dynamics with full attitude). ``v_body``, ``w_body`` are ``(N, 3)`` body-frame
    linear and angular velocities (``w_body`` defaults to zero). Returns ``(E, 3)``.
    """
    p = _check_positions(p_ned, (3,))
    n = len(p)
    rot = _check_rotations(rot_ned_body, n)
    e = _check_edges(edges, n, p)
    t = _rate_terms(
        p, rot, _check_vectors(v_body, n, "v_body"), _check_vectors(w_body, n, "w_body"), e
    )
    return (
        -np.cross(t["w_i"], t["beta"])
        + np.einsum("ekl,el->ek", t["proj"], t["u"]) * t["chi"][:, None]
    )


def bearing_rate_gradient(
    p_ned: ArrayLike,
    rot_ned_body: ArrayLike,
    v_body: ArrayLike,
    edges: ArrayLike,
    w_body: ArrayLike | None = None,
) -> FloatArray:
    """Gradient of :func:`bearing_rates` in local coordinates: the block ``R~_B``, ``(3E, 6N)``.

    Columns as :func:`onboard.rigidity.bearing.se3_rigidity_matrix`: ``(p_1..p_N,
    delta_1..delta_N)``. Formulas in the module doc.
    """
    p = _check_positions(p_ned, (3,))
    n = len(p)
    rot = _check_rotations(rot_ned_body, n)
    e = _check_edges(edges, n, p)
    v = _check_vectors(v_body, n, "v_body")
    t = _rate_terms(p, rot, v, _check_vectors(w_body, n, "w_body"), e)
    beta, chi, proj, u = t["beta"], t["chi"], t["proj"], t["u"]
    c = chi[:, None, None]
    outer_bu = beta[:, :, None] * u[:, None, :]
    a = -hat(t["w_i"]) - c * (np.einsum("ek,ek->e", beta, u)[:, None, None] * np.eye(3) + outer_bu)
    b_world = np.einsum("ekl,el->ek", t["rot_i"], beta)
    proj_u = np.einsum("ekl,el->ek", proj, u)
    grad_pj = c * a @ proj @ np.swapaxes(t["rot_i"], 1, 2) - c**2 * (
        proj_u[:, :, None] * b_world[:, None, :]
    )
    grad_ri = a @ hat(beta) + c * proj @ hat(t["v_j_in_i"])
    grad_rj = -c * proj @ t["i_rot_j"] @ hat(v[e[:, 1]])
    return _scatter(
        6 * n,
        [
            (e[:, 0], -grad_pj, 0),
            (e[:, 1], grad_pj, 0),
            (e[:, 0], grad_ri, 3 * n),
            (e[:, 1], grad_rj, 3 * n),
        ],
    )


def dynamic_observability_matrix(
    p_ned: ArrayLike,
    rot_ned_body: ArrayLike,
    v_body: ArrayLike,
    edges: ArrayLike,
    w_body: ArrayLike | None = None,
) -> FloatArray:
    """DBOM ``R~ = stack(R~_A, R~_B)`` of paper 001 eq. 16 along the given motion, ``(6E, 6N)``.

    ``R~_A`` is the SE(3) rigidity matrix (rows ``0..3E-1``), ``R~_B`` the gradient of the bearing
    rates (rows ``3E..6E-1``); both unscaled. Columns ``(p_1..p_N, delta_1..delta_N)``.
    """
    return np.vstack(
        [
            se3_rigidity_matrix(p_ned, rot_ned_body, edges),
            bearing_rate_gradient(p_ned, rot_ned_body, v_body, edges, w_body),
        ]
    )


def _normalized_rank(static: FloatArray, dynamic: FloatArray, rtol: float) -> int:
    """Rank of ``stack(static, dynamic)`` with each block scaled to unit spectral norm."""
    blocks = [b / np.linalg.norm(b, 2) for b in (static, dynamic) if np.linalg.norm(b, 2) > 0.0]
    return numerical_rank(np.vstack(blocks), rtol) if blocks else 0


def _report(
    static: FloatArray, dynamic: FloatArray, expected_static: int, rtol: float
) -> ObservabilityReport:
    static_rank = numerical_rank(static, rtol)
    dynamic_rank = _normalized_rank(static, dynamic, rtol)
    expected_dynamic = expected_static + 1
    return ObservabilityReport(
        static_rank=static_rank,
        dynamic_rank=dynamic_rank,
        expected_static_rank=expected_static,
        expected_dynamic_rank=expected_dynamic,
        scale_observable=dynamic_rank == expected_dynamic,
    )


def observability_rank_report(
    p_ned: ArrayLike,
    rot_ned_body: ArrayLike,
    v_body: ArrayLike,
    edges: ArrayLike,
    w_body: ArrayLike | None = None,
    rtol: float = RANK_RTOL,
) -> ObservabilityReport:
    """Static and dynamic ranks of ``SE(3)`` agents; expected ``6N - 7`` and ``6N - 6``."""
    static = se3_rigidity_matrix(p_ned, rot_ned_body, edges)
    dynamic = bearing_rate_gradient(p_ned, rot_ned_body, v_body, edges, w_body)
    return _report(static, dynamic, expected_rank_se3(static.shape[1] // 6), rtol)


# ---------------------------------------------------------------------------------------------
# R^3 x S^1 agents (yaw-only attitude, paper 000's model)
# ---------------------------------------------------------------------------------------------


def _r3s1_columns(n: int) -> IntArray:
    """SE(3) columns that are the ``R^3 x S^1`` coordinates ``(p_1..p_N, psi_1..psi_N)``.

    ``R_z(psi) exp(hat(e3) t) = R_z(psi + t)``: the yaw coordinate is the third local rotation
    coordinate, so the ``R^3 x S^1`` gradients are the ``SE(3)`` ones restricted to these
    columns.
    """
    return np.concatenate([np.arange(3 * n), 3 * n + 3 * np.arange(n) + 2])


def _r3s1_inputs(
    p_ned: ArrayLike, yaw_rad: ArrayLike, u_body: ArrayLike, yaw_rate: ArrayLike | None
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    p = _check_positions(p_ned, (3,))
    n = len(p)
    yaw = _check_yaw(yaw_rad, n)
    u = _check_vectors(u_body, n, "u_body")
    rate = np.zeros(n) if yaw_rate is None else _check_yaw(yaw_rate, n)
    w = np.zeros((n, 3))
    w[:, 2] = rate
    return p, rot_z(yaw), u, w


def r3s1_dynamic_observability_matrix(
    p_ned: ArrayLike,
    yaw_rad: ArrayLike,
    u_body: ArrayLike,
    edges: ArrayLike,
    yaw_rate: ArrayLike | None = None,
) -> FloatArray:
    """DBOM of ``R^3 x S^1`` agents (``pdot_i = R_z(psi_i) u_i``, ``psidot_i = w_i``), ``(6E, 4N)``.

    Columns ``(p_1..p_N, psi_1..psi_N)``: rows ``0..3E-1`` are the world-frame rigidity matrix
    of paper 000, rows ``3E..`` the gradient of ``betadot_ij = -w_i S beta_ij + P_ij u_ij/d_ij``.
    """
    p, rot, u, w = _r3s1_inputs(p_ned, yaw_rad, u_body, yaw_rate)
    full = dynamic_observability_matrix(p, rot, u, edges, w)
    return full[:, _r3s1_columns(len(p))]


def r3s1_observability_report(
    p_ned: ArrayLike,
    yaw_rad: ArrayLike,
    u_body: ArrayLike,
    edges: ArrayLike,
    yaw_rate: ArrayLike | None = None,
    rtol: float = RANK_RTOL,
) -> ObservabilityReport:
    """Static and dynamic ranks of ``R^3 x S^1`` agents; expected ``4N - 5`` and ``4N - 4``."""
    matrix = r3s1_dynamic_observability_matrix(p_ned, yaw_rad, u_body, edges, yaw_rate)
    half = matrix.shape[0] // 2
    return _report(matrix[:half], matrix[half:], expected_rank_r3s1(matrix.shape[1] // 4), rtol)


def scale_observable_moving(
    p_ned: ArrayLike,
    yaw_rad: ArrayLike,
    edges: ArrayLike,
    u_body: ArrayLike,
    yaw_rate: ArrayLike | None = None,
) -> bool:
    """Whether ``R^3 x S^1`` agents moving with body velocities ``u_body`` make scale observable.

    True iff the dynamic rank reaches ``4N - 4`` (:func:`r3s1_observability_report`). Pass
    generic velocities (e.g. from a seeded ``np.random.default_rng``) to test the formation
    itself rather than one particular motion.
    """
    return r3s1_observability_report(p_ned, yaw_rad, u_body, edges, yaw_rate).scale_observable


# ---------------------------------------------------------------------------------------------
# The paper's DBOM: one row block per input vector field (paper 001 eq. 13c, 16, 27-31)
# ---------------------------------------------------------------------------------------------
#
# ``dynamic_observability_matrix`` above differentiates ONE first-order Lie derivative: the one
# along the motion actually flown, ``f = sum_i (v_i g_v_i + w_i g_w_i)``; its rank depends on
# the velocities (zero or common velocities leave the scale unobservable). Paper 001 instead
# stacks, for every input vector field ``g_v_ik``, ``g_w_ik`` (agent ``i``, axis ``k``; eq. 2,
# 13c), the gradient of ``L_g beta`` as its own row block. That matrix does not depend on the
# inputs: it tells whether SOME motion makes the scale observable (rank ``6N - 6``), not whether
# the motion flown does. Since ``L_f`` is linear in ``f``, every row of the motion matrix is a
# combination of the field matrix's rows (tests/onboard/test_dbom_fields.py), so its rank is
# never larger. The field gradients here are the full ones (with the ``K_ij betadot`` terms
# that eq. 24-26 set aside and eq. 27-31 leave out); by eq. 26 the rank is the same.


def dbom_fields_matrix(p_ned: ArrayLike, rot_ned_body: ArrayLike, edges: ArrayLike) -> FloatArray:
    """Paper 001's DBOM (eq. 16 with the fields of eq. 13c), ``(3E (1 + 6N), 6N)``.

    Rows: ``R~_A`` (the SE(3) rigidity matrix, ``3E`` rows), then for ``i = 0..N-1``, ``k = 0..2``
    the gradient of ``L_{g_v_ik} beta`` (``3E`` rows each), then the same for ``g_w_ik``.
    ``L_{g_v_ik} beta`` is :func:`bearing_rates` with the unit body velocity ``e_k`` on agent
    ``i`` and every other input zero (likewise ``g_w_ik`` with a unit angular rate). Columns as
    :func:`onboard.rigidity.bearing.se3_rigidity_matrix`. Independent of the inputs.
    """
    p = _check_positions(p_ned, (3,))
    n = len(p)
    rot = _check_rotations(rot_ned_body, n)
    e = _check_edges(edges, n, p)
    blocks = [se3_rigidity_matrix(p, rot, e)]
    zeros = np.zeros((n, 3))
    for angular in (False, True):
        for i in range(n):
            for k in range(3):
                unit = zeros.copy()
                unit[i, k] = 1.0
                v, w = (zeros, unit) if angular else (unit, zeros)
                blocks.append(bearing_rate_gradient(p, rot, v, e, w))
    return np.vstack(blocks)


def dbom_fields_rank(
    p_ned: ArrayLike, rot_ned_body: ArrayLike, edges: ArrayLike, rtol: float = RANK_RTOL
) -> int:
    """Rank of :func:`dbom_fields_matrix` (``R~_A`` and the field blocks each scaled to unit
    spectral norm, as :func:`observability_rank_report`). Generic rigid frameworks: ``6N - 6``
    (paper 001 sec. III-C, ``N = 3``: 12); only translations and global rotations remain."""
    matrix = dbom_fields_matrix(p_ned, rot_ned_body, edges)
    n_static = se3_rigidity_matrix(p_ned, rot_ned_body, edges).shape[0]
    return _normalized_rank(matrix[:n_static], matrix[n_static:], rtol)
