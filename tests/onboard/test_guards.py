"""Each safety rule of the onboard daemon as a guard (:mod:`onboard.daemon.guards`): pure logic
over a :class:`GuardInput`, one test (at least) per guard, and the fold of their verdicts."""

from __future__ import annotations

import dataclasses
import math

import pytest

from messages.agent import Setpoint
from messages.vocabulary import Alarm
from onboard.daemon.guards import (
    Action,
    AltitudeBandGuard,
    ClockFaultGuard,
    ClockSkewGuard,
    EstimateHealthGuard,
    FenceGuard,
    FiniteSetpointGuard,
    GuardInput,
    LostPeersGuard,
    PilotTakeoverGuard,
    RigidityGuard,
    StaleInputsGuard,
    StepErrorGuard,
    daemon_guards,
    decide,
)

HEALTHY = GuardInput()


def _with(**kw) -> GuardInput:
    return dataclasses.replace(HEALTHY, **kw)


def test_lost_peers_raise_one_alarm_each_and_do_not_hold():
    g = LostPeersGuard()
    assert g.check(HEALTHY).action is Action.PASS and g.check(HEALTHY).alarms == ()
    v = g.check(_with(lost_peers=(1, 3)))
    assert v.action is Action.PASS
    assert v.alarms == ("peer_lost:1", "peer_lost:3")


def test_rigidity_guard_holds_only_when_the_rest_is_not_rigid():
    asked: list[frozenset[int]] = []

    def rigid_without(lost: frozenset[int]) -> bool:
        asked.append(lost)
        return lost == frozenset({1})  # losing 1 leaves a rigid framework, losing 2 does not

    g = RigidityGuard(rigid_without)
    assert g.check(HEALTHY).action is Action.PASS and asked == []  # nothing lost: not asked
    assert g.check(_with(lost_peers=(1,))).action is Action.PASS
    v = g.check(_with(lost_peers=(1, 2)))
    assert v.action is Action.HOLD and v.alarms == (Alarm.RIGIDITY_LOST,)
    assert asked == [frozenset({1}), frozenset({1, 2})]


def test_clock_skew_holds_and_names_the_peers():
    g = ClockSkewGuard()
    assert g.check(HEALTHY).action is Action.PASS
    v = g.check(_with(skewed_peers=(2,)))
    assert v.action is Action.HOLD and v.alarms == ("peer_clock:2",)


@pytest.mark.parametrize(
    ("kw", "alarms"),
    [
        ({"autopilot_stale": True}, ("autopilot_stale",)),
        ({"bearings_age_s": 0.31}, ("bearings_stale",)),
        ({"bearings_age_s": math.inf}, ("bearings_stale",)),
        ({"autopilot_stale": True, "bearings_age_s": 1.0}, ("autopilot_stale", "bearings_stale")),
    ],
)
def test_stale_inputs_hold(kw, alarms):
    v = StaleInputsGuard(stale_s=0.3).check(_with(**kw))
    assert v.action is Action.HOLD and v.alarms == alarms


def test_fresh_inputs_pass_at_the_limit():
    assert StaleInputsGuard(stale_s=0.3).check(_with(bearings_age_s=0.3)).action is Action.PASS


def test_step_error_holds_for_its_window_only():
    g = StepErrorGuard(window_s=1.0)
    assert g.check(_with(step_error_age_s=0.2)).action is Action.HOLD
    assert g.check(_with(step_error_age_s=1.0)).alarms == ("step_error",)
    assert g.check(_with(step_error_age_s=1.01)).action is Action.PASS
    assert g.check(HEALTHY).action is Action.PASS  # never failed


def test_clock_fault_is_an_alarm_not_a_hold():
    v = ClockFaultGuard().check(_with(clock_fault=Alarm.CLOCK_JUMP))
    assert v.action is Action.PASS and v.alarms == ("clock_jump",)
    assert ClockFaultGuard().check(HEALTHY).alarms == ()


def test_takeover_alarm_names_who_has_the_vehicle():
    g = PilotTakeoverGuard()
    assert g.check(_with(phase="pilot")).alarms == ("pilot_takeover",)
    assert g.check(_with(phase="failsafe")).alarms == ("failsafe",)
    assert g.check(_with(phase="flying")).alarms == ()
    assert g.check(_with(phase="pilot")).action is Action.PASS  # nothing is streamed anyway


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_a_non_finite_setpoint_holds(bad):
    g = FiniteSetpointGuard()
    assert g.check(_with(setpoint=Setpoint((0.1, bad, 0.0), 0.0))).action is Action.HOLD
    v = g.check(_with(setpoint=Setpoint((0.1, 0.0, 0.0), bad)))
    assert v.action is Action.HOLD and v.alarms == ("estimate_diverging",)
    assert g.check(_with(setpoint=Setpoint((0.1, 0.2, 0.3), 0.4))).action is Action.PASS


