"""Active scale estimation (paper 000 eq. 11-16): every gradient against finite differences,
and the properties the control laws are built for."""

import math

import numpy as np
import pytest

from onboard.control.active_scale import (
    active_velocity_rate,
    convergence_gain,
    lambda_bar,
    lambda_bar_gradient,
    rotation_rate_derivative,
    rotation_velocity_body,
    soft_min_weight,
)
from onboard.estimation.sfm_observer import excitation
from onboard.geometry import bearings_body, rot_z

PAIRS = [(0, 1), (1, 2), (0, 3), (2, 3)]


def _setup(seed):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(4, 3)) * 2
    yaw = rng.uniform(-3, 3, 4)
    u = rng.normal(size=(4, 3)) * 0.7
    return p, yaw, u


def _lambdas(p, yaw, u):
    """lambda_ij from the truth, with i's bearing and u_ij in i's body frame."""
    out = []
    for i, j in PAIRS:
        b, _ = bearings_body(p, yaw, [[i, j]])
        u_ij = rot_z(yaw[j] - yaw[i]) @ u[j] - u[i]
        out.append(excitation(tuple(b[0]), tuple(u_ij)))
    return np.array(out)


def test_soft_min_weight_is_the_partial_derivative():
    lam = np.array([0.3, 0.5, 1.2, 0.31])
    lb = lambda_bar(list(lam))
    assert lb <= lam.min()
    for k in range(4):
        e = np.zeros(4)
        e[k] = 1e-7
        fd = (lambda_bar(list(lam + e)) - lambda_bar(list(lam - e))) / 2e-7
        assert soft_min_weight(lam[k], lb) == pytest.approx(fd, rel=1e-6, abs=1e-8)  # FD round-off


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lambda_bar_gradient_wrt_own_velocity(seed):
    p, yaw, u = _setup(seed)
    lb = lambda_bar(list(_lambdas(p, yaw, u)))
    for i in range(4):
        terms = []
        for a, b in PAIRS:
            if i not in (a, b):
                continue
            j = b if a == i else a  # agent i uses ITS OWN bearing, also on edges it does not run
            beta, _ = bearings_body(p, yaw, [[i, j]])
            u_ij = rot_z(yaw[j] - yaw[i]) @ u[j] - u[i]
            terms.append((tuple(beta[0]), tuple(u_ij), excitation(tuple(beta[0]), tuple(u_ij))))
        grad = lambda_bar_gradient(terms, lb)
        fd = np.zeros(3)
        for m in range(3):
            du = np.zeros((4, 3))
            du[i, m] = 1e-6
            fd[m] = (
                lambda_bar(list(_lambdas(p, yaw, u + du)))
                - lambda_bar(list(_lambdas(p, yaw, u - du)))
            ) / 2e-6
        assert np.allclose(grad, fd, atol=1e-6)


@pytest.mark.parametrize("seed", [3, 4])
def test_rotation_gradient_is_the_sum_over_agents(seed):
    """d lambdabar / d w_l (eq. 14) = sum_i (d lambdabar/d u_i) R_i^T S (p_i - pbar)."""
    p, yaw, u = _setup(seed)
    p_bar = p.mean(axis=0)
    n3 = np.array([rotation_velocity_body(tuple(p[i]), yaw[i], tuple(p_bar)) for i in range(4)])
    lb = lambda_bar(list(_lambdas(p, yaw, u)))
    total = 0.0
    for i in range(4):
        terms = []
        for a, b in PAIRS:
            if i in (a, b):
                j = b if a == i else a
                beta, _ = bearings_body(p, yaw, [[i, j]])
                u_ij = rot_z(yaw[j] - yaw[i]) @ u[j] - u[i]
                terms.append((tuple(beta[0]), tuple(u_ij), excitation(tuple(beta[0]), tuple(u_ij))))
        total += np.dot(lambda_bar_gradient(terms, lb), n3[i])
    fd = (
        lambda_bar(list(_lambdas(p, yaw, u + 1e-6 * n3)))
        - lambda_bar(list(_lambdas(p, yaw, u - 1e-6 * n3)))
    ) / 2e-6
    assert total == pytest.approx(fd, rel=1e-5, abs=1e-8)


