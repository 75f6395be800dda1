"""Angle rigidity (paper 003): rank tests, the rigidity matrix, weights and the eigenvalue gradient."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg

from onboard.geometry import FloatArray, hat, rot_z, so3_exp
from onboard.graph import angle_set, angle_set_with_rows, complete_graph, normalize_edges
from onboard.rigidity.angle import (
    angle_eigenvalue_gradient,
    angle_function,
    angle_rigidity_eigenvalue,
    angle_rigidity_matrix,
    angle_rigidity_rank,
    expected_angle_rank,
    is_infinitesimally_angle_rigid,
    weighted_angle_rigidity_eigenvalue,
    weighted_angle_rigidity_matrix,
    weighted_eigenvalue_gradient,
)
from onboard.rigidity.weights import (
    SensingModel,
    edge_weights,
    fov_weight,
    range_weight,
    sensing_weights,
    smooth_step,
)

# A 6-agent scene whose weighted eigenvalue is simple and well separated (8th = 0.32, 9th = 0.74)
# and where 6 range weights and 6 fov weights sit strictly inside their transition zones.
SCENE_SEED = 4
SCENE_MODEL = SensingModel(fov_deg=150.0, range_m=9.0)


def scene(seed: int = SCENE_SEED, n: int = 6) -> tuple[FloatArray, FloatArray]:
    """Random positions in a cube; cameras roughly toward the barycenter."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(-4.0, 4.0, size=(n, 3))
    to_center = p.mean(axis=0) - p
    yaw = np.arctan2(to_center[:, 1], to_center[:, 0]) + rng.normal(0.0, 0.4, n)
    return p, yaw


def central_difference(fun, x: FloatArray, h: float) -> FloatArray:  # type: ignore[no-untyped-def]
    """Central finite-difference gradient of a scalar function of an array."""
    grad = np.zeros_like(x)
    for idx in np.ndindex(x.shape):
        xp, xm = x.copy(), x.copy()
        xp[idx] += h
        xm[idx] -= h
        grad[idx] = (fun(xp) - fun(xm)) / (2.0 * h)
    return grad


# --------------------------------------------------------------------------- rank


def test_expected_rank_counts_trivial_motions() -> None:
    assert expected_angle_rank(5, 2) == 2 * 5 - 4
    assert expected_angle_rank(5, 3) == 3 * 5 - 7
    with pytest.raises(ValueError, match="at least 3"):
        expected_angle_rank(2, 3)


def test_complete_graph_of_four_generic_agents_is_iar_in_3d() -> None:
    p = np.random.default_rng(0).normal(size=(4, 3))
    edges = complete_graph(4)
    assert angle_rigidity_rank(p, edges) == 5
    assert is_infinitesimally_angle_rigid(p, edges)


def test_chain_is_not_iar_in_3d() -> None:
    p = np.random.default_rng(1).normal(size=(4, 3))
    chain = np.array([[1, 0], [1, 2], [2, 1], [2, 3]])  # two angles only, at agents 1 and 2
    assert angle_rigidity_rank(p, chain) == 2
    assert not is_infinitesimally_angle_rigid(p, chain)


def test_2d_triangle_and_square_are_iar_and_collinear_is_not() -> None:
    rng = np.random.default_rng(2)
    assert is_infinitesimally_angle_rigid(rng.normal(size=(3, 2)), complete_graph(3))
    assert angle_rigidity_rank(rng.normal(size=(4, 2)), complete_graph(4)) == 4
    collinear = np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0]])
    assert angle_rigidity_rank(collinear, complete_graph(3)) == 0
    assert not is_infinitesimally_angle_rigid(collinear, complete_graph(3))


def test_2d_path_is_not_iar() -> None:
    p = np.random.default_rng(3).normal(size=(4, 2))
    path = np.array([[1, 0], [1, 2], [2, 1], [2, 3]])
    assert not is_infinitesimally_angle_rigid(p, path)


def test_rank_is_scale_independent() -> None:
    p = np.random.default_rng(4).normal(size=(5, 3))
    edges = complete_graph(5)
    assert angle_rigidity_rank(1e-3 * p, edges) == angle_rigidity_rank(1e3 * p, edges) == 8


def test_bad_input_raises_clear_errors() -> None:
    p = np.random.default_rng(5).normal(size=(4, 3))
    with pytest.raises(ValueError, match="positions"):
        angle_function(np.zeros((4, 4)), [[0, 1, 2]])
    with pytest.raises(ValueError, match="NaN"):
        angle_function(np.full((4, 3), np.nan), [[0, 1, 2]])
    with pytest.raises(ValueError, match="out of range"):
        angle_function(p, [[0, 1, 7]])
    with pytest.raises(ValueError, match="distinct"):
        angle_function(p, [[0, 1, 1]])
    with pytest.raises(ValueError, match="coincident"):
        angle_rigidity_matrix(np.vstack([p[:3], p[:1]]), [[0, 1, 3]])
    with pytest.raises(ValueError, match="yaw_rad"):
        weighted_angle_rigidity_eigenvalue(p, np.zeros(3), complete_graph(4), SCENE_MODEL)


