"""Pure logic of the autopilot link: modes, frames, saturation, retries, the telemetry fold."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as dialect

from messages import mavlink as mv
from onboard.autopilot.base import Flavour, LinkConfig, LinkCounters, StreamState
from onboard.autopilot.states import (
    DATA_STREAM_GROUP,
    Attempt,
    TelemetryState,
    backoff_s,
    body_velocity,
    climb_done,
    flavour_from_autopilot,
    is_autopilot_heartbeat,
    mode_command_params,
    mode_name,
    retry_loop,
    retryable,
    saturate_setpoint,
    snapshot,
    stream_groups,
)


# --- flavours and modes ---------------------------------------------------------------------------
def test_flavour_and_autopilot_heartbeats():
    assert flavour_from_autopilot(12) is Flavour.PX4
    assert flavour_from_autopilot(3) is Flavour.ARDUPILOT
    assert flavour_from_autopilot(0) is None
    assert is_autopilot_heartbeat(2, 12)
    assert not is_autopilot_heartbeat(6, 8)  # a ground station
    assert not is_autopilot_heartbeat(18, 8)  # a companion computer
    assert not is_autopilot_heartbeat(2, 8)  # autopilot INVALID


@pytest.mark.parametrize("name", sorted(mv.PX4_MODES))
def test_px4_mode_command_round_trips_through_the_heartbeat(name):
    p1, main, sub = mode_command_params(Flavour.PX4, name)
    assert int(p1) & mv.BASE_MODE_CUSTOM
    custom = mv.px4_custom_mode(int(main), int(sub))
    assert mode_name(Flavour.PX4, mv.BASE_MODE_CUSTOM, custom) == name


@pytest.mark.parametrize("name", sorted(mv.COPTER_MODES))
def test_copter_mode_command_round_trips_through_the_heartbeat(name):
    p1, number, _ = mode_command_params(Flavour.ARDUPILOT, name)
    assert int(p1) & mv.BASE_MODE_CUSTOM
    assert mode_name(Flavour.ARDUPILOT, mv.BASE_MODE_CUSTOM | 16, int(number)) == name


def test_unknown_modes():
    with pytest.raises(ValueError, match="unknown PX4 mode"):
        mode_command_params(Flavour.PX4, "GUIDED")
    with pytest.raises(ValueError, match="unknown ArduCopter mode"):
        mode_command_params(Flavour.ARDUPILOT, "OFFBOARD")
    assert mode_name(Flavour.ARDUPILOT, mv.BASE_MODE_CUSTOM, 99) == "UNKNOWN(99)"
    assert mode_name(Flavour.PX4, mv.BASE_MODE_CUSTOM, mv.px4_custom_mode(9)) == "UNKNOWN(9,0)"
    assert mode_name(Flavour.PX4, 0, 0).startswith("UNKNOWN")


# --- frames --------------------------------------------------------------------------------------
def test_body_velocity_undoes_the_heading_rotation():
    rng = np.random.default_rng(3)
    yaw = rng.uniform(-math.pi, math.pi, 50)
    v_body = rng.normal(size=(50, 3))
    c, s = np.cos(yaw), np.sin(yaw)
    v_ned = np.stack([c * v_body[:, 0] - s * v_body[:, 1], s * v_body[:, 0] + c * v_body[:, 1]], 1)
    v_ned = np.column_stack([v_ned, v_body[:, 2]])
    np.testing.assert_allclose(body_velocity(v_ned, yaw), v_body, atol=1e-12)


def test_body_velocity_facing_east_moving_east_is_forward():
    np.testing.assert_allclose(
        body_velocity(np.array([0.0, 2.0, 0.5]), math.pi / 2), [2, 0, 0.5], atol=1e-12
    )


# --- safety --------------------------------------------------------------------------------------
def test_saturation_keeps_small_setpoints():
    s = saturate_setpoint((0.3, -0.4, 0.2), 0.1, 2.0, 1.0, 0.8)
    assert s.v_body == pytest.approx((0.3, -0.4, 0.2))
    assert s.yaw_rate_rad_s == pytest.approx(0.1)
    assert not s.clipped and not s.non_finite


def test_saturation_clips_horizontal_norm_keeping_direction():
    s = saturate_setpoint((3.0, 4.0, -5.0), -2.0, 2.0, 1.0, 0.8)
    assert math.hypot(s.v_body[0], s.v_body[1]) == pytest.approx(2.0)
    assert s.v_body[0] / s.v_body[1] == pytest.approx(3.0 / 4.0)
    assert s.v_body[2] == pytest.approx(-1.0)
    assert s.yaw_rate_rad_s == pytest.approx(-0.8)
    assert s.clipped


@pytest.mark.parametrize(
    "v, r",
    [((math.nan, 0.0, 0.0), 0.0), ((0.5, 0.0, math.inf), 0.0), ((0.5, 0.0, 0.0), math.nan),
     ((1.0, 2.0), 0.0), ("fast", 0.0), (None, 0.1)],
)  # fmt: skip
def test_non_finite_or_malformed_setpoint_means_stop(v, r):
    s = saturate_setpoint(v, r, 2.0, 1.0, 0.8)
    assert s.non_finite
    assert s.v_body == (0.0, 0.0, 0.0) and s.yaw_rate_rad_s == 0.0


# --- retries -------------------------------------------------------------------------------------
def test_backoff_doubles_then_caps():
    assert [backoff_s(k, 0.5, 4.0) for k in range(6)] == [0.5, 1.0, 2.0, 4.0, 4.0, 4.0]


def test_retryable_results():
    assert retryable(None)  # timeout
    assert retryable(mv.RESULT_TEMPORARILY_REJECTED)
    assert retryable(mv.RESULT_DENIED) and retryable(mv.RESULT_FAILED)
    assert not retryable(mv.RESULT_UNSUPPORTED)
    assert not retryable(mv.RESULT_ACCEPTED)


class FakeTime:
    def __init__(self) -> None:
        self.t = 100.0
        self.waits: list[float] = []

    def clock(self) -> float:
        return self.t

    def wait(self, dt: float) -> bool:
        self.waits.append(dt)
        self.t += dt
        return False


def test_retry_loop_retries_refusals_with_backoff_until_success():
    ft = FakeTime()
    outcomes = iter([mv.RESULT_DENIED, mv.RESULT_TEMPORARILY_REJECTED, mv.RESULT_ACCEPTED])

    def attempt() -> Attempt:
        r = next(outcomes)
        return Attempt(r == mv.RESULT_ACCEPTED, r, 2, retry=retryable(r))

    a, sends, why = retry_loop(attempt, ft.clock, ft.wait, 30.0, 0.5, 4.0)
    assert a.ok and a.result == mv.RESULT_ACCEPTED
    assert sends == 6 and why == ""
    assert ft.waits == [0.5, 1.0]


def test_retry_loop_stops_on_a_final_refusal():
    ft = FakeTime()
    a, sends, why = retry_loop(
        lambda: Attempt(False, mv.RESULT_UNSUPPORTED, 1, retry=False), ft.clock, ft.wait, 30, 0.5, 4
    )
    assert not a.ok and sends == 1 and why == "" and ft.waits == []


def test_retry_loop_gives_up_at_the_deadline():
    ft = FakeTime()
    a, sends, why = retry_loop(
        lambda: Attempt(False, None, 1, retry=True), ft.clock, ft.wait, 5.0, 0.5, 4.0
    )
    assert not a.ok and why == "gave up retrying"
    assert sum(ft.waits) <= 5.0
    assert ft.waits == [0.5, 1.0, 2.0]  # the next one (4 s) would end after the deadline
    assert sends == 4


def test_retry_loop_ends_when_closed():
    calls = []
    a, sends, why = retry_loop(
        lambda: calls.append(1) or Attempt(False, None, 1, retry=True),
        lambda: 0.0,
        lambda _dt: True,
        30.0,
        0.5,
        4.0,
    )
    assert why == "link closed" and len(calls) == 1 and sends == 1 and not a.ok


# --- telemetry fold ------------------------------------------------------------------------------
def heartbeat(custom_mode: int, armed: bool = False, autopilot: int = 12):
    base = mv.BASE_MODE_CUSTOM | (mv.BASE_MODE_ARMED if armed else 0)
    return dialect.MAVLink_heartbeat_message(2, autopilot, base, custom_mode, 3, 3)


def test_fold_heartbeat_attitude_position():
    st = TelemetryState(flavour=Flavour.PX4)
    assert st.apply(heartbeat(mv.px4_custom_mode(6), armed=True), 1.0)
    assert st.mode == "OFFBOARD" and st.armed and st.t_heartbeat_s == 1.0
    assert st.apply(dialect.MAVLink_attitude_message(2500, 0.1, -0.2, math.pi / 2, 0, 0, 0.3), 1.1)
    assert (st.roll_rad, st.pitch_rad, st.yaw_rate_rad_s) == pytest.approx((0.1, -0.2, 0.3))
    assert st.t_boot_s == pytest.approx(2.5)
    assert st.apply(
        dialect.MAVLink_local_position_ned_message(2600, 1, 2, -3.0, 0.0, 1.5, -0.2), 1.2
    )
    assert st.altitude_m == pytest.approx(3.0)
    assert st.v_body() == pytest.approx((1.5, 0.0, -0.2), abs=1e-6)


def test_fold_drops_non_finite_messages_unchanged():
    st = TelemetryState(flavour=Flavour.PX4)
    st.apply(dialect.MAVLink_attitude_message(1000, 0.0, 0.0, 0.5, 0, 0, 0.0), 1.0)
    assert not st.apply(dialect.MAVLink_attitude_message(1100, math.nan, 0.0, 0.7, 0, 0, 0), 2.0)
    assert st.yaw_rad == pytest.approx(0.5) and st.t_attitude_s == 1.0
    assert not st.apply(dialect.MAVLink_local_position_ned_message(1, 0, 0, 0, math.inf, 0, 0), 2.0)
    assert st.t_velocity_s == -math.inf


def test_fold_sys_status_prearm_bit_and_battery():
    st = TelemetryState(flavour=Flavour.ARDUPILOT)
    present = mv.SENSOR_GYRO | mv.SENSOR_PREARM_CHECK

    def sys_status(health: int):
        return dialect.MAVLink_sys_status_message(
            present, present, health, 200, 15800, 100, 87, 0, 0, 0, 0, 0, 0
        )

    st.apply(sys_status(mv.SENSOR_GYRO), 1.0)
    assert st.sys_status_seen and not st.ready
    assert st.battery_remaining_pct == 87 and st.battery_voltage_v == pytest.approx(15.8)
    st.apply(sys_status(mv.SENSOR_GYRO | mv.SENSOR_PREARM_CHECK), 2.0)
    assert st.ready


def test_fold_statustext_and_landed_state():
    st = TelemetryState(flavour=Flavour.ARDUPILOT)
    st.apply(dialect.MAVLink_statustext_message(2, b"PreArm: EKF3 still initialising"), 5.0)
    st.apply(dialect.MAVLink_statustext_message(6, b"later"), 7.0)
    assert st.texts_since(5.0) == ("PreArm: EKF3 still initialising", "later")
    assert st.texts_since(6.0) == ("later",)
    st.apply(dialect.MAVLink_extended_sys_state_message(0, mv.LANDED_TAKEOFF), 7.0)
    assert st.landed_state == mv.LANDED_TAKEOFF


def test_snapshot_ages_and_stale_flags():
    cfg = LinkConfig(stale_after_s=0.5, heartbeat_timeout_s=3.0)
    st = TelemetryState(flavour=Flavour.PX4)
    st.apply(heartbeat(mv.px4_custom_mode(4, 3)), 10.0)
    st.apply(dialect.MAVLink_attitude_message(0, 0, 0, 0, 0, 0, 0), 10.0)
    zero = saturate_setpoint((0, 0, 0), 0, 1, 1, 1)
    t = snapshot(st, 10.4, cfg, 1, StreamState.IDLE, zero, LinkCounters())
    assert t.connected and t.mode == "AUTO.LOITER"
    assert t.heartbeat_age_s == pytest.approx(0.4)
    assert not t.stale_attitude and t.stale_velocity  # never received
    assert t.stale
    t = snapshot(st, 13.5, cfg, 1, StreamState.IDLE, zero, LinkCounters())
    assert t.stale_heartbeat and t.stale_attitude and not t.connected


def test_link_config_rejects_nonsense():
    with pytest.raises(ValueError, match="rate_hz"):
        LinkConfig(rate_hz=0.0)
    with pytest.raises(ValueError, match="max_yaw_rate_rad_s"):
        LinkConfig(max_yaw_rate_rad_s=math.nan)
    with pytest.raises(ValueError, match="command_sends"):
        LinkConfig(command_sends=0)


def test_climb_done_needs_in_air_and_the_altitude():
    st = TelemetryState(flavour=Flavour.ARDUPILOT, landed_state=mv.LANDED_TAKEOFF, altitude_m=3.0)
    assert not climb_done(st, 3.0)  # still "taking off": ArduCopter ignores velocity targets
    st.landed_state = mv.LANDED_IN_AIR
    assert climb_done(st, 3.0)
    st.altitude_m = 2.6
    assert not climb_done(st, 3.0)
    assert climb_done(st, 2.75)


def test_stream_group_fallback_never_asks_for_every_stream():
    """Issue 22, bug 6: EXTENDED_SYS_STATE was listed in EXTENDED_STATUS (2), which carries it on
    no ArduCopter; a message without a group fell back to group 0, MAV_DATA_STREAM_ALL."""
    rates = {"SYS_STATUS": 2.0, "GPS_RAW_INT": 5.0, "EXTENDED_SYS_STATE": 2.0, "ATTITUDE": 20.4}
    groups, ungrouped = stream_groups(list(rates), rates)
    assert groups == {2: 5, 10: 20}
    assert ungrouped == ["EXTENDED_SYS_STATE"]
    assert "EXTENDED_SYS_STATE" not in DATA_STREAM_GROUP
    assert stream_groups(["BATTERY_STATUS"], {"BATTERY_STATUS": 0.5}) == ({12: 1}, [])


@pytest.mark.parametrize(
    "msg",
    [
        dialect.MAVLink_local_position_ned_message(1100, 0, 0, -1e6, 0, 0, 0),  # 1000 km up
        dialect.MAVLink_local_position_ned_message(1100, 0, 0, -5.0, 1e4, 0, 0),  # 10 km/s
        dialect.MAVLink_local_position_ned_message(1100, 2e5, 0, -5.0, 0, 0, 0),
        dialect.MAVLink_attitude_message(1100, 0.0, 0.0, 0.5, 0, 0, 100.0),  # 100 rad/s yaw rate
        dialect.MAVLink_attitude_message(1100, 0.0, 40.0, 0.5, 0, 0, 0.0),
    ],
)
def test_fold_drops_implausible_telemetry_unchanged_and_remembers_when(msg):
    """Issue 23 defect 8: finite but impossible telemetry once passed and kept the daemon's
    estimates 100-150 % off."""
    st = TelemetryState(flavour=Flavour.PX4)
    assert st.apply(dialect.MAVLink_attitude_message(1000, 0.0, 0.0, 0.5, 0, 0, 0.2), 1.0)
    assert st.apply(dialect.MAVLink_local_position_ned_message(1000, 1, 2, -5.0, 0.5, 0, 0), 1.0)
    before = (st.altitude_m, st.north_m, st.v_ned, st.yaw_rate_rad_s, st.pitch_rad, st.t_boot_s)
    assert not st.apply(msg, 2.0)
    after = (st.altitude_m, st.north_m, st.v_ned, st.yaw_rate_rad_s, st.pitch_rad, st.t_boot_s)
    assert after == before
    assert st.implausible == 1 and st.t_implausible_s == 2.0
    zero = saturate_setpoint((0, 0, 0), 0, 1, 1, 1)
    tel = snapshot(st, 2.5, LinkConfig(), 1, StreamState.IDLE, zero, LinkCounters())
    assert tel.implausible == 1 and tel.implausible_age_s == pytest.approx(0.5)
    # the edge of the ranges still passes: 100 m/s, 20 rad/s
    assert st.apply(dialect.MAVLink_local_position_ned_message(1200, 0, 0, -5.0, 100.0, 0, 0), 3.0)
    assert st.apply(dialect.MAVLink_attitude_message(1200, 0.0, 0.0, 0.5, 0, 0, -20.0), 3.0)
