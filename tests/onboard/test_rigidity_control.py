"""Rigidity maintenance, collision and tracking potentials (paper 003 eq. 19, 30, 32):
every gradient against central finite differences, plus the barrier's shape."""

from __future__ import annotations

import numpy as np
import pytest

from onboard.control import rigidity as ctl
from onboard.geometry import camera_axis_ned, rot_z
from onboard.graph import complete_graph
from onboard.rigidity.angle import (
    weighted_angle_rigidity_eigenvalue,
    weighted_eigenvalue_gradient,
    weighted_eigenvalues_gradients,
)
from onboard.rigidity.weights import SensingModel

GAINS = ctl.MaintenanceGains(
    lambda_min=0.02,
    lambda_safe=0.2,
    k_rigidity=0.3,
    r_coll_m=0.5,
    r_safe_m=2.0,
    k_collision=0.7,
    r_track_m=1.5,
    k_track_range=0.4,
    k_track_camera=1.3,
)


def _fd(f, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    out = np.zeros_like(x)
    for k in range(x.size):
        e = np.zeros_like(x)
        e.flat[k] = h
        out.flat[k] = (f(x + e) - f(x - e)) / (2 * h)
    return out


def test_barrier_slope_matches_finite_differences() -> None:
    lam = np.linspace(0.03, 0.19, 17)
    _, slope = ctl.rational_barrier(lam, 0.02, 0.2, 0.3)
    fd = np.array(
        [_fd(lambda x: ctl.rational_barrier(x[0], 0.02, 0.2, 0.3)[0], [v])[0] for v in lam]
    )
    np.testing.assert_allclose(slope, fd, rtol=1e-5)


def test_barrier_is_c1_at_safe_level_and_unbounded_at_minimum() -> None:
    v, s = ctl.rational_barrier(np.array([0.2, 0.2 - 1e-7, 0.5]), 0.02, 0.2, 1.0)
    assert v[0] == 0.0 and s[0] == 0.0 and v[2] == 0.0 and s[2] == 0.0
    assert v[1] < 1e-10 and abs(s[1]) < 1e-4  # value and slope go to 0 continuously
    v_low, s_low = ctl.rational_barrier(np.array([0.021, 0.0201, 0.02001]), 0.02, 0.2, 1.0)
    assert np.all(np.diff(v_low) > 0) and v_low[-1] > 1e3
    assert np.all(s_low < 0)  # descending pushes lambda up
    v_below, s_below = ctl.rational_barrier(0.0, 0.02, 0.2, 1.0)
    assert np.isinf(v_below) and np.isfinite(s_below) and s_below < -1e5


def test_barrier_rejects_bad_levels() -> None:
    with pytest.raises(ValueError):
        ctl.rational_barrier(0.1, 0.2, 0.1)
    with pytest.raises(ValueError):
        ctl.MaintenanceGains(lambda_min=0.3, lambda_safe=0.2)


def test_collision_gradient_matches_finite_differences() -> None:
    rng = np.random.default_rng(3)
    p_i = np.array([0.1, -0.2, -3.0])
    others = p_i + rng.normal(scale=0.9, size=(5, 3))
    others = others[np.linalg.norm(others - p_i, axis=1) > 0.6]
    value, grad = ctl.collision_potential(p_i, others, GAINS)
    assert value > 0.0  # some neighbour is inside r_safe
    fd = _fd(lambda x: ctl.collision_potential(x, others, GAINS)[0], p_i)
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-8)
    # far away: no force
    v_far, g_far = ctl.collision_potential(p_i, p_i + np.array([[5.0, 0, 0]]), GAINS)
    assert v_far == 0.0 and np.all(g_far == 0.0)


def test_tracking_gradient_matches_finite_differences() -> None:
    p_i = np.array([1.0, 2.0, -4.0])
    yaw = 0.4
    target = np.array([4.0, -1.0, -5.5])
    _, gp, gy = ctl.tracking_potential(p_i, yaw, target, GAINS)
    fd_p = _fd(lambda x: ctl.tracking_potential(x, yaw, target, GAINS)[0], p_i)
    fd_y = _fd(lambda x: ctl.tracking_potential(p_i, x[0], target, GAINS)[0], [yaw])[0]
    np.testing.assert_allclose(gp, fd_p, rtol=1e-6, atol=1e-9)
    assert gy == pytest.approx(fd_y, rel=1e-6)


