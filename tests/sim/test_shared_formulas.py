"""One implementation of each formula: the pure functions the agent core calls as Python and
the compiled team engine calls compiled (sim.jit) give the same bits, and the classes that
delegate to them keep their behaviour."""

from __future__ import annotations

import math

import numpy as np

from onboard.control import active_scale, formation, random_motion
from onboard.estimation import angles, consensus, localization, relative_yaw, sfm_observer
from onboard.estimation.sfm_observer import WindowAverage, window_add
from sim import camera, world
from sim.jit import compiled

RNG = np.random.default_rng(7)


def _v3(scale: float = 1.0) -> tuple[float, float, float]:
    x = RNG.normal(size=3) * scale
    return (float(x[0]), float(x[1]), float(x[2]))


def _unit() -> tuple[float, float, float]:
    x = RNG.normal(size=3)
    x /= np.linalg.norm(x)
    return (float(x[0]), float(x[1]), float(x[2]))


def test_wrap_rad_is_math_remainder_bit_for_bit() -> None:
    turns = np.array([m * math.pi for m in range(-9, 10)])  # the ties and the branch ends
    edges = np.concatenate([turns, np.nextafter(turns, np.inf), np.nextafter(turns, -np.inf)])
    xs = np.concatenate(
        [RNG.uniform(-1, 1, 20000) * 10.0 ** RNG.uniform(-4, 7, 20000), RNG.uniform(-12, 12, 5000)]
    )
    fast = compiled(angles).wrap_rad
    for a in [*xs.tolist(), *edges.tolist(), 0.0, -0.0]:
        r = math.remainder(a, math.tau)
        assert angles.wrap_rad(a) == r and math.copysign(1.0, angles.wrap_rad(a)) == math.copysign(
            1.0, r
        ), a
        assert fast(a) == angles.wrap_rad(a)
    assert math.isnan(angles.wrap_rad(math.inf))  # no ValueError in the middle of a run


def test_compiled_formulas_equal_the_python_ones() -> None:
    loc, cons, ryaw = compiled(localization), compiled(consensus), compiled(relative_yaw)
    sfm, act, form, rand = (
        compiled(sfm_observer),
        compiled(active_scale),
        compiled(formation),
        compiled(random_motion),
    )
    wld, cam = compiled(world), compiled(camera)
    for _ in range(20):
        args = (_v3(3), 2.0, 0.002, _v3(), 0.3, _v3(), 0.1, _v3(50), 100.0, 1.0, 50.0, 10.0)
        assert loc.localization_euler_step(*args) == localization.localization_euler_step(*args)
        args = (0.3, -0.1, 0.5, 0.2, 20.0, 1.0)
        assert cons.pi_coupling_rates(*args) == consensus.pi_coupling_rates(*args)
        off = float(RNG.uniform(-4, 4))
        assert ryaw.filter_offset(0.6, 0.8, False, off, 0.2) == relative_yaw.filter_offset(
            0.6, 0.8, False, off, 0.2
        )
        b, bh, u = _unit(), _unit(), _v3()
        args = (bh, 0.4, b, u, 0.2, 0.002, 10.0, 10.0, 1e-3, 1.0)
        assert sfm.observer_step(*args) == sfm_observer.observer_step(*args)
        args = ((0.1, 0.2, 0.3), b, u, 0.2, 0.05, -5.0)
        assert act.lambda_bar_gradient_term(*args) == active_scale.lambda_bar_gradient_term(*args)
        assert form.formation_in_term((0.1, 0, 0), 0.7, b, bh) == formation.formation_in_term(
            (0.1, 0, 0), 0.7, b, bh
        )
        assert rand.ou_direction_step(u, b, 0.002, 1.0) == random_motion.ou_direction_step(
            u, b, 0.002, 1.0
        )
        args = (_v3(5), 0.4, _v3(), 0.1, _v3(), 0.2, 0.002, 0.3, 0.2)
        assert wld.kinematic_step(*args) == world.kinematic_step(*args)
        assert cam.noisy_bearing(b, u, 0.02) == camera.noisy_bearing(b, u, 0.02)


def test_camera_noise_is_the_former_vectorized_formula() -> None:
    beta = RNG.normal(size=(500, 3))
    beta /= np.linalg.norm(beta, axis=1, keepdims=True)
    z, sigma = RNG.standard_normal((500, 3)), 0.02
    n = z * sigma
    n -= np.sum(n * beta, axis=1, keepdims=True) * beta
    out = beta + n
    expected = out / np.linalg.norm(out, axis=1, keepdims=True)
    assert np.array_equal(camera.noisy_bearings(beta, z, sigma), expected)


def test_kinematic_step_flies_the_body_command_and_lags() -> None:
    p, yaw, v, vb, w = world.kinematic_step(
        (0.0, 0.0, 0.0), math.pi / 2, (0, 0, 0), 0.0, (1.0, 0.0, 0.0), 0.5, 0.1, 0.0, 0.0
    )
    assert np.allclose(v, (0.0, 1.0, 0.0)) and np.allclose(p, (0.0, 0.1, 0.0))
    assert yaw == math.pi / 2 + 0.05 and w == 0.5
    assert np.allclose(vb, (math.sin(yaw), math.cos(yaw), 0.0))
    _, _, v, _, w = world.kinematic_step(
        (0.0, 0.0, 0.0), 0.0, (0, 0, 0), 0.0, (1.0, 0.0, 0.0), 1.0, 0.1, 0.25, 0.5
    )
    assert v == (0.25, 0.0, 0.0) and w == 0.5


def test_window_average_grows_its_ring_and_matches_the_direct_sum() -> None:
    w = WindowAverage(window_s=1.0)
    samples = []
    t = 0.0
    for k in range(3000):  # 2 ms steps, then 5 ms: 500 samples in the window, past the 64 slots
        dt = 0.002 if k < 1500 else 0.005
        t += dt
        y = float(RNG.uniform(0, 1))
        samples.append((t, y * dt))
        avg = w.add(t, y, dt)
        if k % 50 == 0 or k > 2990:
            direct = sum(v for s, v in samples if s > t - 1.0)
            assert math.isclose(avg, direct, rel_tol=1e-9, abs_tol=1e-12)


def test_a_full_window_ring_forgets_its_oldest_sample() -> None:
    times, values = [0.0] * 3, [0.0] * 3
    state = (0, 0, 0.0)
    for k in range(1, 5):
        *state, _ = window_add(times, values, *state, float(k), 1.0, 1.0, 100.0)
    start, count, integral = state
    assert (start, count, integral) == (1, 3, 3.0)
    assert sorted(times) == [2.0, 3.0, 4.0]
