"""Bearing rigidity matrices: finite-difference Jacobians, ranks, null spaces, IBR tests."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from scipy.linalg import null_space, subspace_angles

from onboard.geometry import bearings_body, bearings_world, rot_z, so3_exp
from onboard.graph import complete_graph
from onboard.rigidity.bearing import (
    RANK_RTOL,
    bearing_rigidity_matrix,
    bearings_se3,
    expected_rank_positions,
    expected_rank_r3s1,
    expected_rank_se3,
    ibr_positions,
    ibr_r3s1,
    ibr_se3,
    numerical_rank,
    position_trivial_motions,
    r3s1_rigidity_matrix_body,
    r3s1_rigidity_matrix_world,
    r3s1_trivial_motions_world,
    rigidity_eigenvalue,
    se3_rigidity_matrix,
    se3_trivial_motions,
)

FD_STEP = 1e-6
FD_ATOL = 1e-8  # central differences: truncation ~ h^2 |f'''| + round-off ~ eps/h, both << 1e-8
PATH = np.array([[0, 1], [1, 2], [2, 3]])


def generic_agents(seed: int, n: int = 4, dim: int = 3):
    """Generic positions (spread over a few metres), yaws and full attitudes."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(-5.0, 5.0, size=(n, dim))
    yaw = rng.uniform(-np.pi, np.pi, size=n)
    rot = so3_exp(rng.normal(size=(n, 3)))
    return p, yaw, rot


def fd_jacobian(f: Callable[[int, float], np.ndarray], n_cols: int) -> np.ndarray:
    """Central differences ``(f(c, +h) - f(c, -h)) / 2h`` for every coordinate ``c``."""
    cols = [(f(c, FD_STEP) - f(c, -FD_STEP)) / (2 * FD_STEP) for c in range(n_cols)]
    return np.stack(cols, axis=1)


def same_subspace(a: np.ndarray, b: np.ndarray) -> float:
    """Largest principal angle between the column spans of ``a`` and ``b`` (0 when equal)."""
    assert a.shape[1] == b.shape[1]
    return float(np.max(subspace_angles(a, b)))


# --------------------------------------------------------------------------- IBR by rank


def test_complete_graph_of_four_generic_agents_is_ibr_everywhere():
    p, yaw, rot = generic_agents(seed=1)
    edges = complete_graph(4)
    results = [
        ibr_positions(p, edges),
        ibr_r3s1(p, yaw, edges, frame="body"),
        ibr_r3s1(p, yaw, edges, frame="world"),
        ibr_se3(p, rot, edges),
    ]
    assert [r.expected_rank for r in results] == [8, 11, 11, 17]
    for r in results:
        assert r.is_rigid
        assert r.rank == r.expected_rank
        assert r.eigenvalue > 1e-4


def test_path_is_not_ibr_anywhere():
    p, yaw, rot = generic_agents(seed=2)
    results = [ibr_positions(p, PATH), ibr_r3s1(p, yaw, PATH), ibr_se3(p, rot, PATH)]
    for r in results:
        assert not r.is_rigid
        assert r.rank < r.expected_rank
        assert r.eigenvalue < 1e-12


def test_complete_triangle_in_the_plane_is_ibr_and_collinear_agents_are_not():
    p, _, _ = generic_agents(seed=3, n=3, dim=2)
    res = ibr_positions(p, complete_graph(3))
    assert res.is_rigid and res.rank == expected_rank_positions(3, 2) == 3
    line = np.outer([0.0, 1.0, 2.5, 4.0], [1.0, -2.0, 0.5])
    res_line = ibr_positions(line, complete_graph(4))
    assert not res_line.is_rigid


def test_rigidity_eigenvalue_is_the_first_nontrivial_one_and_scales_as_inverse_square():
    p, _, _ = generic_agents(seed=4)
    edges = complete_graph(4)
    b = bearing_rigidity_matrix(p, edges)
    eig = np.linalg.eigvalsh(b.T @ b)
    res = ibr_positions(p, edges)
    assert res.eigenvalue == pytest.approx(eig[4])  # d + 2 = 5th smallest in R^3
    assert np.all(np.abs(eig[:4]) < 1e-12) and eig[4] > 1e-4
    # B scales as 1/length, so B^T B and its eigenvalues scale as 1/length^2.
    assert ibr_positions(3.0 * p, edges).eigenvalue == pytest.approx(res.eigenvalue / 9.0)


