"""Dynamic bearing observability matrix (paper 001 sec. III): rates, gradients, ranks."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import null_space, subspace_angles

from onboard.geometry import bearings_body, rot_z, so3_exp
from onboard.graph import complete_graph
from onboard.rigidity.bearing import (
    RANK_RTOL,
    bearings_se3,
    r3s1_rigidity_matrix_world,
    se3_rigidity_matrix,
    se3_trivial_motions,
)
from onboard.rigidity.observability import (
    bearing_rate_gradient,
    bearing_rates,
    dynamic_observability_matrix,
    observability_rank_report,
    r3s1_dynamic_observability_matrix,
    r3s1_observability_report,
    scale_observable_moving,
)

FD_STEP = 1e-5
FD_ATOL = 1e-7  # central differences: truncation ~ h^2 = 1e-10 times O(1) third derivatives


def moving_agents(seed: int, n: int = 3):
    """Generic poses and generic (non-zero, non-parallel) body velocities."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(-5.0, 5.0, size=(n, 3))
    rot = so3_exp(rng.normal(size=(n, 3)))
    v = rng.normal(size=(n, 3))
    w = rng.normal(scale=0.5, size=(n, 3))
    return p, rot, v, w


def perturbed(p, rot, c: int, h: float):
    """Move local coordinate ``c`` by ``h``: ``p + h e_c`` or ``R_i exp(h hat(e_k))``."""
    q, r = p.copy(), rot.copy()
    n = len(p)
    if c < 3 * n:
        q.flat[c] += h
    else:
        i, k = divmod(c - 3 * n, 3)
        r[i] = r[i] @ so3_exp(h * np.eye(3)[k])
    return q, r


# ------------------------------------------------------------------ first-order Lie derivative


@pytest.mark.parametrize("with_rotation", [False, True])
def test_bearing_rates_match_finite_differences_of_bearings_along_the_motion(with_rotation):
    p, rot, v, w = moving_agents(seed=1, n=4)
    w = w if with_rotation else None
    edges = complete_graph(4)
    w_vec = np.zeros((4, 3)) if w is None else w

    def bearings_at(t: float) -> np.ndarray:
        # A curve through (p, R) with tangent pdot = R v, Rdot = R hat(w).
        p_t = p + t * np.einsum("nkl,nl->nk", rot, v)
        rot_t = rot @ so3_exp(t * w_vec)
        return bearings_se3(p_t, rot_t, edges)

    fd = (bearings_at(FD_STEP) - bearings_at(-FD_STEP)) / (2 * FD_STEP)
    rates = bearing_rates(p, rot, v, edges, w)
    np.testing.assert_allclose(rates, fd, atol=FD_ATOL)
    # Unit bearings stay unit: the rate is orthogonal to the bearing.
    beta = bearings_se3(p, rot, edges)
    assert np.abs(np.sum(beta * rates, axis=1)).max() < 1e-12


@pytest.mark.parametrize("seed", [2, 3])
def test_analytic_rate_gradient_matches_finite_differences_on_the_manifold(seed):
    p, rot, v, w = moving_agents(seed=seed, n=4)
    edges = complete_graph(4)
    analytic = bearing_rate_gradient(p, rot, v, edges, w)

    def rates(c: int, h: float) -> np.ndarray:
        q, r = perturbed(p, rot, c, h)
        return bearing_rates(q, r, v, edges, w).ravel()

    fd = np.stack([(rates(c, FD_STEP) - rates(c, -FD_STEP)) / (2 * FD_STEP) for c in range(24)], 1)
    assert np.abs(analytic).max() > 0.1  # the comparison is not between two zero matrices
    np.testing.assert_allclose(analytic, fd, atol=FD_ATOL)


def test_dbom_stacks_rigidity_matrix_over_rate_gradient():
    p, rot, v, w = moving_agents(seed=4)
    edges = complete_graph(3)
    dbom = dynamic_observability_matrix(p, rot, v, edges, w)
    assert dbom.shape == (36, 18)
    np.testing.assert_array_equal(dbom[:18], se3_rigidity_matrix(p, rot, edges))
    np.testing.assert_array_equal(dbom[18:], bearing_rate_gradient(p, rot, v, edges, w))