# --------------------------------------------------------------------------- matrix


def test_angle_set_matches_its_definition() -> None:
    """The vectorized angle set equals a literal reading of paper 003's definition."""
    rng = np.random.default_rng(6)
    edges = normalize_edges(rng.integers(0, 9, size=(40, 2)))
    angles, rows_ij, rows_ik = angle_set_with_rows(edges)
    pairs = [tuple(e) for e in edges.tolist()]
    reference = sorted((i, j, k) for (i, j) in pairs for (i2, k) in pairs if i2 == i and j < k)
    assert sorted(map(tuple, angles.tolist())) == reference
    assert len(set(map(tuple, angles.tolist()))) == len(angles)
    np.testing.assert_array_equal(edges[rows_ij], angles[:, :2])
    np.testing.assert_array_equal(edges[rows_ik], angles[:, [0, 2]])
    np.testing.assert_array_equal(angle_set(edges), angles)


@pytest.mark.parametrize("dim", [2, 3])
def test_rigidity_matrix_matches_finite_differences(dim: int) -> None:
    p = np.random.default_rng(7).normal(size=(5, dim))
    angles = angle_set(complete_graph(5))
    numeric = np.stack(
        [
            central_difference(lambda x, a=a: angle_function(x, angles)[a], p, 1e-6).ravel()
            for a in range(len(angles))
        ]
    )
    np.testing.assert_allclose(angle_rigidity_matrix(p, angles), numeric, atol=1e-8)


def test_trivial_motions_are_in_the_kernel_in_3d() -> None:
    p = np.random.default_rng(8).normal(size=(5, 3))
    r = angle_rigidity_matrix(p, angle_set(complete_graph(5)))
    motions = [np.tile(e, 5) for e in np.eye(3)]  # translations
    motions += [(p @ hat(w).T).ravel() for w in np.eye(3)]  # rotations
    motions.append(p.ravel())  # scaling
    for m in motions:
        np.testing.assert_allclose(r @ m, 0.0, atol=1e-12)


def test_weighted_gram_with_unit_weights_is_rt_s_r() -> None:
    p, yaw = scene()
    edges = complete_graph(len(p))
    unlimited = SensingModel(fov_deg=360.0, range_m=np.inf)
    angles = angle_set(edges)
    i, j, k = angles.T
    s = np.linalg.norm(p[j] - p[i], axis=1) * np.linalg.norm(p[k] - p[i], axis=1)
    r = angle_rigidity_matrix(p, angles)
    np.testing.assert_allclose(
        weighted_angle_rigidity_matrix(p, yaw, edges, unlimited), r.T @ (s[:, None] * r), atol=1e-12
    )


def test_unweighted_eigenvalue_is_eighth_of_rt_r() -> None:
    p = np.random.default_rng(9).normal(size=(5, 3))
    angles = angle_set(complete_graph(5))
    r = angle_rigidity_matrix(p, angles)
    eig = np.linalg.eigvalsh(r.T @ r)
    assert abs(eig[6]) < 1e-12 * eig[-1] < eig[7]
    assert angle_rigidity_eigenvalue(p, angles) == pytest.approx(eig[7], rel=1e-10)


# --------------------------------------------------------------------------- weights


def test_smooth_step_ends_and_derivative() -> None:
    x = np.linspace(-1.0, 4.0, 501)
    s, ds = smooth_step(x, 1.0, 3.0)
    assert np.all(s[x <= 1.0] == 1.0) and np.all(s[x >= 3.0] == 0.0)
    assert np.all(np.diff(s) <= 0.0)
    inner = x[(x > 1.0) & (x < 3.0)]
    numeric = central_difference(lambda y: smooth_step(y, 1.0, 3.0)[0].sum(), inner, 1e-6)
    np.testing.assert_allclose(smooth_step(inner, 1.0, 3.0)[1], numeric, atol=1e-8)
    # C^1: the slope vanishes at both ends, where the flat parts begin.
    assert smooth_step(1.0, 1.0, 3.0)[1] == 0.0 and smooth_step(3.0, 1.0, 3.0)[1] == 0.0
    assert ds.min() == pytest.approx(-1.5 / 2.0, rel=1e-3)  # peak slope 1.5 / width
    with pytest.raises(ValueError):
        smooth_step(x, 2.0, 2.0)


