"""ArduCopter flavour: identity, modes, GUIDED takeoff, velocity frames, GUIDED timeout, LAND,
and what it does like ArduCopter 4.7 SITL (streams on request, EKF warm-up, arming refusals,
the take-off's spool-up and climb, the landing, NaN parameters)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from messages import mavlink as mv
from sim.autopilot.common import Phase

GUIDED = mv.COPTER_MODES["GUIDED"]
LAND = mv.COPTER_MODES["LAND"]


def _guided_airborne(b, i=0, alt=5.0):
    b.run(max(0.0, b.aps[i].options.ekf_warmup_s - b.t + 0.01))  # the EKF has a position
    assert b.command(i, mv.CMD_DO_SET_MODE, 1, GUIDED) == mv.RESULT_ACCEPTED
    assert b.command(i, mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_ACCEPTED
    assert b.command(i, mv.CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt) == mv.RESULT_ACCEPTED
    b.run_until(lambda: b.aps[i].phase == Phase.AIR, 15.0)
    b.run(3.0)


def test_identity_and_modes(bench_factory):
    b = bench_factory("ardupilot", n=1, transport="tcp")
    b.run(1.05)
    hb = b.sent(0, "HEARTBEAT")[-1]
    assert hb.autopilot == mv.MAV_AUTOPILOT_ARDUPILOTMEGA and hb.type == mv.MAV_TYPE_QUADROTOR
    assert hb.custom_mode == 0  # STABILIZE
    assert hb.base_mode & mv.BASE_MODE_STABILIZE and not hb.base_mode & mv.BASE_MODE_GUIDED
    assert b.command(0, mv.CMD_DO_SET_MODE, 1, GUIDED) == mv.RESULT_ACCEPTED
    hb = b.sent(0, "HEARTBEAT")[-1]
    assert hb.custom_mode == GUIDED and hb.base_mode & mv.BASE_MODE_GUIDED
    assert b.command(0, mv.CMD_DO_SET_MODE, 0, GUIDED) == mv.RESULT_UNSUPPORTED  # no custom bit
    assert b.command(0, mv.CMD_DO_SET_MODE, 1, 99) == mv.RESULT_FAILED
    b.outbox[0].clear()
    b.deliver(0, b.dialect.MAVLink_set_mode_message(1, 1, mv.COPTER_MODES["LOITER"]))
    assert b.aps[0].mode == "LOITER"
    ack = b.sent(0, "COMMAND_ACK")[-1]
    assert ack.result == mv.RESULT_ACCEPTED and ack.command == 11


def test_takeoff_rules(bench_factory):
    b = bench_factory("ardupilot", n=1, ekf_warmup_s=0.0)
    b.run(0.1)
    assert b.command(0, mv.CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 5) == mv.RESULT_FAILED  # STABILIZE
    assert b.command(0, mv.CMD_DO_SET_MODE, 1, GUIDED) == mv.RESULT_ACCEPTED
    assert b.command(0, mv.CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 5) == mv.RESULT_FAILED  # disarmed
    assert b.command(0, mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_ACCEPTED
    assert b.command(0, mv.CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, -1) == mv.RESULT_FAILED  # below
    assert b.command(0, mv.CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 5) == mv.RESULT_ACCEPTED
    assert b.aps[0].mode == "GUIDED"
    b.run_until(lambda: b.aps[0].phase == Phase.AIR, 15.0)
    assert b.aps[0].mode == "GUIDED"
    b.run(3.0)
    assert b.aps[0].altitude_m == pytest.approx(5.0, abs=0.05)
    assert b.command(0, mv.CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 8) == mv.RESULT_FAILED  # flying
    assert b.texts(0) == []  # ArduCopter refuses take-offs without a word


@pytest.mark.parametrize("frame", [mv.FRAME_BODY_NED, mv.FRAME_BODY_OFFSET_NED])
def test_body_velocity_is_rotated_by_heading(bench_factory, frame):
    b = bench_factory("ardupilot", n=1)
    ap = b.aps[0]
    _guided_airborne(b)
    # turn to face east first (yaw rate 0.5 rad/s for pi/1 s)
    b.run(math.pi, every=0.05, action=lambda: b.setpoint(0, (0, 0, 0), yaw_rate=0.5, frame=frame))
    b.run(1.0, every=0.05, action=lambda: b.setpoint(0, (0, 0, 0), yaw_rate=0.0, frame=frame))
    yaw = float(b.server.world.yaw_rad[0])
    assert yaw == pytest.approx(math.pi / 2, abs=0.12)
    p0 = ap.p_ned.copy()
    b.run(4.0, every=0.05, action=lambda: b.setpoint(0, (1.0, 0, 0), frame=frame))
    d = ap.p_ned - p0
    heading = math.atan2(d[1], d[0])
    assert heading == pytest.approx(yaw, abs=0.02)
    assert np.linalg.norm(d[:2]) == pytest.approx(4.0 - 0.3, abs=0.15)


@pytest.mark.parametrize("frame", [mv.FRAME_LOCAL_NED, mv.FRAME_LOCAL_OFFSET_NED])
def test_ned_velocity_ignores_heading(bench_factory, frame):
    b = bench_factory("ardupilot", n=1)
    ap = b.aps[0]
    _guided_airborne(b)
    b.run(2.0, every=0.05, action=lambda: b.setpoint(0, (0, 0, 0), yaw_rate=0.5, frame=frame))
    p0 = ap.p_ned.copy()
    b.run(3.0, every=0.05, action=lambda: b.setpoint(0, (0.0, -1.0, 0), frame=frame))
    d = ap.p_ned - p0
    assert math.atan2(d[1], d[0]) == pytest.approx(-math.pi / 2, abs=0.02)


def test_guided_timeout_stops_and_stays_guided(bench_factory):
    b = bench_factory("ardupilot", n=1)
    ap = b.aps[0]
    _guided_airborne(b)
    last: dict[str, float] = {}

    def send() -> None:
        b.setpoint(0, (2.0, 0.0, 0.0))
        last["t"] = b.t

    b.run(2.0, every=0.1, action=send)
    took = b.run_until(lambda: not ap.velocity_active, 5.0)
    assert b.t - last["t"] == pytest.approx(3.0, abs=0.03)  # GUID_TIMEOUT
    assert took > 2.5
    assert ap.mode == "GUIDED"
    b.run(2.0)
    assert np.linalg.norm(b.server.world.v_ned[0]) < 0.01


def test_velocity_ignored_unless_guided_and_airborne(bench_factory):
    b = bench_factory("ardupilot", n=1)
    ap = b.aps[0]
    b.setpoint(0, (1.0, 0, 0))  # STABILIZE, on the ground
    assert ap.counters.ignored_setpoints == 1
    _guided_airborne(b)
    assert b.command(0, mv.CMD_DO_SET_MODE, 1, mv.COPTER_MODES["LOITER"]) == mv.RESULT_ACCEPTED
    p0 = ap.p_ned.copy()
    b.run(2.0, every=0.1, action=lambda: b.setpoint(0, (1.0, 0, 0)))
    assert ap.counters.ignored_setpoints == 21
    assert np.linalg.norm(ap.p_ned - p0) < 0.01


def test_land_and_disarm(bench_factory):
    b = bench_factory("ardupilot", n=1)
    ap = b.aps[0]
    _guided_airborne(b, alt=3.0)
    assert b.command(0, mv.CMD_NAV_LAND) == mv.RESULT_ACCEPTED
    assert ap.mode == "LAND"
    b.outbox[0].clear()
    descent = b.run_until(lambda: ap.phase == Phase.GROUND, 10.0)
    assert descent == pytest.approx(3.0 / 0.5 + 0.3, abs=0.2)  # LAND_SPEED 0.5 m/s, as SITL
    assert b.run_until(lambda: not ap.armed, 3.0) == pytest.approx(2.0, abs=0.05)
    assert "Disarming motors" in b.texts(0) and ap.mode == "LAND"
    assert b.command(0, mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_FAILED  # LAND not armable
    assert "Arm: Mode not armable" in b.texts(0)


def test_params_are_cast(bench_factory):
    b = bench_factory("ardupilot", n=2)
    b.deliver(1, b.dialect.MAVLink_param_request_read_message(2, 1, b"SYSID_THISMAV", -1))
    v = b.sent(1, "PARAM_VALUE")[0]
    assert v.param_value == 2.0 and v.param_type == 6
    b.outbox[1].clear()
    b.deliver(1, b.dialect.MAVLink_param_set_message(2, 1, b"GUID_TIMEOUT", 1.5, 9))
    assert b.sent(1, "PARAM_VALUE")[0].param_value == pytest.approx(1.5)
    b.outbox[1].clear()
    b.deliver(1, b.dialect.MAVLink_param_set_message(2, 1, b"DISARM_DELAY", 2.5, 6))  # not an int
    echo = b.sent(1, "PARAM_VALUE")[0]
    assert echo.param_value == 10.0  # unchanged value is echoed


def test_streams_nothing_until_asked_and_a_position_only_after_the_ekf_warmup(bench_factory):
    """ArduCopter 4.7 SITL: HEARTBEAT only until asked; the LOCAL_POSITION_NED request is
    accepted at once but the stream starts only once the EKF has a position."""
    b = bench_factory("ardupilot", n=1, ekf_warmup_s=3.0)
    b.run(1.0)
    assert {m.get_type() for m in b.outbox[0]} == {"HEARTBEAT"}
    for msg_id in (30, 32, 245):  # ATTITUDE, LOCAL_POSITION_NED, EXTENDED_SYS_STATE
        assert b.command(0, mv.CMD_SET_MESSAGE_INTERVAL, msg_id, 100_000) == mv.RESULT_ACCEPTED
    b.outbox[0].clear()
    b.run(1.0)
    assert 9 <= len(b.sent(0, "ATTITUDE")) <= 11 and len(b.sent(0, "EXTENDED_SYS_STATE")) >= 9
    assert b.sent(0, "LOCAL_POSITION_NED") == []
    assert b.command(0, mv.CMD_REQUEST_MESSAGE, 242) == mv.RESULT_ACCEPTED
    assert b.sent(0, "HOME_POSITION") == []  # no origin yet
    first = b.run_until(lambda: bool(b.sent(0, "LOCAL_POSITION_NED")), 3.0)
    assert b.t == pytest.approx(3.0, abs=0.11) and first > 0.9
    b.deliver(0, b.dialect.MAVLink_request_data_stream_message(1, 1, 2, 4, 1))  # EXTENDED_STATUS
    b.outbox[0].clear()
    b.run(1.0)
    assert 3 <= len(b.sent(0, "SYS_STATUS")) <= 5  # the group carries SYS_STATUS ...
    kept = bench_factory("ardupilot", n=1, boot_streams=True)  # the old behaviour, on request
    kept.run(1.05)
    assert len(kept.sent(0, "ATTITUDE")) >= 20


def test_any_mode_while_disarmed_refusals_at_arming(bench_factory):
    """ArduCopter accepts any mode disarmed and refuses at arming, with its own texts."""
    b = bench_factory("ardupilot", n=1, ekf_warmup_s=2.0)
    ap = b.aps[0]
    b.run(0.5)
    assert b.command(0, mv.CMD_DO_SET_MODE, 1, GUIDED) == mv.RESULT_ACCEPTED  # no position yet
    assert b.command(0, mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_FAILED
    assert b.texts(0) == ["Arm: Need Position Estimate"]
    assert b.command(0, mv.CMD_DO_SET_MODE, 1, mv.COPTER_MODES["STABILIZE"]) == 0
    assert b.command(0, mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_FAILED
    assert b.texts(0)[-1] == "Arm: EKF attitude is bad"
    b.deliver(0, b.dialect.MAVLink_command_long_message(1, 1, 511, 0, 1, 500_000, 0, 0, 0, 0, 0))
    b.outbox[0].clear()
    b.run(0.6)
    status = b.sent(0, "SYS_STATUS")[-1]
    assert not status.onboard_control_sensors_health & mv.SENSOR_PREARM_CHECK
    b.run(1.0)  # past the EKF warm-up
    assert b.sent(0, "SYS_STATUS")[-1].onboard_control_sensors_health & mv.SENSOR_PREARM_CHECK
    assert b.command(0, mv.CMD_DO_SET_MODE, 1, GUIDED) == mv.RESULT_ACCEPTED
    assert b.command(0, mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_ACCEPTED
    b.outbox[0].clear()
    assert b.run_until(lambda: not ap.armed, 11.0) == pytest.approx(10.0, abs=0.05)  # DISARM_DELAY
    assert b.texts(0) == ["Disarming motors"]


def test_takeoff_spools_up_then_climbs_like_sitl(bench_factory):
    """Measured on ArduCopter 4.7 SITL, 5 m take-off: lift-off (5 cm) 1.7 s after the command,
    1.46 m at 3.0 s, 3.19 m at 4.0 s, 4.37 m at 5.0 s, 5 m at 6.3-6.5 s; landed state
    ON_GROUND for 1.3 s, then TAKEOFF, IN_AIR at the target. Velocity targets are ignored
    until then."""
    b = bench_factory("ardupilot", n=1, ekf_warmup_s=0.0)
    ap = b.aps[0]
    b.run(0.1)
    assert b.command(0, mv.CMD_DO_SET_MODE, 1, GUIDED) == mv.RESULT_ACCEPTED
    assert b.command(0, mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_ACCEPTED
    assert b.command(0, mv.CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 5.0) == mv.RESULT_ACCEPTED
    t0 = b.t
    heights: dict[float, float] = {}
    states: dict[float, int] = {}
    moved: list[float] = []

    def sample() -> None:
        k = round(b.t - t0, 2)
        heights[k], states[k] = ap.altitude_m, ap.landed_state()
        if states[k] != mv.LANDED_IN_AIR:
            moved.append(abs(float(ap.p_ned[0])))
        b.setpoint(0, (2.0, 0.0, 0.0))  # ignored while the take-off climbs

    b.run(7.0, every=0.1, action=sample)
    lift_off = min(k for k, h in heights.items() if h > 0.05)
    assert lift_off == pytest.approx(1.7, abs=0.15)
    for k, sitl in ((3.0, 1.46), (4.0, 3.19), (5.0, 4.37)):
        assert heights[k] == pytest.approx(sitl, abs=0.35), (k, heights[k])
    reached = min(k for k, h in heights.items() if h > 4.85)
    assert 5.4 <= reached <= 6.2  # SITL: 5.75 s (IN_AIR at 6.1 s)
    assert states[1.0] == mv.LANDED_ON_GROUND and states[2.0] == mv.LANDED_TAKEOFF
    assert states[6.9] == mv.LANDED_IN_AIR and ap.mode == "GUIDED"
    assert max(moved) < 1e-9 and ap.counters.ignored_setpoints >= 50


def test_nan_parameters_that_crash_arducopter_are_refused_and_counted(bench_factory):
    """ArduCopter 4.7 SITL aborts (SIGFPE) on these NaN parameters; here they are refused."""
    b = bench_factory("ardupilot", n=1, ekf_warmup_s=0.0)
    ap = b.aps[0]
    b.run(0.1)
    nan = math.nan
    for command, params in (
        (mv.CMD_COMPONENT_ARM_DISARM, (1, nan)),  # what the GCS once sent (issue 22, bug 2)
        (mv.CMD_COMPONENT_ARM_DISARM, (nan,)),
        (mv.CMD_DO_SET_MODE, (1, nan)),
        (mv.CMD_SET_MESSAGE_INTERVAL, (30, nan)),
        (mv.CMD_REQUEST_MESSAGE, (nan,)),
    ):
        assert b.command(0, command, *params) == mv.RESULT_DENIED
        assert "NaN" in b.texts(0)[-1]
    assert ap.counters.nan_commands == 5 and not ap.armed and ap.mode == "STABILIZE"
    # NaN where ArduCopter does not crash keeps its own answer
    assert b.command(0, mv.CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, nan) == mv.RESULT_FAILED
    assert b.command(0, mv.CMD_NAV_LAND, 0, 0, 0, nan) == mv.RESULT_ACCEPTED
    assert ap.counters.nan_commands == 5