# ------------------------------------------------------------------ ranks (paper 001 sec. III-C)


@pytest.mark.parametrize("seed", [5, 6, 7])
def test_three_moving_agents_make_scale_observable_11_to_12(seed):
    p, rot, v, w = moving_agents(seed=seed)
    edges = complete_graph(3)
    for angular in (None, w):
        report = observability_rank_report(p, rot, v, edges, angular)
        assert (report.static_rank, report.expected_static_rank) == (11, 11)
        assert (report.dynamic_rank, report.expected_dynamic_rank) == (12, 12)
        assert report.scale_observable


def test_moving_null_space_is_exactly_global_translations_and_rotations():
    p, rot, v, w = moving_agents(seed=8)
    dbom = dynamic_observability_matrix(p, rot, v, complete_graph(3), w)
    rigid_motions = se3_trivial_motions(p, rot)[:, :6]  # drop the scaling column
    assert np.abs(dbom @ rigid_motions).max() < 1e-12
    scaling = se3_trivial_motions(p, rot)[:, 6]
    assert np.linalg.norm(dbom @ scaling) > 1e-3
    kernel = null_space(dbom, rcond=RANK_RTOL)
    assert np.max(subspace_angles(kernel, rigid_motions)) < 1e-8


def test_static_agents_keep_rank_6n_minus_7_even_when_rotating():
    p, rot, _, w = moving_agents(seed=9)
    edges = complete_graph(3)
    still = observability_rank_report(p, rot, np.zeros((3, 3)), edges)
    spinning = observability_rank_report(p, rot, np.zeros((3, 3)), edges, w)
    for report in (still, spinning):
        assert report.static_rank == report.dynamic_rank == 11
        assert not report.scale_observable
    assert not np.any(bearing_rate_gradient(p, rot, np.zeros((3, 3)), edges))


def test_rigid_translation_of_the_whole_formation_does_not_reveal_scale():
    """Same world velocity for every agent: no parallax, so the scale stays hidden."""
    p, rot, _, _ = moving_agents(seed=10)
    v_ned = np.array([1.0, -0.5, 0.2])
    v_body = np.einsum("nlk,l->nk", rot, v_ned)  # R_i^T v_ned
    report = observability_rank_report(p, rot, v_body, complete_graph(3))
    assert np.abs(bearing_rates(p, rot, v_body, complete_graph(3))).max() < 1e-12
    assert report.dynamic_rank == 11 and not report.scale_observable


def test_a_moving_path_is_not_observable():
    p, rot, v, _ = moving_agents(seed=11, n=4)
    report = observability_rank_report(p, rot, v, np.array([[0, 1], [1, 2], [2, 3]]))
    assert report.static_rank < 17 and report.dynamic_rank < 18
    assert not report.scale_observable


def test_rank_does_not_depend_on_speed():
    """R~_B is linear in the velocities; the block scaling makes the rank test unit-free."""
    p, rot, v, _ = moving_agents(seed=12)
    edges = complete_graph(3)
    for speed in (1e-6, 1.0, 1e4):
        assert observability_rank_report(p, rot, speed * v, edges).dynamic_rank == 12


# --------------------------------------------------------------------------- R^3 x S^1 agents


def r3s1_moving(seed: int, n: int):
    rng = np.random.default_rng(seed)
    p = rng.uniform(-5.0, 5.0, size=(n, 3))
    yaw = rng.uniform(-np.pi, np.pi, size=n)
    u = rng.normal(size=(n, 3))
    rate = rng.normal(scale=0.5, size=n)
    return p, yaw, u, rate