@pytest.mark.parametrize(
    "model",
    [SensingModel(120.0, 15.0), SensingModel(360.0, 15.0), SensingModel(90.0, math.inf)],
)
def test_sensing_weights_are_the_range_and_fov_weights(model: SensingModel) -> None:
    rng = np.random.default_rng(2)
    d = rng.uniform(0.5, 20.0, 40)
    cos_axis = rng.uniform(-1.0, 1.0, 40)
    together = sensing_weights(d, cos_axis, model)
    apart = (*range_weight(d, model), *fov_weight(cos_axis, model))
    for a, b in zip(together, apart, strict=True):
        np.testing.assert_array_equal(a, b)  # the same arithmetic, entry by entry


def test_range_and_fov_weights_and_derivatives() -> None:
    model = SensingModel(fov_deg=90.0, range_m=10.0)
    assert model.range_full_m == pytest.approx(8.0)
    d = np.linspace(7.0, 11.0, 41) + 0.013
    w, dw = range_weight(d, model)
    assert np.all(w[d <= 8.0] == 1.0) and np.all(w[d >= 10.0] == 0.0)
    np.testing.assert_allclose(
        dw, central_difference(lambda y: range_weight(y, model)[0].sum(), d, 1e-6), atol=1e-7
    )
    half = np.deg2rad(45.0)
    c = np.cos(np.linspace(0.0, 1.2 * half, 37) + 0.003)
    w, dw = fov_weight(c, model)
    assert np.all(w[c >= np.cos(0.8 * half)] == 1.0) and np.all(w[c <= np.cos(half)] == 0.0)
    np.testing.assert_allclose(
        dw, central_difference(lambda y: fov_weight(y, model)[0].sum(), c, 1e-7), atol=1e-5
    )


def test_edge_weights_use_the_camera_axis() -> None:
    model = SensingModel(fov_deg=90.0, range_m=10.0)
    p = np.array([[0.0, 0.0, 0.0], [0.0, 5.0, 0.0], [5.0, 0.0, 0.0]])
    edges = np.array([[0, 1], [0, 2]])
    ew = edge_weights(p, np.array([np.pi / 2, 0.0, 0.0]), edges, model)  # nose east
    np.testing.assert_allclose(ew.w, [1.0, 0.0])


def test_sensing_model_validates() -> None:
    with pytest.raises(ValueError, match="fov_deg"):
        SensingModel(fov_deg=-10.0, range_m=5.0)
    with pytest.raises(ValueError, match="range_m"):
        SensingModel(fov_deg=90.0, range_m=0.0)
    with pytest.raises(ValueError, match="fov_transition"):
        SensingModel(fov_deg=90.0, range_m=5.0, fov_transition=0.0)


# --------------------------------------------------------------------------- weighted eigenvalue


def test_scene_has_weights_in_transition_and_a_simple_eigenvalue() -> None:
    p, yaw = scene()
    edges = complete_graph(len(p))
    ew = edge_weights(p, yaw, edges, SCENE_MODEL)
    assert np.sum((ew.w_range > 0.0) & (ew.w_range < 1.0)) >= 3
    assert np.sum((ew.w_fov > 0.0) & (ew.w_fov < 1.0)) >= 3
    eig = scipy.linalg.eigvalsh(weighted_angle_rigidity_matrix(p, yaw, edges, SCENE_MODEL))
    assert eig[8] > 1.5 * eig[7] > 0.0


@pytest.mark.parametrize("factor", [0.5, 3.0])
def test_weighted_eigenvalue_is_scale_invariant_while_range_is_flat(factor: float) -> None:
    p, yaw = scene()
    edges = complete_graph(len(p))
    # fov weights in transition (scale invariant); range far from binding at x3.
    model = SensingModel(fov_deg=150.0, range_m=200.0)
    assert 3.0 * np.ptp(p, axis=0).max() * np.sqrt(3.0) < model.range_full_m
    lam, _ = weighted_angle_rigidity_eigenvalue(p, yaw, edges, model)
    lam_scaled, _ = weighted_angle_rigidity_eigenvalue(factor * p, yaw, edges, model)
    assert lam_scaled == pytest.approx(lam, rel=1e-10)
    # The unweighted eigenvalue, for contrast, scales like 1/scale^2.
    angles = angle_set(edges)
    ratio = angle_rigidity_eigenvalue(factor * p, angles) / angle_rigidity_eigenvalue(p, angles)
    assert ratio == pytest.approx(factor**-2, rel=1e-10)


