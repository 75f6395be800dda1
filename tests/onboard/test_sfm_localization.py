"""Localization filter (paper 000 eq. 6): per-edge gradients against finite differences, the
agents' blocks add up to the gradient of the global cost, and the filter recovers the correct
scale from distances."""

import math

import numpy as np
import pytest

from onboard.estimation.localization import (
    LocalizationFilter,
    bearing_term_gradient,
    distance_term_gradient,
)
from onboard.geometry import bearings_body
from onboard.graph import reciprocal_pairs
from sim.runner import localization_error, scale_ratio

EDGES = np.array([[0, 1], [1, 0], [1, 2], [2, 0], [2, 3], [3, 2], [3, 1], [0, 3]])


def _cost(p, yaw, beta_meas, d_hat, k_l=100.0, k_d=1.0):
    b, _ = bearings_body(p, yaw, EDGES)
    pairs = reciprocal_pairs(EDGES)
    r = p[pairs[:, 1]] - p[pairs[:, 0]]
    return 0.5 * k_l * np.sum((b - beta_meas) ** 2) + 0.25 * k_d * np.sum(
        (np.sum(r * r, axis=1) - d_hat**2) ** 2
    )


def test_edge_gradients_match_finite_differences():
    rng = np.random.default_rng(5)
    p = rng.normal(size=(2, 3)) * 2
    yaw = rng.uniform(-3, 3)
    beta = rng.normal(size=3)
    beta /= np.linalg.norm(beta)

    def f(x):
        b, _ = bearings_body(np.array([x[0:3], x[4:7]]), np.array([x[3], 0.0]), [[0, 1]])
        return 0.5 * np.sum((b[0] - beta) ** 2)

    x0 = np.concatenate([p[0], [yaw], p[1]])
    fd = np.array([(f(x0 + e) - f(x0 - e)) / 2e-6 for e in np.eye(7) * 1e-6])
    g_i, g_yaw, g_j = bearing_term_gradient(tuple(p[0]), yaw, tuple(p[1]), tuple(beta))
    assert np.allclose(np.concatenate([g_i, [g_yaw], g_j]), fd, atol=1e-7)

    d_hat = 1.7

    def h(pi):
        return 0.25 * (np.sum((p[1] - pi) ** 2) - d_hat**2) ** 2

    fd_d = np.array([(h(p[0] + e) - h(p[0] - e)) / 2e-6 for e in np.eye(3) * 1e-6])
    assert np.allclose(distance_term_gradient(tuple(p[0]), tuple(p[1]), d_hat), fd_d, atol=1e-6)


def _filter_step(p_hat, yaw_hat, beta_meas, d_hat, dt, **bounds):
    """Every agent advances its own block with only its local data (zero velocity)."""
    pairs = {tuple(e) for e in reciprocal_pairs(EDGES)}
    rows = {tuple(e): k for k, e in enumerate(EDGES)}
    new_p, new_yaw = p_hat.copy(), yaw_hat.copy()
    for i in range(len(p_hat)):
        f = LocalizationFilter(tuple(p_hat[i]), yaw_hat[i], **bounds)
        out = [(tuple(p_hat[j]), tuple(beta_meas[rows[(i, j)]])) for a, j in EDGES if a == i]
        inn = [
            (tuple(p_hat[a]), yaw_hat[a], tuple(beta_meas[rows[(a, i)]]))
            for a, j in EDGES
            if j == i
        ]
        dist = [
            (tuple(p_hat[b if a == i else a]), d_hat[k])
            for k, (a, b) in enumerate(sorted(pairs))
            if i in (a, b)
        ]
        f.step(dt, (0.0, 0.0, 0.0), 0.0, out, inn, dist)
        new_p[i], new_yaw[i] = f.p_hat_ned, f.yaw_hat_rad
    return new_p, new_yaw


