"""--strict: an autopilot fresh from boot, as real ones are."""

from __future__ import annotations

import math

import pytest

from messages import mavlink as mv
from sim.autopilot.common import Phase

NAN = math.nan


def test_px4_refuses_until_warmup_then_reverts_boot_mode(bench_factory):
    b = bench_factory("px4", n=1, strict=True, warmup_s=2.0)
    ap = b.aps[0]
    b.run(0.6)
    health = b.sent(0, "SYS_STATUS")[-1].onboard_control_sensors_health
    assert not health & mv.SENSOR_PREARM_CHECK
    assert b.sent(0, "GPS_RAW_INT")[-1].fix_type < 3
    assert b.command(0, mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_DENIED
    assert any("Arming denied" in t for t in b.texts(0))
    b.setpoint(0, (0.0, 0.0, 0.0))
    assert (
        b.command(0, mv.CMD_DO_SET_MODE, 1, mv.PX4_MAIN_OFFBOARD, 0)
        == mv.RESULT_TEMPORARILY_REJECTED
    )
    assert b.command(0, mv.CMD_NAV_TAKEOFF, *([NAN] * 7)) == mv.RESULT_TEMPORARILY_REJECTED
    assert b.command(0, mv.CMD_DO_SET_MODE, 1, mv.PX4_MAIN_ALTCTL, 0) == mv.RESULT_ACCEPTED
    assert ap.mode == "ALTCTL"
    b.run_until(lambda: ap.booted, 3.0)
    assert b.t == pytest.approx(2.0, abs=0.011)
    assert ap.mode == "AUTO.LOITER"  # reverted at the end of boot
    assert any("reverted" in t for t in b.texts(0))
    b.run(0.6)
    assert b.sent(0, "SYS_STATUS")[-1].onboard_control_sensors_health & mv.SENSOR_PREARM_CHECK
    assert b.command(0, mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_ACCEPTED


def test_autodisarm_when_armed_but_not_flown(bench_factory):
    b = bench_factory("px4", n=1, strict=True, warmup_s=0.1)
    ap = b.aps[0]
    b.run(0.2)
    assert b.command(0, mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_ACCEPTED
    took = b.run_until(lambda: not ap.armed, 15.0)
    assert took == pytest.approx(10.0, abs=0.02)  # COM_DISARM_PRFLT
    assert any("auto preflight disarming" in t for t in b.texts(0))
    # not in non-strict mode
    b2 = bench_factory("px4", n=1)
    assert b2.command(0, mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_ACCEPTED
    b2.run(12.0)
    assert b2.aps[0].armed


def test_ardupilot_streams_only_on_request(bench_factory):
    b = bench_factory("ardupilot", n=1, strict=True, warmup_s=0.5)
    b.run(2.0)
    kinds = {m.get_type() for m in b.outbox[0]}
    assert "HEARTBEAT" in kinds and "ATTITUDE" not in kinds and "SYS_STATUS" not in kinds
    assert b.command(0, mv.CMD_SET_MESSAGE_INTERVAL, 30, 100_000) == mv.RESULT_ACCEPTED
    b.deliver(0, b.dialect.MAVLink_request_data_stream_message(1, 1, 6, 4, 1))  # POSITION at 4 Hz
    b.outbox[0].clear()
    b.run(1.0)
    assert 9 <= len(b.sent(0, "ATTITUDE")) <= 11
    assert 3 <= len(b.sent(0, "GLOBAL_POSITION_INT")) <= 5
    assert b.sent(0, "SYS_STATUS") == []
    b.deliver(0, b.dialect.MAVLink_request_data_stream_message(1, 1, 6, 4, 0))  # stop
    b.outbox[0].clear()
    b.run(1.0)
    assert b.sent(0, "GLOBAL_POSITION_INT") == []


def test_ardupilot_boot_refusals_and_revert(bench_factory):
    """ArduCopter 4.7 SITL: a mode set before "ArduPilot Ready" is accepted, then reverted to
    STABILIZE when the init ends; arming is refused until the EKF has a position."""
    b = bench_factory("ardupilot", n=1, strict=True, warmup_s=1.0, ekf_warmup_s=2.0)
    ap = b.aps[0]
    assert b.command(0, mv.CMD_DO_SET_MODE, 1, mv.COPTER_MODES["GUIDED"]) == mv.RESULT_ACCEPTED
    assert b.command(0, mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_FAILED
    assert b.texts(0) == ["Arm: AHRS: EKF3 still initialising"]
    b.run(1.1)
    assert ap.mode == "STABILIZE" and "ArduPilot Ready" in b.texts(0)
    assert b.command(0, mv.CMD_DO_SET_MODE, 1, mv.COPTER_MODES["GUIDED"]) == mv.RESULT_ACCEPTED
    assert b.command(0, mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_FAILED
    assert b.texts(0)[-1] == "Arm: Need Position Estimate"
    b.run(1.0)
    assert b.command(0, mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_ACCEPTED
    assert ap.mode == "GUIDED"


def test_ardupilot_ignores_velocity_while_takeoff_climbs(bench_factory):
    b = bench_factory("ardupilot", n=1, strict=True, warmup_s=0.1, ekf_warmup_s=0.1)
    ap = b.aps[0]
    b.run(0.2)
    assert b.command(0, mv.CMD_DO_SET_MODE, 1, mv.COPTER_MODES["GUIDED"]) == mv.RESULT_ACCEPTED
    assert b.command(0, mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_ACCEPTED
    assert b.command(0, mv.CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 4.0) == mv.RESULT_ACCEPTED
    b.run(1.0, every=0.1, action=lambda: b.setpoint(0, (2.0, 0.0, 0.0)))
    assert ap.phase == Phase.TAKEOFF and ap.counters.ignored_setpoints == 10
    assert abs(ap.p_ned[0]) < 1e-9  # did not move sideways
    b.run_until(lambda: ap.phase == Phase.AIR, 10.0)
    b.run(1.0, every=0.1, action=lambda: b.setpoint(0, (2.0, 0.0, 0.0)))
    assert ap.p_ned[0] > 0.5