def test_altitude_band_bounds_the_down_velocity_at_floor_and_ceiling():
    g = AltitudeBandGuard(min_alt_m=2.0, max_alt_m=10.0)
    low = g.check(_with(altitude_m=1.0, setpoint=Setpoint((0.5, 0.0, 0.5), 0.1)))  # sinking
    assert low.action is Action.CLAMP and low.alarms == ("altitude_floor",)
    assert low.setpoint is not None and low.setpoint.v_body[2] < 0.0  # climbs back
    assert low.setpoint.v_body[:2] == (0.5, 0.0) and low.setpoint.yaw_rate_rad_s == 0.1
    high = g.check(_with(altitude_m=11.0, setpoint=Setpoint((0.0, 0.0, -0.5), 0.0)))
    assert high.alarms == ("altitude_ceiling",)
    assert high.setpoint is not None and high.setpoint.v_body[2] > 0.0
    inside = g.check(_with(altitude_m=5.0, setpoint=Setpoint((0.0, 0.0, 0.5), 0.0)))
    assert inside.action is Action.PASS


def test_fence_bounds_the_outward_velocity_in_the_heading_frame():
    g = FenceGuard(max_radius_m=5.0)
    # at 6 m north, heading east (yaw 90 deg): body -y is north, i.e. outwards
    out = _with(north_m=6.0, yaw_rad=math.pi / 2, setpoint=Setpoint((0.0, -1.0, 0.2), 0.0))
    v = g.check(out)
    assert v.action is Action.CLAMP and v.alarms == ("fence",)
    assert v.setpoint is not None
    v_north = -v.setpoint.v_body[1]  # heading east: north = -y_body
    assert v_north < 1.0 - 1e-9  # the outward component shrank
    assert v.setpoint.v_body[2] == 0.2  # the vertical is not the fence's
    inward = _with(north_m=6.0, yaw_rad=math.pi / 2, setpoint=Setpoint((0.0, 2.0, 0.0), 0.0))
    assert g.check(inward).action is Action.PASS
    assert g.check(_with(setpoint=Setpoint((1.0, 0.0, 0.0), 0.0))).action is Action.PASS


def _guards(rigid=True):
    return daemon_guards(lambda lost: rigid, 0.3, 1.0, 2.0, 10.0, 5.0)


def test_decide_holds_on_any_check_and_skips_the_envelope_then():
    inp = _with(altitude_m=1.0, setpoint=Setpoint((0.3, 0.0, 0.5), 0.0), autopilot_stale=True)
    d = decide(_guards(), inp)
    assert d.hold and d.setpoint == Setpoint((0.0, 0.0, 0.0), 0.0)
    assert d.alarms == ("autopilot_stale",)  # no altitude_floor: nothing is flown


def test_decide_lists_alarms_in_the_daemons_order():
    inp = _with(
        lost_peers=(2,),
        skewed_peers=(1,),
        clock_fault=Alarm.CLOCK_RESYNC,
        setpoint=Setpoint((math.nan, 0.0, 0.0), 0.0),
    )
    d = decide(_guards(rigid=False), inp)
    assert d.hold
    assert d.alarms == (
        "peer_lost:2",
        "rigidity_lost",
        "peer_clock:1",
        "clock_resync",
        "estimate_diverging",
    )


def test_decide_applies_both_bounds_when_flying_only():
    inp = _with(altitude_m=1.0, north_m=6.0, yaw_rad=0.0, setpoint=Setpoint((1.0, 0.0, 0.5), 0.2))
    d = decide(_guards(), inp)
    assert not d.hold and d.alarms == ("altitude_floor", "fence")
    assert d.setpoint.v_body[0] < 1.0 and d.setpoint.v_body[2] < 0.0
    assert d.setpoint.yaw_rate_rad_s == 0.2
    holding = decide(_guards(), dataclasses.replace(inp, phase="holding"))
    assert holding.alarms == () and holding.setpoint == inp.setpoint


def test_estimate_health_holds_on_nonfinite_estimates_and_implausible_telemetry():
    """Issue 23 defect 8: corrupted autopilot telemetry or NaN estimates hold with an alarm."""
    g = EstimateHealthGuard(window_s=1.0)
    assert g.check(HEALTHY).action is Action.PASS
    v = g.check(_with(estimate_healthy=False))
    assert v.action is Action.HOLD and v.alarms == ("estimate_nonfinite",)
    v = g.check(_with(implausible_telemetry_age_s=0.4))
    assert v.action is Action.HOLD and v.alarms == ("telemetry_implausible",)
    assert g.check(_with(implausible_telemetry_age_s=1.5)).action is Action.PASS
    d = decide(_guards(), _with(implausible_telemetry_age_s=0.1, setpoint=Setpoint((2, 0, 0), 0)))
    assert d.hold and d.setpoint.v_body == (0.0, 0.0, 0.0)