def test_agent_blocks_sum_to_the_global_gradient():
    rng = np.random.default_rng(6)
    p = rng.normal(size=(4, 3)) * 2
    yaw = rng.uniform(-3, 3, 4)
    beta_meas, _ = bearings_body(p + rng.normal(size=p.shape) * 0.3, yaw + 0.1, EDGES)
    d_hat = rng.uniform(1, 3, len(reciprocal_pairs(EDGES)))
    dt = 1e-7
    unbounded = {"max_correction_m_s": math.inf, "max_correction_rad_s": math.inf}
    p1, y1 = _filter_step(p, yaw, beta_meas, d_hat, dt, **unbounded)
    step = np.concatenate([(p1 - p).ravel(), y1 - yaw]) / dt
    x0 = np.concatenate([p.ravel(), yaw])

    def j(x):
        return _cost(x[:12].reshape(4, 3), x[12:], beta_meas, d_hat)

    grad = np.array([(j(x0 + e) - j(x0 - e)) / 2e-6 for e in np.eye(16) * 1e-6])
    assert np.allclose(step, -grad, rtol=1e-4, atol=1e-4)


def test_filter_recovers_configuration_with_correct_scale():
    rng = np.random.default_rng(7)
    p = np.array([[0, 0, -2], [2.5, 0.5, -2.5], [1, 2.5, -1.5], [-1.5, 1.5, -2.2]], dtype=float)
    yaw = np.array([0.3, 2.0, -1.0, 1.0])
    beta_meas, _ = bearings_body(p, yaw, EDGES)
    pairs = reciprocal_pairs(EDGES)
    d_true = np.linalg.norm(p[pairs[:, 1]] - p[pairs[:, 0]], axis=1)
    p_hat = 1.4 * p + rng.normal(size=p.shape) * 0.2 + np.array([1.0, -2.0, 0.5])
    yaw_hat = yaw + 0.1 * rng.normal(size=4)
    assert localization_error(p_hat, p) > 0.5
    for _ in range(3000):
        p_hat, yaw_hat = _filter_step(p_hat, yaw_hat, beta_meas, d_true, 0.002)
    assert localization_error(p_hat, p) < 1e-3
    assert scale_ratio(p_hat, p) == pytest.approx(1.0, abs=1e-3)


def test_bearing_term_is_zero_not_nan_for_coincident_estimates():
    """Two estimates at the same point define no bearing: the term must vanish, not divide by 0."""
    import math

    from onboard.estimation.localization import bearing_term_gradient

    g_i, g_yaw, g_j = bearing_term_gradient((1.0, 2.0, 3.0), 0.3, (1.0, 2.0, 3.0), (1.0, 0.0, 0.0))
    assert g_i == (0.0, 0.0, 0.0) and g_yaw == 0.0 and g_j == (0.0, 0.0, 0.0)
    g_i, g_yaw, _ = bearing_term_gradient((0.0, 0.0, 0.0), 0.0, (2.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    assert all(math.isfinite(x) for x in (*g_i, g_yaw)) and g_yaw != 0.0


def test_correction_speed_is_bounded_along_the_gradient():
    """A far-off SfM distance makes the quartic term's gradient huge; one step must stay bounded
    (explicit Euler diverged to NaN in the demo) and still point down the gradient."""
    from onboard.estimation.localization import MAX_CORRECTION_M_S, LocalizationFilter

    p_i, p_j, d_hat = (0.0, 0.0, 0.0), (5.0, 0.0, 0.0), 50.0
    free = LocalizationFilter(p_i, 0.0, max_correction_m_s=math.inf)
    bounded = LocalizationFilter(p_i, 0.0)
    for f in (free, bounded):
        f.step(0.005, (0.0, 0.0, 0.0), 0.0, [], [], [(p_j, d_hat)])
    step_free, step_bounded = np.array(free.p_hat_ned), np.array(bounded.p_hat_ned)
    assert np.linalg.norm(step_free) > 10 * MAX_CORRECTION_M_S * 0.005
    assert np.linalg.norm(step_bounded) == pytest.approx(MAX_CORRECTION_M_S * 0.005)
    assert np.allclose(
        step_bounded / np.linalg.norm(step_bounded), step_free / np.linalg.norm(step_free)
    )
