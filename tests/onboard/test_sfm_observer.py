"""SfM inverse-depth observer (paper 000 eq. 7-10): model, gain shaping, convergence with and
without persistent excitation, and the convergence index."""

import math

import numpy as np
import pytest

from onboard.estimation.sfm_observer import (
    SfmEdge,
    WindowAverage,
    bearing_rate,
    excitation,
    observer_rates,
)
from onboard.geometry import bearings_body, rot_z


def _beta(p_i, yaw_i, p_j):
    b, d = bearings_body(np.array([p_i, p_j]), np.array([yaw_i, 0.0]), np.array([[0, 1]]))
    return b[0], d[0]


def test_bearing_rate_matches_finite_difference_of_true_bearing():
    rng = np.random.default_rng(0)
    for _ in range(5):
        p_i, p_j = rng.normal(size=(2, 3)) * 3
        yaw_i, yaw_j = rng.uniform(-3, 3, 2)
        u_i, u_j = rng.normal(size=(2, 3))
        w_i = rng.normal()
        eps = 1e-6

        def beta_at(s, p_i=p_i, p_j=p_j, yaw_i=yaw_i, yaw_j=yaw_j, u_i=u_i, u_j=u_j, w_i=w_i):
            pi = p_i + s * rot_z(yaw_i) @ u_i
            pj = p_j + s * rot_z(yaw_j) @ u_j
            return _beta(pi, yaw_i + s * w_i, pj)[0]

        fd = (beta_at(eps) - beta_at(-eps)) / (2 * eps)
        beta, d = _beta(p_i, yaw_i, p_j)
        u_ij = rot_z(yaw_j - yaw_i) @ u_j - u_i
        model = bearing_rate(tuple(beta), 1.0 / d, tuple(u_ij), w_i)
        assert np.allclose(model, fd, atol=1e-7)
        assert excitation(tuple(beta), tuple(u_ij)) == pytest.approx(
            u_ij @ (np.eye(3) - np.outer(beta, beta)) @ u_ij
        )


def test_gain_is_the_svd_shaped_h():
    rng = np.random.default_rng(1)
    alpha, h = 10.0, 10.0
    beta = rng.normal(size=3)
    beta /= np.linalg.norm(beta)
    u = rng.normal(size=3)
    omega = (u @ (np.eye(3) - np.outer(beta, beta)))[None, :]
    _, sv, vt = np.linalg.svd(omega)
    lam = sv[0] ** 2
    h_ref = vt.T @ np.diag([2 * math.sqrt(alpha * lam), h, h]) @ vt
    base, _ = observer_rates(tuple(beta), 0.3, tuple(beta), tuple(u), 0.2, alpha, h)
    h_num = np.zeros((3, 3))
    for k in range(3):
        xi = np.zeros(3)
        xi[k] = 1e-3
        d, _ = observer_rates(tuple(beta + xi), 0.3, tuple(beta), tuple(u), 0.2, alpha, h)
        h_num[:, k] = -(np.array(d) - np.array(base)) / 1e-3
    assert np.allclose(h_num, h_ref, atol=1e-9)


def _simulate(u_world_of_t, duration=8.0, dt=0.002, frame_every=10, chi0_factor=1.6):
    """Agent i moves with world velocity u(t) (yaw spinning slowly), j hovers at the origin."""
    p_i = np.array([3.0, 1.0, -1.0])
    p_j = np.zeros(3)
    yaw_i = 0.4
    w_i = 0.1
    beta, d = _beta(p_i, yaw_i, p_j)
    edge = SfmEdge(chi_hat=chi0_factor / d)
    errors = []
    for k in range(int(duration / dt)):
        t = k * dt
        beta, d = _beta(p_i, yaw_i, p_j)
        v_world = u_world_of_t(t, p_i)
        u_i = rot_z(yaw_i).T @ v_world
        u_ij = tuple(-u_i)  # j is still
        if k % frame_every == 0:
            edge.new_bearing(tuple(beta), t, t, u_ij, w_i)
        edge.step(t, dt, u_ij, w_i)
        errors.append(edge.chi_hat - 1.0 / d)
        p_i = p_i + dt * v_world
        yaw_i += dt * w_i
    return np.array(errors), edge


def test_observer_converges_under_persistent_excitation():
    def orbit(t, p):  # horizontal circle-ish motion across the line of sight
        return 0.7 * np.array([-math.sin(0.8 * t), math.cos(0.8 * t), 0.2 * math.sin(t)])

    err, edge = _simulate(orbit)
    assert abs(err[0]) > 0.1
    assert abs(err[-1]) < 1e-3
    assert edge.excitation > 0.05
    assert edge.e_index < 1e-6


