"""ArduCopter flavour: identity, modes, GUIDED takeoff, velocity frames, GUIDED timeout, LAND."""

from __future__ import annotations

import math

import numpy as np
import pytest

from messages import mavlink as mv
from sim.autopilot.common import Phase

GUIDED = mv.COPTER_MODES["GUIDED"]
LAND = mv.COPTER_MODES["LAND"]


def _guided_airborne(b, i=0, alt=5.0):
    assert b.command(i, mv.CMD_DO_SET_MODE, 1, GUIDED) == mv.RESULT_ACCEPTED
    assert b.command(i, mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_ACCEPTED
    assert b.command(i, mv.CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt) == mv.RESULT_ACCEPTED
    b.run_until(lambda: b.aps[i].phase == Phase.AIR, 15.0)
    b.run(3.0)


def test_identity_and_modes(bench_factory):
    b = bench_factory("ardupilot", n=1, transport="tcp")
    b.run(1.05)
    assert len(b.sent(0, "ATTITUDE")) >= 20  # default streams (MAVSDK never requests them)
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
    b = bench_factory("ardupilot", n=1)
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
    b.run_until(lambda: ap.phase == Phase.GROUND, 10.0)
    assert b.run_until(lambda: not ap.armed, 3.0) == pytest.approx(1.0, abs=0.05)
    assert b.command(0, mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_FAILED  # LAND not armable
    assert any("not armable" in t for t in b.texts(0))


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