def test_rotation_velocity_is_a_rigid_rotation_that_keeps_body_bearings():
    p, yaw, _ = _setup(5)
    p_bar = p.mean(axis=0)
    u = np.array([rotation_velocity_body(tuple(p[i]), yaw[i], tuple(p_bar)) for i in range(4)])
    v_world = np.einsum("nij,nj->ni", rot_z(yaw), u)
    edges = [(i, j) for i in range(4) for j in range(4) if i != j]
    eps = 1e-6
    b_plus, _ = bearings_body(p + eps * v_world, yaw + eps, edges)
    b_minus, _ = bearings_body(p - eps * v_world, yaw - eps, edges)
    assert np.allclose((b_plus - b_minus) / (2 * eps), 0.0, atol=1e-8)
    assert np.allclose(v_world[:, 2], 0.0)


def test_eq12_keeps_the_speed_and_climbs_the_gradient():
    u = (0.1, 0.0, 0.0)
    grad = (0.0, 1.0, 0.5)
    for _ in range(5000):
        du = active_velocity_rate(u, grad)
        u = tuple(a + 0.002 * b for a, b in zip(u, du, strict=True))
    assert 0.5 * np.dot(u, u) == pytest.approx(0.25, rel=1e-3)
    g = np.array(grad) / np.linalg.norm(grad)
    assert np.dot(u, g) / np.linalg.norm(u) > 0.999
    # the gradient term is orthogonal to u: it turns u without changing its norm
    du = np.array(active_velocity_rate((0.6, 0.2, 0.1), grad, k_nu=0.0))
    assert np.dot(du, (0.6, 0.2, 0.1)) == pytest.approx(0.0, abs=1e-12)


def test_convergence_gain_is_a_smooth_step():
    e = np.linspace(0, 2e-3, 2001)
    k = np.array([convergence_gain(x) for x in e])
    assert k[0] == 0.0 and k[-1] == 1.0
    assert np.all(np.diff(k) >= 0)
    assert convergence_gain(1e-4) == 0.0 and convergence_gain(1e-3) == 1.0
    # C^1 at both ends: one-sided slopes vanish
    h = 1e-9
    assert (convergence_gain(1e-4 + h) - convergence_gain(1e-4)) / h < 1e-2
    assert (convergence_gain(1e-3) - convergence_gain(1e-3 - h)) / h < 1e-2


def test_rotation_rate_is_damped_and_gated_by_e():
    assert rotation_rate_derivative(0.5, 3.0, 0.1, k_e=0.0) == pytest.approx(-0.5)
    assert rotation_rate_derivative(0.0, 3.0, 0.05, k_e=1.0) == pytest.approx(2.0 * 0.5 * 3.0)
    assert math.isfinite(rotation_rate_derivative(0.0, 1.0, -1.0, 1.0))


def test_the_start_bias_makes_zero_unstable_and_fades_with_the_gate():
    kw = {"k_w": 1.0, "k_l0": 2.0, "gamma": 0.05}
    # no gradient, gate fully on: a small w_l of either sign is pushed away from 0 towards
    # +-w_l_start, and w_l_start itself is an equilibrium
    assert rotation_rate_derivative(0.01, 0.0, 0.0, 1.0, w_l_start=0.4, **kw) > 0.0
    assert rotation_rate_derivative(-0.01, 0.0, 0.0, 1.0, w_l_start=0.4, **kw) < 0.0
    at_start = rotation_rate_derivative(0.4, 0.0, 0.0, 1.0, w_l_start=0.4, **kw)
    assert abs(at_start) < 1e-6
    # gate at or below one half: paper 000's eq. 15 exactly
    for k_e in (0.0, 0.3, 0.5):
        paper = rotation_rate_derivative(0.2, 1.5, 0.1, k_e, **kw)
        assert rotation_rate_derivative(0.2, 1.5, 0.1, k_e, w_l_start=0.4, **kw) == paper
