"""Flight envelope: altitude band and horizontal fence (``onboard.control.envelope``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from onboard.control.envelope import bound_down_velocity, bound_horizontal_velocity


def test_inside_the_band_a_moderate_command_is_unchanged():
    assert bound_down_velocity(0.5, 10.0, 2.0, 50.0) == 0.5
    assert bound_down_velocity(-0.5, 10.0, 2.0, 50.0) == -0.5


def test_descent_slows_to_zero_at_the_floor_and_turns_into_a_climb_below_it():
    assert bound_down_velocity(2.0, 3.0, 2.0, 50.0) == pytest.approx(1.0)
    assert bound_down_velocity(2.0, 2.0, 2.0, 50.0) == 0.0
    assert bound_down_velocity(0.0, 1.5, 2.0, 50.0) == pytest.approx(-0.5)
    assert bound_down_velocity(-1.0, 1.5, 2.0, 50.0) == -1.0  # already climbing faster


def test_ceiling_mirrors_the_floor():
    assert bound_down_velocity(-2.0, 49.0, 2.0, 50.0) == pytest.approx(-1.0)
    assert bound_down_velocity(0.0, 51.0, 2.0, 50.0) == pytest.approx(1.0)


def test_flying_the_bound_never_crosses_the_floor():
    """Euler steps of h' = -v_down with a command that keeps pushing down."""
    h, dt = 6.0, 0.01
    for _ in range(2000):
        h -= dt * bound_down_velocity(3.0, h, 2.0, 50.0)
        assert h >= 2.0
    assert h == pytest.approx(2.0, abs=1e-6)


def test_bad_band_is_rejected():
    with pytest.raises(ValueError):
        bound_down_velocity(0.0, 5.0, 10.0, 5.0)
    with pytest.raises(ValueError):
        bound_down_velocity(0.0, 5.0, 1.0, 5.0, gain_1_s=0.0)


def test_inside_the_fence_only_the_outward_excess_is_removed():
    # 3 m north of the origin, fence 5 m: outward (north) speed at most 2 m/s
    assert bound_horizontal_velocity(1.0, 0.5, 3.0, 0.0, 5.0) == (1.0, 0.5)
    assert bound_horizontal_velocity(-4.0, 0.0, 3.0, 0.0, 5.0) == (-4.0, 0.0)  # inwards: free
    v_n, v_e = bound_horizontal_velocity(3.0, 1.5, 3.0, 0.0, 5.0)
    assert (v_n, v_e) == pytest.approx((2.0, 1.5))  # along the fence: untouched


def test_outside_the_fence_the_vehicle_is_pulled_back():
    v_n, v_e = bound_horizontal_velocity(0.0, 0.0, 0.0, -6.0, 5.0)
    assert (v_n, v_e) == pytest.approx((0.0, 1.0))  # 1 m out: 1 m/s inwards (east)
    assert bound_horizontal_velocity(1.0, 1.0, 0.0, 0.0, 5.0) == (1.0, 1.0)  # at the origin


def test_flying_the_fence_never_leaves_it():
    """Euler steps with a command that pushes outwards and sideways, from random starts."""
    rng = np.random.default_rng(7)
    dt = 0.01
    for _ in range(20):
        p = rng.uniform(-3.0, 3.0, 2)
        push = rng.normal(size=2) * 3.0
        for _ in range(1000):
            v = bound_horizontal_velocity(push[0], push[1], p[0], p[1], 4.0)
            p = p + dt * np.asarray(v)
            assert math.hypot(*p) <= 4.0 + 1e-9


def test_bad_fence_is_rejected():
    with pytest.raises(ValueError):
        bound_horizontal_velocity(0.0, 0.0, 1.0, 1.0, 0.0)
    with pytest.raises(ValueError):
        bound_horizontal_velocity(0.0, 0.0, 1.0, 1.0, 5.0, gain_1_s=-1.0)
