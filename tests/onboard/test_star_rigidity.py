"""One agent's star of angles (paper 003 eq. 3, 10-11, 16-21): the stars of all agents assemble
the framework's weighted matrix-vector product and form gradient exactly; the gradients match
central finite differences; the weighted degree bounds the largest eigenvalue."""

from __future__ import annotations

import numpy as np
import pytest

from onboard.estimation import star_rigidity as st
from onboard.estimation.angle_localization import local_angle_gradient, local_vertical_gradient
from onboard.graph import complete_graph
from onboard.rigidity.angle import weighted_angle_rigidity_matrix, weighted_form_gradient
from onboard.rigidity.weights import SensingModel

MODEL = SensingModel(120.0, 12.0)


def _team(seed: int, n: int = 6) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    p = rng.uniform(-4.0, 4.0, (n, 3)) + np.array([0.0, 0.0, -6.0])
    c = p.mean(axis=0)
    # cameras roughly toward the barycenter: some neighbours in the roll-off zones
    yaw = np.arctan2(c[1] - p[:, 1], c[0] - p[:, 0]) + rng.normal(scale=0.5, size=n)
    return p, yaw


def _others(n: int, i: int) -> list[int]:
    return [j for j in range(n) if j != i]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_stars_assemble_the_weighted_matrix_times_several_vectors(seed: int) -> None:
    p, yaw = _team(seed)
    n = len(p)
    v = np.random.default_rng(seed + 10).normal(size=(n, 3, 3))
    total = np.zeros_like(v)
    for i in range(n):
        nb = _others(n, i)
        mv = st.weighted_matvec(st.star(p[i], yaw[i], p[nb], MODEL), v[i], v[nb])
        total[i] += mv[0]
        total[nb] += mv[1:]
    m = weighted_angle_rigidity_matrix(p, yaw, complete_graph(n), MODEL)
    np.testing.assert_allclose(total.reshape(3 * n, 3), m @ v.reshape(3 * n, 3), atol=1e-12)
    # one vector at a time gives the same columns
    one = st.weighted_matvec(st.star(p[0], yaw[0], p[1:], MODEL), v[0, :, 1], v[1:, :, 1])
    mv0 = st.weighted_matvec(st.star(p[0], yaw[0], p[1:], MODEL), v[0], v[1:])
    np.testing.assert_allclose(one, mv0[:, :, 1], atol=1e-14)


@pytest.mark.parametrize("seed", [0, 3])
def test_stars_assemble_the_form_gradient(seed: int) -> None:
    p, yaw = _team(seed)
    n = len(p)
    v = np.random.default_rng(seed + 20).normal(size=(n, 3))
    value, gp, gy = 0.0, np.zeros((n, 3)), np.zeros(n)
    for i in range(n):
        nb = _others(n, i)
        val, _, g, g_yaw = st.form_gradient(st.star(p[i], yaw[i], p[nb], MODEL), v[i], v[nb])
        value += val
        gp[i] += g[0]
        gp[nb] += g[1:]
        gy[i] += g_yaw
    ref_val, ref_p, ref_y = weighted_form_gradient(p, yaw, complete_graph(n), MODEL, v)
    assert value == pytest.approx(ref_val, rel=1e-12)
    np.testing.assert_allclose(gp, ref_p, atol=1e-11)
    np.testing.assert_allclose(gy, ref_y, atol=1e-11)


