"""Paper 002 eq. 23 in flight and the smooth formation switch (onboard/control/formation.py,
onboard/core/motion.py): the body-frame distance terms are ``-k_F`` times the gradient of the
distance cost (finite differences of :func:`onboard.distributed.formation.formation_costs`),
the ramp is a smoothstep, the desired bearings turn along great circles, a core that adopts a
doubled formation with its distances pushes the vehicles apart (bearings only: it does not),
and the command never jumps at the switch."""

from __future__ import annotations

import math

import numpy as np
import pytest

from messages.agent import BearingMeasurement, OwnMeasurements
from messages.peer import LocalizationState
from onboard.control.formation import (
    formation_distance_velocity,
    formation_velocity,
    ramp_fraction,
    slerp_bearing,
)
from onboard.core.agent import AgentCore
from onboard.core.config import build_config
from onboard.distributed.formation import formation_costs
from onboard.distributed.reshaping import ReshapeD
from onboard.geometry import bearings_body, rot_z

EDGES = np.array([[0, 1], [1, 0], [1, 2], [2, 0], [2, 3], [3, 1], [0, 3]])
TRIANGLE = ((0, 1), (1, 0), (1, 2), (2, 1), (0, 2), (2, 0))
P_OLD = np.array([[0.0, 0.0, -5.0], [4.0, 0.0, -5.0], [2.0, 3.464, -5.0]])
YAW = np.array([0.3, -0.4, 1.1])


@pytest.mark.parametrize("f_d", [ReshapeD(w=0.7), ReshapeD(w=0.25, delta=2.0)])
@pytest.mark.parametrize("seed", [0, 1])
def test_bearing_plus_distance_velocity_is_minus_kf_times_the_gradient(seed, f_d):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(4, 3)) * 3.0
    yaw = rng.uniform(-3, 3, 4)
    des = rng.normal(size=(len(EDGES), 3))
    des /= np.linalg.norm(des, axis=1, keepdims=True)
    d_des = rng.uniform(1.0, 6.0, len(EDGES))
    t_des_world = np.einsum("eij,ej->ei", rot_z(yaw[EDGES[:, 0]]), des)
    beta, d = bearings_body(p, yaw, EDGES)
    k_f = 0.5

    def cost(q: np.ndarray) -> float:
        return float(np.sum(formation_costs(q, EDGES, t_des_world, d_des, f_d=f_d)))

    for i in range(4):
        out = [e for e in range(len(EDGES)) if EDGES[e, 0] == i]
        inn = [e for e in range(len(EDGES)) if EDGES[e, 1] == i]
        u_b = formation_velocity(
            [(tuple(beta[e]), tuple(des[e])) for e in out],
            [(yaw[EDGES[e, 0]] - yaw[i], tuple(beta[e]), tuple(des[e])) for e in inn],
            k_f,
        )
        u_d = formation_distance_velocity(
            [(tuple(beta[e]), tuple(des[e]), d[e], d_des[e]) for e in out],
            [(yaw[EDGES[e, 0]] - yaw[i], tuple(beta[e]), tuple(des[e]), d[e], d_des[e])
             for e in inn],
            k_f, f_d,
        )  # fmt: skip
        grad = np.zeros(3)
        for m in range(3):
            dp = np.zeros((4, 3))
            dp[i, m] = 1e-6
            grad[m] = (cost(p + dp) - cost(p - dp)) / 2e-6
        u_world = rot_z(yaw[i]) @ (np.array(u_b) + np.array(u_d))
        assert np.allclose(u_world, -k_f * grad, atol=1e-5), (i, u_world, -k_f * grad)
        assert np.linalg.norm(u_d) > 1e-3  # the distance part is not vacuous


def test_the_distance_term_vanishes_at_the_desired_distance_and_is_bounded():
    b = (1.0, 0.0, 0.0)
    f_d = ReshapeD(w=0.25, delta=2.0)
    assert formation_distance_velocity([(b, b, 5.0, 5.0)], [], 0.5, f_d) == (0.0, 0.0, 0.0)
    far = formation_distance_velocity([(b, b, 1e4, 5.0)], [], 0.5, f_d)
    assert 0.0 < far[0] <= 0.5 * 0.25 * 2.0  # k_F w delta
    near = formation_distance_velocity([(b, b, 2.0, 5.0)], [], 0.5, f_d)
    assert near[0] < 0.0  # too close: away from the neighbour


