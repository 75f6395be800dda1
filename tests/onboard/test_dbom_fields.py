"""Paper 001's DBOM with one row block per input vector field (eq. 13c, 16) vs the motion DBOM."""

from __future__ import annotations

import numpy as np

from onboard.geometry import so3_exp
from onboard.rigidity.bearing import numerical_rank, se3_rigidity_matrix, se3_trivial_motions
from onboard.rigidity.observability import (
    bearing_rate_gradient,
    dbom_fields_matrix,
    dbom_fields_rank,
    observability_rank_report,
)


def _framework(seed: int, n: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    p = rng.uniform(-3.0, 3.0, size=(n, 3))
    rot = so3_exp(rng.normal(size=(n, 3)))
    edges = np.array([(i, j) for i in range(n) for j in range(n) if i != j])
    return p, rot, edges


def test_n3_ranks_are_the_papers_11_and_12():
    p, rot, edges = _framework(0)
    assert numerical_rank(se3_rigidity_matrix(p, rot, edges)) == 11
    assert dbom_fields_rank(p, rot, edges) == 12


def test_shape_and_null_space_is_the_rigid_motions():
    p, rot, edges = _framework(1, 4)
    m = dbom_fields_matrix(p, rot, edges)
    assert m.shape == (3 * len(edges) * (1 + 6 * 4), 24)
    rigid = se3_trivial_motions(p, rot)[:, :6]
    np.testing.assert_allclose(m @ rigid, 0.0, atol=1e-9)
    scaling = se3_trivial_motions(p, rot)[:, 6]
    assert np.linalg.norm(m @ scaling) > 1e-3
    assert dbom_fields_rank(p, rot, edges) == 6 * 4 - 6


def test_motion_dbom_rows_are_combinations_of_the_field_blocks():
    """``L_f`` is linear in ``f``: the gradient along the flown motion is ``sum u_ik dL_g_ik``."""
    p, rot, edges = _framework(2)
    rng = np.random.default_rng(3)
    v, w = rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
    m = dbom_fields_matrix(p, rot, edges)
    rows = 3 * len(edges)
    fields = m[rows:].reshape(18, rows, 18)
    combined = np.einsum("f,frc->rc", np.concatenate([v.ravel(), w.ravel()]), fields)
    np.testing.assert_allclose(combined, bearing_rate_gradient(p, rot, v, edges, w), atol=1e-12)


def test_fields_rank_does_not_depend_on_the_motion_flown():
    """Static agents or a common translation: the motion DBOM stays at 11, the paper's at 12."""
    p, rot, edges = _framework(4)
    rot = np.tile(np.eye(3), (3, 1, 1))
    common = np.tile([0.5, -0.2, 0.1], (3, 1))
    for v in (np.zeros((3, 3)), common):
        assert observability_rank_report(p, rot, v, edges).dynamic_rank == 11
    assert dbom_fields_rank(p, rot, edges) == 12