def test_form_gradient_matches_central_differences() -> None:
    p, yaw = _team(4, n=5)
    c = p[1:].mean(axis=0) - p[0]
    yaw[0] = np.arctan2(c[1], c[0]) + 0.5  # everyone in view, some in the fov roll-off
    v = np.random.default_rng(5).normal(size=(5, 3))

    def value(q: np.ndarray, psi: float) -> float:
        return st.form_gradient(st.star(q[0], psi, q[1:], MODEL), v[0], v[1:])[0]

    _, _, grad, grad_yaw = st.form_gradient(st.star(p[0], yaw[0], p[1:], MODEL), v[0], v[1:])
    h = 1e-6
    fd = np.zeros_like(p)
    for a in range(5):
        for d in range(3):
            e = np.zeros_like(p)
            e[a, d] = h
            fd[a, d] = (value(p + e, yaw[0]) - value(p - e, yaw[0])) / (2 * h)
    fd_yaw = (value(p, yaw[0] + h) - value(p, yaw[0] - h)) / (2 * h)
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-7)
    assert grad_yaw == pytest.approx(fd_yaw, rel=1e-5, abs=1e-7)
    assert np.max(np.abs(grad)) > 1e-3 and abs(grad_yaw) > 1e-3  # not a trivial comparison
    # the star's part of M_w v is the derivative of its half value: d(v^T M v)/dv = 2 M v
    mv = st.weighted_matvec(st.star(p[0], yaw[0], p[1:], MODEL), v[0], v[1:])
    fd_v = np.zeros_like(v)
    for a in range(5):
        for d in range(3):
            e = np.zeros_like(v)
            e[a, d] = h
            s = st.star(p[0], yaw[0], p[1:], MODEL)
            fd_v[a, d] = (
                st.form_gradient(s, v[0] + e[0], v[1:] + e[1:])[0]
                - st.form_gradient(s, v[0] - e[0], v[1:] - e[1:])[0]
            ) / (2 * h)
    np.testing.assert_allclose(2.0 * mv, fd_v, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("seed", [0, 6])
def test_weighted_degree_bounds_the_largest_eigenvalue(seed: int) -> None:
    p, yaw = _team(seed, n=7)
    n = len(p)
    s_v = np.zeros(n)
    for i in range(n):
        nb = _others(n, i)
        deg = st.weighted_degree(st.star(p[i], yaw[i], p[nb], MODEL))
        s_v[i] += deg[0]
        s_v[nb] += deg[1:]
    m = weighted_angle_rigidity_matrix(p, yaw, complete_graph(n), MODEL)
    lam_max = np.linalg.eigvalsh(m)[-1]
    assert lam_max > 0.0
    assert s_v.max() >= lam_max
    # per vertex, s_v bounds the Rayleigh quotient of any vector supported there
    np.testing.assert_array_less(np.diag(m).reshape(n, 3).max(axis=1), s_v + 1e-12)


def test_localization_terms_match_the_reference_and_finite_differences() -> None:
    p, _ = _team(7, n=5)
    rng = np.random.default_rng(8)
    beta = p[1:] - p[0] + rng.normal(scale=0.4, size=(4, 3))
    beta /= np.linalg.norm(beta, axis=1, keepdims=True)
    s = st.star(p[0], 0.0, p[1:], MODEL)
    val, grad = st.angle_gradient(s, beta, 4.0)
    ref_val, ref_grad = local_angle_gradient(p[0], p[1:], beta, 4.0)
    assert val == pytest.approx(ref_val, rel=1e-12) and val > 0.0
    np.testing.assert_allclose(grad, ref_grad, atol=1e-12)
    vval, vgrad = st.vertical_gradient(s, beta, 4.0)
    ref_vval, ref_vgrad = local_vertical_gradient(p[0], p[1:], beta, 4.0)
    assert vval == pytest.approx(ref_vval, rel=1e-12) and vval > 0.0
    np.testing.assert_allclose(vgrad, ref_vgrad, atol=1e-12)
    h = 1e-6
    e = np.zeros_like(p)
    e[2, 1] = h
    fd = (
        st.angle_gradient(st.star((p + e)[0], 0.0, (p + e)[1:], MODEL), beta, 4.0)[0]
        - st.angle_gradient(st.star((p - e)[0], 0.0, (p - e)[1:], MODEL), beta, 4.0)[0]
    ) / (2 * h)
    assert grad[2, 1] == pytest.approx(fd, rel=1e-5)


def test_restrict_equals_the_smaller_star() -> None:
    p, yaw = _team(9, n=6)
    s = st.star(p[0], yaw[0], p[1:], MODEL)
    idx = np.array([0, 2, 4])
    small = st.star(p[0], yaw[0], p[1:][idx], MODEL)
    part = st.restrict(s, idx)
    for name in ("r", "d", "b", "cos", "mask", "h", "dh_dr", "dh_dyaw"):
        np.testing.assert_allclose(getattr(part, name), getattr(small, name), atol=1e-15)


def test_bad_input_raises_clear_errors() -> None:
    p, yaw = _team(10, n=4)
    with pytest.raises(ValueError, match="coincides"):
        st.star(p[0], yaw[0], np.vstack([p[1:], p[:1]]), MODEL)
    s = st.star(p[0], yaw[0], p[1:], MODEL)
    with pytest.raises(ValueError, match="bearings"):
        st.angle_gradient(s, np.eye(3)[:2], 1.0)
    # fewer than two neighbours: no angle, zero blocks of the right shape
    one = st.star(p[0], yaw[0], p[1:2], MODEL)
    assert st.weighted_matvec(one, np.ones((3, 2)), np.ones((1, 3, 2))).shape == (2, 3, 2)
    assert st.form_gradient(one, np.ones(3), np.ones((1, 3)))[0] == 0.0