def test_ramp_fraction_is_a_smoothstep():
    ramp = 3.0
    t = np.linspace(-1.0, 4.0, 501)
    s = np.array([ramp_fraction(x, ramp) for x in t])
    assert s[t <= 0].max() == 0.0 and s[t >= ramp].min() == 1.0
    assert np.all(np.diff(s) >= 0.0)
    assert ramp_fraction(1.5, ramp) == pytest.approx(0.5)
    h = 1e-4  # slope 0 at both ends, 1.5 / ramp in the middle
    assert ramp_fraction(h, ramp) / h < 1e-3
    assert (1.0 - ramp_fraction(ramp - h, ramp)) / h < 1e-3
    assert (ramp_fraction(1.5 + h, ramp) - ramp_fraction(1.5 - h, ramp)) / (2 * h) == (
        pytest.approx(1.5 / ramp)
    )
    assert ramp_fraction(0.0, 0.0) == 1.0  # no ramp: at once


def test_slerp_bearing_turns_along_the_great_circle():
    rng = np.random.default_rng(4)
    for _ in range(20):
        a, b = rng.normal(size=(2, 3))
        a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
        theta = math.acos(float(np.clip(a @ b, -1, 1)))
        for s in (0.0, 0.25, 0.5, 1.0):
            v = np.array(slerp_bearing(tuple(a), tuple(b), s))
            assert np.linalg.norm(v) == pytest.approx(1.0)
            assert math.acos(float(np.clip(v @ a, -1, 1))) == pytest.approx(s * theta, abs=1e-7)
            assert abs(np.linalg.det(np.stack([a, b, v]))) < 1e-9  # in the plane of a and b
    x = (1.0, 0.0, 0.0)
    assert slerp_bearing(x, (-1.0, 0.0, 0.0), 0.4) == x
    assert slerp_bearing(x, (-1.0, 0.0, 0.0), 0.6) == (-1.0, 0.0, 0.0)


# ------------------------------------------------------------------------- in the core
def _core(agent_id=0, **kw):
    beta, _ = bearings_body(P_OLD, YAW, TRIANGLE)
    desired = tuple(
        (i, j, tuple(float(x) for x in b)) for (i, j), b in zip(TRIANGLE, beta, strict=True)
    )
    cfg = build_config(
        agent_id=agent_id, n_agents=3, edges=TRIANGLE, mode="formation",
        p_hat0_ned=tuple(tuple(float(x) for x in r) for r in P_OLD),
        yaw_hat0_rad=tuple(float(y) for y in YAW), desired_beta_body=desired,
        desired_yaw_rad=tuple(float(y) for y in YAW), **kw,
    )  # fmt: skip
    return AgentCore(cfg)


def _own(t, p, i=0):
    others = [j for j in range(3) if j != i]
    b, _ = bearings_body(p, YAW, [(i, j) for j in others])
    return OwnMeasurements(
        t_s=t, yaw_rad=float(YAW[i]), v_body=(0.0, 0.0, 0.0), yaw_rate_rad_s=0.0,
        bearings=tuple(BearingMeasurement(j, tuple(b[k]), t) for k, j in enumerate(others)),
    )  # fmt: skip


def _peers(t, p):
    return [
        LocalizationState(sender=j, seq=int(t * 100), stamp_s=t,
                          p_hat_ned=tuple(float(x) for x in p[j]), yaw_hat_rad=float(YAW[j]))
        for j in (1, 2)
    ]  # fmt: skip


def _fly(core, p, t0, t1, dt=0.05, i=0):
    """Commands (NED) at the fixed positions ``p`` from ``t0`` to ``t1``."""
    out = []
    for k in range(round((t1 - t0) / dt) + 1):
        t = t0 + k * dt
        sp, _ = core.step(t, _own(t, p, i), _peers(t, p))
        out.append(rot_z(YAW[i]) @ np.array(sp.v_body))
    return np.array(out)