def test_r3s1_dbom_is_world_rigidity_matrix_over_gradient_of_yaw_model_rates():
    p, yaw, u, rate = r3s1_moving(seed=13, n=4)
    edges = complete_graph(4)
    dbom = r3s1_dynamic_observability_matrix(p, yaw, u, edges, rate)
    assert dbom.shape == (72, 16)
    np.testing.assert_allclose(dbom[:36], r3s1_rigidity_matrix_world(p, yaw, edges))

    def rates(q: np.ndarray, y: np.ndarray) -> np.ndarray:
        # betadot_ij = -w_i S beta_ij + P_ij (iR_j u_j - u_i) / d_ij  (paper 000), built from
        # bearings_body and yaw-only rotations independently of the SE(3) code.
        beta, d = bearings_body(q, y, edges)
        i, j = edges[:, 0], edges[:, 1]
        u_ij = np.einsum("ekl,el->ek", rot_z(y[j] - y[i]), u[j]) - u[i]
        proj_u = u_ij - beta * np.sum(beta * u_ij, axis=1, keepdims=True)
        s_beta = np.stack([-beta[:, 1], beta[:, 0], np.zeros(len(beta))], axis=1)
        return (-rate[i, None] * s_beta + proj_u / d[:, None]).ravel()

    cols = []
    for c in range(16):
        plus_p, minus_p, plus_y, minus_y = p.copy(), p.copy(), yaw.copy(), yaw.copy()
        if c < 12:
            plus_p.flat[c] += FD_STEP
            minus_p.flat[c] -= FD_STEP
        else:
            plus_y[c - 12] += FD_STEP
            minus_y[c - 12] -= FD_STEP
        cols.append((rates(plus_p, plus_y) - rates(minus_p, minus_y)) / (2 * FD_STEP))
    np.testing.assert_allclose(dbom[36:], np.stack(cols, axis=1), atol=FD_ATOL)


@pytest.mark.parametrize("n", [3, 5])
def test_r3s1_moving_agents_reach_4n_minus_4(n):
    p, yaw, u, rate = r3s1_moving(seed=14 + n, n=n)
    edges = complete_graph(n)
    for yaw_rate in (None, rate):
        report = r3s1_observability_report(p, yaw, u, edges, yaw_rate)
        assert report.static_rank == report.expected_static_rank == 4 * n - 5
        assert report.dynamic_rank == report.expected_dynamic_rank == 4 * n - 4
    assert scale_observable_moving(p, yaw, edges, u)


def test_r3s1_scale_not_observable_when_still_or_with_an_unseen_agent():
    p, yaw, u, rate = r3s1_moving(seed=20, n=4)
    assert not scale_observable_moving(p, yaw, complete_graph(4), np.zeros((4, 3)), rate)
    # Agent 3 is measured by nobody and measures nobody: its pose can never be recovered.
    report = r3s1_observability_report(p, yaw, u, np.array([[0, 1], [1, 2], [2, 0]]))
    assert report.dynamic_rank < report.expected_dynamic_rank
    assert not report.scale_observable


def test_r3s1_moving_path_is_observable_although_not_ibr():
    """Each directed edge gives 2 bearing + 2 bearing-rate equations for its 4 unknowns
    (distance, direction, relative yaw): with known body velocities a moving path (3 edges,
    12 = 4N - 4 rows) is observable at first order, while statically it is flexible."""
    p, yaw, u, _ = r3s1_moving(seed=20, n=4)
    report = r3s1_observability_report(p, yaw, u, np.array([[0, 1], [1, 2], [2, 3]]))
    assert report.static_rank == 6 < report.expected_static_rank
    assert report.dynamic_rank == report.expected_dynamic_rank == 12
    assert report.scale_observable


def test_same_seed_gives_same_verdict_and_bad_velocities_raise():
    p, yaw, u, _ = r3s1_moving(seed=21, n=4)
    p2, yaw2, u2, _ = r3s1_moving(seed=21, n=4)
    np.testing.assert_array_equal(
        r3s1_dynamic_observability_matrix(p, yaw, u, complete_graph(4)),
        r3s1_dynamic_observability_matrix(p2, yaw2, u2, complete_graph(4)),
    )
    with pytest.raises(ValueError, match="u_body"):
        scale_observable_moving(p, yaw, complete_graph(4), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="w_body"):
        bearing_rates(p, so3_exp(np.zeros((4, 3))), u, complete_graph(4), np.full((4, 3), np.nan))