def test_observer_stalls_without_excitation():
    def along_line_of_sight(t, p):  # u parallel to beta: Omega = 0, lambda = 0
        return -0.3 * p / np.linalg.norm(p)

    err, edge = _simulate(along_line_of_sight, duration=4.0)
    assert edge.excitation < 1e-12
    assert abs(err[-1]) > 0.5 * abs(err[0])

    err_still, _ = _simulate(lambda t, p: np.zeros(3), duration=4.0)
    assert err_still[-1] == pytest.approx(err_still[0], rel=1e-9)


def test_frame_prediction_leaves_no_bias():
    def orbit(t, p):
        return 0.7 * np.array([-math.sin(0.8 * t), math.cos(0.8 * t), 0.0])

    err_50hz, _ = _simulate(orbit, frame_every=10)
    err_500hz, _ = _simulate(orbit, frame_every=1)
    assert abs(err_50hz[-1]) < 1e-3 and abs(err_500hz[-1]) < 1e-3


def test_window_average_is_the_moving_integral():
    w = WindowAverage(window_s=1.0)
    dt = 0.002
    for k in range(1, 1501):
        t = k * dt
        w.add(t, t, dt)  # signal y = t
    # (1/T) int_{t-1}^{t} y = t - 0.5 at t = 3 (piecewise constant samples: +dt/2)
    assert w.value == pytest.approx(3.0 - 0.5 + dt / 2, abs=1e-9)
    w2 = WindowAverage(window_s=1.0)
    for k in range(1, 201):
        w2.add(k * 0.002, 2.0, 0.002)
    assert w2.value == pytest.approx(2.0 * 0.4)  # only 0.4 s of data so far


def test_resync_restarts_the_bearing_state_without_a_kick():
    """After a hole the first frame shows the bearing moved on; a resynchronized observer takes
    it as its new state (no ``-alpha Omega xi`` kick), and keeps ``chihat``."""
    u = (0.0, 1.0, 0.0)

    def after_hole(resync: bool) -> float:
        edge = SfmEdge(chi_hat=0.2)
        edge.new_bearing((1.0, 0.0, 0.0), 0.0, 0.0, u, 0.0)
        edge.step(0.01, 0.01, u, 0.0)
        if resync:
            edge.resync()
            edge.step(0.02, 0.01, u, 0.0)  # no frame yet: nothing to integrate
            assert edge.chi_hat == pytest.approx(0.2, abs=1e-3)
        beta = (math.cos(0.3), math.sin(0.3), 0.0)  # 1 s later, the target has moved on
        edge.new_bearing(beta, 1.0, 1.0, u, 0.0)
        chi = edge.chi_hat
        edge.step(1.01, 0.01, u, 0.0)
        return abs(edge.chi_hat - chi)

    assert after_hole(resync=True) < 1e-3 < after_hole(resync=False)


def test_chi_at_carries_the_estimate_to_now():
    """The agent runs an observer only up to its newest frame; ``chi_at`` carries ``chihat``
    over the frame's age with the model (eq. 7). Approaching the target at 1 m/s from 5 m, 0.15 s
    after the observer's time: the carried estimate is within 2e-4 1/m of the truth, the raw one
    is about 0.006 1/m (3%) short; the carry is capped at the horizon."""
    p_i, yaw_i, w_i, dt = np.array([5.0, 0.5, -1.0]), 0.3, 0.0, 0.002
    v_world = np.array([-1.0, 0.3, 0.0])  # mostly towards j at the origin, a little across
    beta, d = _beta(p_i, yaw_i, np.zeros(3))
    edge = SfmEdge(chi_hat=1.0 / d)  # converged: isolate the carry
    t = 0.0
    for k in range(100):
        t = k * dt
        beta, d = _beta(p_i + t * v_world, yaw_i, np.zeros(3))
        u_ij = tuple(-(rot_z(yaw_i).T @ v_world))
        if k % 10 == 0:
            edge.new_bearing(tuple(beta), t, t, u_ij, w_i)
        edge.step(t, dt, u_ij, w_i)
    assert edge.t_s == t
    h = 0.15
    _, d_later = _beta(p_i + (t + h) * v_world, yaw_i, np.zeros(3))
    raw_error = edge.chi_hat - 1.0 / d_later
    carried_error = edge.chi_at(t + h, horizon_s=0.5) - 1.0 / d_later
    assert raw_error < -0.005
    assert abs(carried_error) < 2e-4, (raw_error, carried_error)
    assert edge.chi_at(t + 10.0, horizon_s=0.5) == pytest.approx(edge.chi_at(t + 0.5, 0.5))
    assert edge.chi_at(t - 1.0, horizon_s=0.5) == edge.chi_hat  # never carried backwards