def test_weighted_eigenvalue_invariant_to_translation_and_yaw_rotation() -> None:
    p, yaw = scene()
    edges = complete_graph(len(p))
    lam, _ = weighted_angle_rigidity_eigenvalue(p, yaw, edges, SCENE_MODEL)
    moved = p + np.array([3.0, -7.0, 2.0])
    assert weighted_angle_rigidity_eigenvalue(moved, yaw, edges, SCENE_MODEL)[0] == pytest.approx(
        lam, rel=1e-10
    )
    turn = 0.7
    turned = p @ rot_z(turn).T
    assert weighted_angle_rigidity_eigenvalue(turned, yaw + turn, edges, SCENE_MODEL)[
        0
    ] == pytest.approx(lam, rel=1e-10)


def test_unweighted_eigenvalue_invariant_to_rotation_and_translation() -> None:
    p = np.random.default_rng(10).normal(size=(6, 3))
    angles = angle_set(complete_graph(6))
    lam = angle_rigidity_eigenvalue(p, angles)
    moved = p @ so3_exp(np.array([0.3, -1.1, 0.5])).T + np.array([1.0, 2.0, -3.0])
    assert angle_rigidity_eigenvalue(moved, angles) == pytest.approx(lam, rel=1e-10)


# --------------------------------------------------------------------------- gradients


def test_weighted_gradient_matches_finite_differences() -> None:
    p, yaw = scene()
    edges = complete_graph(len(p))
    lam, grad_p, grad_yaw = weighted_eigenvalue_gradient(p, yaw, edges, SCENE_MODEL)
    assert lam == pytest.approx(weighted_angle_rigidity_eigenvalue(p, yaw, edges, SCENE_MODEL)[0])

    def lam_of_p(x: FloatArray) -> float:
        return weighted_angle_rigidity_eigenvalue(x, yaw, edges, SCENE_MODEL)[0]

    def lam_of_yaw(y: FloatArray) -> float:
        return weighted_angle_rigidity_eigenvalue(p, y, edges, SCENE_MODEL)[0]

    num_p = central_difference(lam_of_p, p, 1e-6)
    num_yaw = central_difference(lam_of_yaw, yaw, 1e-6)
    scale = max(np.abs(grad_p).max(), np.abs(grad_yaw).max())
    assert np.abs(grad_yaw).max() > 1e-2 * scale  # the yaw part is not trivially zero
    assert np.abs(grad_p - num_p).max() <= 1e-6 * scale
    assert np.abs(grad_yaw - num_yaw).max() <= 1e-6 * scale


def test_weighted_gradient_respects_the_symmetries() -> None:
    p, yaw = scene()
    _, grad_p, grad_yaw = weighted_eigenvalue_gradient(p, yaw, complete_graph(len(p)), SCENE_MODEL)
    # Translation: the gradient sums to zero. Rotation about the vertical (positions and yaws
    # together): sum_i (S p_i) . grad_p_i + sum_i grad_yaw_i = 0.
    np.testing.assert_allclose(grad_p.sum(axis=0), 0.0, atol=1e-12)
    s_e3 = hat(np.array([0.0, 0.0, 1.0]))
    assert np.sum((p @ s_e3.T) * grad_p) + grad_yaw.sum() == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("dim", [2, 3])
def test_unweighted_gradient_matches_finite_differences(dim: int) -> None:
    p = np.random.default_rng(11).normal(size=(6, dim))
    angles = angle_set(complete_graph(6))
    lam, grad = angle_eigenvalue_gradient(p, angles)
    assert lam == pytest.approx(angle_rigidity_eigenvalue(p, angles))
    numeric = central_difference(lambda x: angle_rigidity_eigenvalue(x, angles), p, 1e-6)
    assert np.abs(grad - numeric).max() <= 1e-6 * np.abs(grad).max()


def test_weighted_gradient_in_2d_matches_finite_differences() -> None:
    rng = np.random.default_rng(3)
    p = rng.uniform(-4.0, 4.0, size=(6, 2))
    to_center = p.mean(axis=0) - p
    yaw = np.arctan2(to_center[:, 1], to_center[:, 0]) + rng.normal(0.0, 0.4, 6)
    edges = complete_graph(6)
    _, grad_p, grad_yaw = weighted_eigenvalue_gradient(p, yaw, edges, SCENE_MODEL)
    num_p = central_difference(
        lambda x: weighted_angle_rigidity_eigenvalue(x, yaw, edges, SCENE_MODEL)[0], p, 1e-6
    )
    num_yaw = central_difference(
        lambda y: weighted_angle_rigidity_eigenvalue(p, y, edges, SCENE_MODEL)[0], yaw, 1e-6
    )
    scale = max(np.abs(grad_p).max(), np.abs(grad_yaw).max())
    assert np.abs(grad_p - num_p).max() <= 1e-6 * scale
    assert np.abs(grad_yaw - num_yaw).max() <= 1e-6 * scale