@pytest.mark.parametrize("distances", [False, True])
def test_a_doubled_formation_with_its_distances_pushes_the_vehicles_apart(distances):
    core = _core()
    _fly(core, P_OLD, 0.0, 0.5)
    centre = P_OLD.mean(axis=0)
    core.adopt_formation(2.0 * (P_OLD - centre) + centre, YAW, distances=distances, ramp_s=1.0)
    v = _fly(core, P_OLD, 0.55, 2.0)[-1]  # after the ramp
    status = core.status()
    assert status.formation_ramp == 1.0
    if not distances:  # same bearings: nothing to do, the size is free
        assert np.linalg.norm(v) < 1e-9 and status.distance_terms == 0
        return
    assert status.distance_terms == 2  # its two out-edges (no in-edge bearings here)
    away = (P_OLD[0] - centre) / np.linalg.norm(P_OLD[0] - centre)
    assert v @ away > 0.2  # outwards (each edge adds up to k_F w delta = 0.25 m/s)


def test_the_switch_ramps_the_desired_bearings_and_the_command_does_not_jump():
    p_new = np.array([[0.0, 0.0, -5.0], [6.0, 0.0, -5.0], [3.0, 2.0, -5.0]])  # isosceles
    old = dict(_core().controller.desired)
    steps = {}
    for ramp in (0.0, 2.0):
        core = _core()
        v0 = _fly(core, P_OLD, 0.0, 0.5)[-1:]  # still: at the old formation
        core.adopt_formation(p_new, YAW, ramp_s=ramp)
        v1 = _fly(core, P_OLD, 0.55, 1.55)  # the switch starts at the first step, 0.55 s
        if ramp:
            ctrl = core.controller
            mid, _, _ = ctrl.desired_now(1.55)  # half way: s = 1/2
            assert core.status().formation_ramp == pytest.approx(0.5)
            turns = []
            for e, b in ctrl.desired.items():
                total = math.acos(np.clip(np.dot(old[e], b), -1, 1))
                half = math.acos(np.clip(np.dot(old[e], mid[e]), -1, 1))
                assert half == pytest.approx(0.5 * total, abs=1e-7)
                turns.append(total)
            assert max(turns) > 0.3  # rad: the shape changes
        v = np.concatenate([v0, v1, _fly(core, P_OLD, 1.6, 3.0)])
        steps[ramp] = float(np.max(np.linalg.norm(np.diff(v, axis=0), axis=1)))
    # at once: one step of the full change; over 2 s: 0.05 s steps of a smoothstep
    print(f"largest command step: {steps[0.0]:.3f} m/s at once, {steps[2.0]:.4f} m/s ramped")
    assert steps[0.0] > 0.1
    assert steps[2.0] < 0.1 * steps[0.0]


def test_the_status_reports_the_switch_as_it_goes():
    core = _core()
    _fly(core, P_OLD, 0.0, 0.5)
    assert core.status().formation_ramp == 1.0
    core.adopt_formation(2.0 * P_OLD, YAW, distances=True, ramp_s=2.0)
    progress = []
    for t in (0.6, 1.1, 1.6, 2.1, 2.7):
        _fly(core, P_OLD, t, t)
        progress.append(core.status().formation_ramp)
    assert progress[0] == 0.0 and progress[-1] == 1.0
    assert progress == sorted(progress) and 0.0 < progress[2] < 1.0


def test_a_distance_ramp_starts_from_the_estimate():
    """Without distances before the change, d* starts at the distance the agent estimates, so
    the distance term starts at zero and grows with the ramp."""
    core = _core()
    _fly(core, P_OLD, 0.0, 0.5)
    core.adopt_formation(2.0 * P_OLD, YAW, distances=True, ramp_s=2.0)
    v = np.linalg.norm(_fly(core, P_OLD, 0.55, 2.6), axis=1)
    assert v[0] < 1e-6  # same bearings, d* = the estimate: nothing yet
    assert v[-1] > 0.2 and np.all(np.diff(v) >= -1e-9)