def test_numerical_rank_ignores_round_off_but_counts_small_real_singular_values():
    rng = np.random.default_rng(5)
    u, _ = np.linalg.qr(rng.normal(size=(6, 6)))
    v, _ = np.linalg.qr(rng.normal(size=(4, 4)))
    for small, rank in [(1e-6, 4), (1e-14, 3)]:
        s = np.zeros((6, 4))
        s[np.arange(4), np.arange(4)] = [1.0, 0.5, 1e-3, small]
        assert numerical_rank(u @ s @ v.T) == rank
    assert RANK_RTOL == 1e-9


def test_rigidity_eigenvalue_rejects_bad_index():
    with pytest.raises(ValueError, match="n_trivial"):
        rigidity_eigenvalue(np.eye(3), 3)


# --------------------------------------------------------------------------- finite differences


@pytest.mark.parametrize("dim", [2, 3])
def test_positions_matrix_rows_are_derivatives_of_world_bearings(dim):
    p, _, _ = generic_agents(seed=6, dim=dim)
    edges = complete_graph(4)

    def bearing(c: int, h: float) -> np.ndarray:
        q = p.copy()
        q.flat[c] += h
        return bearings_world(q, edges)[0].ravel()

    b = bearing_rigidity_matrix(p, edges)
    assert b.shape == (dim * 12, dim * 4)
    np.testing.assert_allclose(b, fd_jacobian(bearing, p.size), atol=FD_ATOL)


def test_r3s1_world_matrix_rows_are_derivatives_along_positions_and_yaws():
    p, yaw, _ = generic_agents(seed=7)
    edges = complete_graph(4)

    def bearing(c: int, h: float) -> np.ndarray:
        q, y = p.copy(), yaw.copy()
        if c < 12:
            q.flat[c] += h
        else:
            y[c - 12] += h
        return bearings_body(q, y, edges)[0].ravel()

    np.testing.assert_allclose(
        r3s1_rigidity_matrix_world(p, yaw, edges), fd_jacobian(bearing, 16), atol=FD_ATOL
    )


def test_r3s1_body_matrix_rows_are_derivatives_along_body_velocities():
    p, yaw, _ = generic_agents(seed=8)
    edges = complete_graph(4)
    rot = rot_z(yaw)

    def bearing(c: int, h: float) -> np.ndarray:
        q, y = p.copy(), yaw.copy()
        if c < 12:
            i, k = divmod(c, 3)
            q[i] += h * rot[i][:, k]  # move along body axis k of agent i
        else:
            y[c - 12] += h
        return bearings_body(q, y, edges)[0].ravel()

    np.testing.assert_allclose(
        r3s1_rigidity_matrix_body(p, yaw, edges), fd_jacobian(bearing, 16), atol=FD_ATOL
    )


def test_se3_matrix_rows_are_derivatives_along_positions_and_local_rotations():
    p, _, rot = generic_agents(seed=9)
    edges = complete_graph(4)

    def bearing(c: int, h: float) -> np.ndarray:
        q, r = p.copy(), rot.copy()
        if c < 12:
            q.flat[c] += h
        else:
            i, k = divmod(c - 12, 3)
            r[i] = r[i] @ so3_exp(h * np.eye(3)[k])
        return bearings_se3(q, r, edges).ravel()

    np.testing.assert_allclose(
        se3_rigidity_matrix(p, rot, edges), fd_jacobian(bearing, 24), atol=FD_ATOL
    )


def test_se3_matrix_reduces_to_the_r3s1_world_matrix_for_yaw_only_attitudes():
    p, yaw, _ = generic_agents(seed=10)
    edges = complete_graph(4)
    full = se3_rigidity_matrix(p, rot_z(yaw), edges)
    yaw_cols = np.concatenate([np.arange(12), 12 + 3 * np.arange(4) + 2])
    np.testing.assert_allclose(full[:, yaw_cols], r3s1_rigidity_matrix_world(p, yaw, edges))


# --------------------------------------------------------------------------- null spaces


