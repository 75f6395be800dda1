"""Altitude envelope (``onboard.control.envelope``)."""

from __future__ import annotations

import pytest

from onboard.control.envelope import bound_down_velocity


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