def test_tracking_body_form_equals_world_gradient() -> None:
    p_i = np.array([1.0, 2.0, -4.0])
    yaw = -2.1
    target = np.array([-3.0, 0.5, -2.0])
    _, gp, gy = ctl.tracking_potential(p_i, yaw, target, GAINS)
    r = target - p_i
    beta = rot_z(yaw).T @ r / np.linalg.norm(r)
    u, w = ctl.tracking_control_body(beta, float(np.linalg.norm(r)), GAINS)
    u_ref, w_ref = ctl.world_to_body_control(gp, gy, yaw)
    np.testing.assert_allclose(u, u_ref, atol=1e-12)
    assert w == pytest.approx(w_ref, abs=1e-12)


def test_tracking_flow_points_camera_at_target_and_holds_radius() -> None:
    p = np.array([0.0, 0.0, -3.0])
    yaw = 2.5
    target = np.array([6.0, 1.0, -3.0])
    dt = 0.02
    for _ in range(3000):
        _, gp, gy = ctl.tracking_potential(p, yaw, target, GAINS)
        p = p - dt * gp
        yaw = yaw - dt * gy
    b = (target - p) / np.linalg.norm(target - p)
    assert float(camera_axis_ned(yaw) @ b) > 0.999
    assert np.linalg.norm(target - p) == pytest.approx(GAINS.r_track_m, abs=0.05)


def test_rigidity_action_increases_the_weighted_eigenvalue() -> None:
    # cameras towards the centroid: a rigid start (with seed 5 and cameras 0.5 rad off it, as
    # before, the eigenvalue was 2e-16 and the comparison below one of round-off)
    rng = np.random.default_rng(4)
    p = rng.uniform(-2.0, 2.0, (5, 3)) + np.array([0.0, 0.0, -5.0])
    c = p.mean(axis=0)
    yaw = np.arctan2(c[1] - p[:, 1], c[0] - p[:, 0])
    model = SensingModel(100.0, 8.0)
    edges = complete_graph(5)
    lam, gp, gy = weighted_eigenvalue_gradient(p, yaw, edges, model)
    assert lam > 1e-3
    gains = ctl.MaintenanceGains(lambda_min=0.5 * lam, lambda_safe=2.0 * lam, k_rigidity=0.1)
    dt = 1e-3
    p_new, yaw_new = p.copy(), yaw.copy()
    for i in range(5):
        u, w = ctl.rigidity_control_body(lam, gp[i], gy[i], yaw[i], gains)
        p_new[i] += dt * rot_z(yaw[i]) @ u
        yaw_new[i] += dt * w
    lam_new = weighted_angle_rigidity_eigenvalue(p_new, yaw_new, edges, model)[0]
    assert lam_new > lam * (1.0 + 1e-9)


def test_camera_angular_velocity_reduces_to_yaw_rate() -> None:
    yaw = 0.8
    p_i = np.zeros(3)
    target = np.array([1.0, 3.0, -0.5])
    g_c = ctl.tracking_axis_gradient(p_i, camera_axis_ned(yaw), target, GAINS)
    omega = ctl.camera_angular_velocity(g_c, rot_z(yaw))
    _, _, gy = ctl.tracking_potential(p_i, yaw, target, GAINS)
    assert omega[2] == pytest.approx(-gy, rel=1e-9)
    # the full-rotation variant also pitches the camera toward a target below the horizon
    assert omega[1] != 0.0