def test_r3s1_world_rank_and_null_space_match_paper_000_eq5():
    p, yaw, _ = generic_agents(seed=11, n=5)
    edges = complete_graph(5)
    b = r3s1_rigidity_matrix_world(p, yaw, edges)
    assert numerical_rank(b) == expected_rank_r3s1(5) == 15
    n1, n2, n3 = r3s1_trivial_motions_world(p)
    basis = np.column_stack([n1, n2, n3])
    assert np.abs(b @ basis).max() < 1e-12
    assert same_subspace(null_space(b, rcond=RANK_RTOL), basis) < 1e-8


def test_body_matrix_is_world_matrix_times_block_diagonal_change_of_coordinates():
    p, yaw, _ = generic_agents(seed=12, n=5)
    edges = complete_graph(5)
    world = r3s1_rigidity_matrix_world(p, yaw, edges)
    body = r3s1_rigidity_matrix_body(p, yaw, edges)
    t = np.zeros((20, 20))
    for i, r in enumerate(rot_z(yaw)):
        t[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] = r
    t[15:, 15:] = np.eye(5)
    np.testing.assert_allclose(body, world @ t, atol=1e-14)
    assert numerical_rank(body) == numerical_rank(world) == 15
    assert ibr_r3s1(p, yaw, edges, "body").eigenvalue == pytest.approx(
        ibr_r3s1(p, yaw, edges, "world").eigenvalue
    )


@pytest.mark.parametrize("n", [3, 4, 6])
def test_se3_rank_is_6n_minus_7_with_translations_rotations_scaling_as_null_space(n):
    p, _, rot = generic_agents(seed=13 + n, n=n)
    edges = complete_graph(n)
    b = se3_rigidity_matrix(p, rot, edges)
    assert numerical_rank(b) == expected_rank_se3(n)
    basis = se3_trivial_motions(p, rot)
    assert np.linalg.matrix_rank(basis) == 7
    assert np.abs(b @ basis).max() < 1e-12
    assert same_subspace(null_space(b, rcond=RANK_RTOL), basis) < 1e-8


def test_positions_null_space_is_translations_and_scaling():
    p, _, _ = generic_agents(seed=20, n=5)
    b = bearing_rigidity_matrix(p, complete_graph(5))
    basis = position_trivial_motions(p)
    assert same_subspace(null_space(b, rcond=RANK_RTOL), basis) < 1e-8


def test_se3_global_rotation_leaves_bearings_unchanged():
    """The rotation columns of the trivial basis are true symmetries, not just first order."""
    p, _, rot = generic_agents(seed=21)
    edges = complete_graph(4)
    q = so3_exp(np.array([0.3, -0.7, 1.1]))
    np.testing.assert_allclose(
        bearings_se3(p @ q.T, q @ rot, edges), bearings_se3(p, rot, edges), atol=1e-12
    )


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("p", "edges", "match"),
    [
        (np.zeros((3, 3)), [[0, 1]], "coincide"),
        (np.eye(3), [[0, 3]], "endpoints"),
        (np.eye(3), [[1, 1]], "self loops"),
        (np.array([[0.0, 0, 0], [1, np.nan, 0], [0, 0, 1]]), [[0, 1]], "NaN"),
        (np.eye(3)[:, :1], [[0, 1]], "shape"),
        (np.eye(3), np.zeros((0, 2), dtype=int), "no edges"),
        (np.eye(3), [[0.0, 1.0]], "integer"),
    ],
)
def test_bad_frameworks_raise_clear_errors(p, edges, match):
    with pytest.raises(ValueError, match=match):
        bearing_rigidity_matrix(p, edges)


def test_bad_rotations_and_yaws_raise_clear_errors():
    p = np.eye(3)
    edges = complete_graph(3)
    with pytest.raises(ValueError, match="orthonormal"):
        se3_rigidity_matrix(p, np.tile(2.0 * np.eye(3), (3, 1, 1)), edges)
    with pytest.raises(ValueError, match="shape"):
        se3_rigidity_matrix(p, np.eye(3), edges)
    with pytest.raises(ValueError, match="yaw"):
        r3s1_rigidity_matrix_body(p, np.zeros(2), edges)
    with pytest.raises(ValueError, match="frame"):
        ibr_r3s1(p, np.zeros(3), edges, frame="ned")
