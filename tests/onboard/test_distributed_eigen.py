"""Distributed power iteration for the weighted angle rigidity eigenvalue (paper 003 eq. 16,
Zelazo et al. 2015 / Yang et al. 2010 scheme): local pieces assemble the global matrix, the
trivial basis spans its null space, and the network converges from a perturbed start."""

from __future__ import annotations

import numpy as np
import pytest

from onboard.estimation.distributed_eigen import (
    EigenGains,
    local_gram_and_form_gradient,
    local_weighted_gram,
    run_rounds,
    trivial_motion_basis,
)
from onboard.graph import complete_graph
from onboard.rigidity.angle import (
    weighted_angle_rigidity_eigenvalue,
    weighted_angle_rigidity_matrix,
    weighted_form_gradient,
)
from onboard.rigidity.weights import SensingModel

MODEL = SensingModel(140.0, 12.0)


def _team(seed: int = 0, n: int = 5) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    p = rng.uniform(-2.5, 2.5, (n, 3)) + np.array([0.0, 0.0, -6.0])
    c = p.mean(axis=0)
    yaw = np.arctan2(c[1] - p[:, 1], c[0] - p[:, 0]) + rng.normal(scale=0.2, size=n)
    return p, yaw


def _candidates(n: int) -> list[list[int]]:
    return [[j for j in range(n) if j != i] for i in range(n)]


def test_local_grams_assemble_the_global_matrix() -> None:
    p, yaw = _team(1)
    n = len(p)
    total = np.zeros((3 * n, 3 * n))
    for i, cand in enumerate(_candidates(n)):
        idx = np.concatenate([np.arange(3 * j, 3 * j + 3) for j in [i, *cand]])
        total[np.ix_(idx, idx)] += local_weighted_gram(p[i], yaw[i], p[cand], MODEL)
    ref = weighted_angle_rigidity_matrix(p, yaw, complete_graph(n), MODEL)
    np.testing.assert_allclose(total, ref, atol=1e-12)


def test_local_form_gradients_sum_to_the_global_one() -> None:
    p, yaw = _team(2)
    n = len(p)
    v = np.random.default_rng(3).normal(size=(n, 3))
    gp = np.zeros((n, 3))
    gy = np.zeros(n)
    value = 0.0
    for i, cand in enumerate(_candidates(n)):
        _, val, g, g_yaw = local_gram_and_form_gradient(p[i], yaw[i], p[cand], v[[i, *cand]], MODEL)
        value += val
        gp[i] += g[0]
        np.add.at(gp, cand, g[1:])
        gy[i] += g_yaw
    ref_val, ref_p, ref_y = weighted_form_gradient(p, yaw, complete_graph(n), MODEL, v)
    assert value == pytest.approx(ref_val, rel=1e-12)
    np.testing.assert_allclose(gp, ref_p, atol=1e-12)
    np.testing.assert_allclose(gy, ref_y, atol=1e-12)


def test_trivial_basis_spans_the_null_space() -> None:
    p, yaw = _team(4)
    m = weighted_angle_rigidity_matrix(p, yaw, complete_graph(len(p)), MODEL)
    t = trivial_motion_basis(p)
    assert np.linalg.matrix_rank(t) == 7
    assert np.max(np.abs(m @ t)) < 1e-10 * np.max(np.abs(m))


@pytest.mark.parametrize("seed", [0, 5])
def test_converges_from_a_perturbed_start(seed: int) -> None:
    p, yaw = _team(seed)
    n = len(p)
    lam, vec = weighted_angle_rigidity_eigenvalue(p, yaw, complete_graph(n), MODEL)
    assert lam > 0.02  # the fixed graph is IAR
    rng = np.random.default_rng(seed + 100)
    v0 = np.sqrt(n) * vec.reshape(n, 3) + rng.normal(scale=0.7, size=(n, 3))
    est, v = run_rounds(
        p,
        yaw,
        _candidates(n),
        MODEL,
        600,
        dt=0.01,
        gains=EigenGains(k_m=8.0, k_t=10.0, k_n=10.0),
        v0=v0,
    )
    err0 = np.max(np.abs(est[0] - lam)) / lam
    err = np.max(np.abs(est[-1] - lam)) / lam
    assert err0 > 0.5  # the start is far off
    assert err < 0.01
    # every agent holds its block of the same eigenvector (up to sign and scale)
    u = v.ravel() / np.linalg.norm(v)
    assert abs(float(u @ vec)) > 0.99


def test_random_start_reaches_five_percent() -> None:
    p, yaw = _team(7)
    n = len(p)
    lam = weighted_angle_rigidity_eigenvalue(p, yaw, complete_graph(n), MODEL)[0]
    est, _ = run_rounds(
        p,
        yaw,
        _candidates(n),
        MODEL,
        800,
        dt=0.01,
        gains=EigenGains(k_m=8.0, k_t=10.0, k_n=10.0),
        seed=3,
    )
    assert np.max(np.abs(est[-1] - lam)) / lam < 0.05