def test_agent_core_rigidity_mode_drops_bad_payloads_and_commands_finite() -> None:
    from messages.agent import BearingMeasurement, OwnMeasurements, TargetMeasurement
    from messages.rigidity import AngleLocalizationShare, RigidityEigenShare
    from onboard.core.agent import AgentCore
    from onboard.core.config import build_config

    edges = tuple((i, j) for i in range(3) for j in range(3) if i != j)
    prior = ((0.0, 0.0, -5.0), (3.0, 1.0, -5.0), (2.0, -2.0, -6.0))
    core = AgentCore(
        build_config(
            agent_id=0,
            n_agents=3,
            edges=edges,
            mode="rigidity-tracking",
            rigidity_maintenance=True,
            p_hat0_ned=prior,
            track_target=0,
        )
    )
    bad = RigidityEigenShare(  # not the layout of 3 vectors per agent
        sender=1, seq=0, stamp_s=0.0, lambda_hat=0.1, targets=[0], state=np.zeros(3),
        per_target=np.zeros(3),
    )  # fmt: skip
    good = AngleLocalizationShare(
        sender=2, seq=0, stamp_s=0.0, p_hat_ned=prior[2], yaw_hat_rad=0.0, yaw_known=True,
        blocks=[],
    )  # fmt: skip
    own = OwnMeasurements(
        t_s=0.01,
        yaw_rad=0.3,
        v_body=(0.0, 0.0, 0.0),
        yaw_rate_rad_s=0.0,
        bearings=(BearingMeasurement(2, (float("nan"), 0.0, 0.0), 0.0),),
        targets=(TargetMeasurement(0, (0.0, 1.0, 0.0), 5.0, 0.01),),
    )
    sp, out = core.step(0.01, own, [bad, good])
    assert core.dropped.get("malformed") == 1
    assert all(np.isfinite(sp.v_body)) and np.isfinite(sp.yaw_rate_rad_s)
    assert sp.yaw_rate_rad_s > 0.0  # target on the right: turn right
    assert core.dropped.get("bad_bearing") == 1
    assert {type(m) for m in out} == {AngleLocalizationShare, RigidityEigenShare}
    # a core without the rigidity layer counts rigidity payloads as unknown
    plain = AgentCore(build_config(agent_id=0, n_agents=3, edges=edges, mode="hold"))
    plain.step(0.0, own, [good])
    assert plain.dropped.get("unknown_type") == 1


def test_softmin_weights_blend_only_the_modes_near_the_minimum() -> None:
    w = ctl.softmin_weights([0.30, 0.10, 0.11], 0.01)
    assert w.sum() == pytest.approx(1.0)
    assert w[1] > w[2] > 0.2 and w[0] < 1e-8  # 0.2 above the minimum: out of the blend
    np.testing.assert_array_equal(ctl.softmin_weights([0.3, 0.1, 0.11], 0.0), [0.0, 1.0, 0.0])
    np.testing.assert_allclose(ctl.softmin_weights([0.2, 0.2], 0.05), [0.5, 0.5])
    with pytest.raises(ValueError):
        ctl.softmin_weights([], 0.01)
    with pytest.raises(ValueError):
        ctl.MaintenanceGains(softmin_tau=-1.0)


def test_smooth_minimum_gradient_matches_finite_differences() -> None:
    """``sum_m pi_m grad lambda_m`` is the gradient of ``L = -tau log sum_m exp(-lambda_m / tau)``
    over the 3 smallest non-trivial weighted eigenvalues (what the rigidity action follows)."""
    rng = np.random.default_rng(3)
    p = rng.uniform(-3.0, 3.0, (5, 3)) + np.array([0.0, 0.0, -5.0])
    c = p.mean(axis=0)
    yaw = np.arctan2(c[1] - p[:, 1], c[0] - p[:, 0]) + rng.normal(0.0, 0.3, 5)
    model = SensingModel(120.0, 10.0)
    edges = complete_graph(5)
    lams, gp, gy = weighted_eigenvalues_gradients(p, yaw, edges, model, 3)
    tau = float(lams[1] - lams[0])  # the second mode weighs e^-1 of the first: a real blend
    pi = ctl.softmin_weights(lams, tau)
    assert pi[1] > 0.2

    def smooth_min(x: np.ndarray, y: np.ndarray) -> float:
        lam = weighted_eigenvalues_gradients(x, y, edges, model, 3)[0]
        return float(-tau * np.log(np.sum(np.exp(-(lam - lams[0]) / tau))))

    grad_p = np.einsum("m,mnd->nd", pi, gp)
    grad_yaw = pi @ gy
    num_p = _fd(lambda x: smooth_min(x, yaw), p)
    num_yaw = _fd(lambda y: smooth_min(p, y), yaw)
    scale = max(np.abs(grad_p).max(), np.abs(grad_yaw).max())
    assert np.abs(grad_p - num_p).max() <= 1e-6 * scale
    assert np.abs(grad_yaw - num_yaw).max() <= 1e-6 * scale
    # and it is not the smallest mode's gradient alone
    assert np.abs(grad_p - gp[0]).max() > 0.05 * scale
