"""PX4 flavour: identity, modes, takeoff/hold/land, offboard entry rule and failsafe."""

from __future__ import annotations

import math

import numpy as np
import pytest

from messages import mavlink as mv
from sim.autopilot.common import Phase

NAN = math.nan


def _fly_to_hold(b, i=0):
    assert b.command(i, mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_ACCEPTED
    assert b.command(i, mv.CMD_NAV_TAKEOFF, *([NAN] * 7)) == mv.RESULT_ACCEPTED
    b.run_until(lambda: b.aps[i].mode == "AUTO.LOITER" and b.aps[i].phase == Phase.AIR, 10.0)
    b.run(3.0)  # settle at the takeoff altitude


def test_heartbeat_identity_and_mode_encoding(bench_factory):
    b = bench_factory("px4", n=2)
    b.run(1.05)
    for i in range(2):
        hbs = b.sent(i, "HEARTBEAT")
        assert len(hbs) == 1 or len(hbs) == 2  # 1 Hz, phase-staggered
        hb = hbs[-1]
        assert hb.type == mv.MAV_TYPE_QUADROTOR and hb.autopilot == mv.MAV_AUTOPILOT_PX4
        assert hb.custom_mode == (4 << 16) | (3 << 24)  # AUTO.LOITER
        assert hb.base_mode & mv.BASE_MODE_CUSTOM and not hb.base_mode & mv.BASE_MODE_ARMED
        assert hb.system_status == mv.MAV_STATE_STANDBY
        assert b.aps[i].sys_id == i + 1


def test_default_streams_and_rates(bench_factory):
    b = bench_factory("px4", n=1)
    b.run(2.0)
    count = {k: len(b.sent(0, k)) for k in ("ATTITUDE", "LOCAL_POSITION_NED", "SYS_STATUS")}
    assert 38 <= count["ATTITUDE"] <= 42  # 20 Hz
    assert 38 <= count["LOCAL_POSITION_NED"] <= 42
    assert 3 <= count["SYS_STATUS"] <= 5  # 2 Hz
    for kind in (
        "ATTITUDE_QUATERNION",
        "GLOBAL_POSITION_INT",
        "EXTENDED_SYS_STATE",
        "GPS_RAW_INT",
        "HOME_POSITION",
        "BATTERY_STATUS",
    ):
        assert b.sent(0, kind), kind
    sys_status = b.sent(0, "SYS_STATUS")[-1]
    assert sys_status.onboard_control_sensors_health & mv.SENSOR_PREARM_CHECK
    assert sys_status.onboard_control_sensors_health & mv.SENSOR_GPS
    gpi = b.sent(0, "GLOBAL_POSITION_INT")[-1]
    assert abs(gpi.lat - 473977420) <= 1 and abs(gpi.lon - 85455940) <= 1
    assert b.sent(0, "EXTENDED_SYS_STATE")[-1].landed_state == mv.LANDED_ON_GROUND


def test_set_message_interval_changes_rate_and_disables(bench_factory):
    b = bench_factory("px4", n=1)
    assert b.command(0, mv.CMD_SET_MESSAGE_INTERVAL, 30, 200_000) == mv.RESULT_ACCEPTED  # 5 Hz
    assert b.command(0, mv.CMD_SET_MESSAGE_INTERVAL, 32, -1) == mv.RESULT_ACCEPTED  # off
    assert b.command(0, mv.CMD_SET_MESSAGE_INTERVAL, 9999, 1000) == mv.RESULT_UNSUPPORTED
    b.outbox[0].clear()
    b.run(2.0)
    assert 9 <= len(b.sent(0, "ATTITUDE")) <= 11
    assert b.sent(0, "LOCAL_POSITION_NED") == []


def test_request_message_and_autopilot_version_uid_unique(bench_factory):
    b = bench_factory("px4", n=3)
    uids = set()
    for i in range(3):
        assert b.command(i, mv.CMD_REQUEST_MESSAGE, 148) == mv.RESULT_ACCEPTED
        v = b.sent(i, "AUTOPILOT_VERSION")
        assert len(v) == 1
        caps = v[0].capabilities
        for bit in (1, 2, 4, 8, 128, 64, 8192):
            assert caps & bit
        uids.add(v[0].uid)
        assert b.command(i, mv.CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1) == mv.RESULT_ACCEPTED
        assert len(b.sent(i, "AUTOPILOT_VERSION")) == 1
        assert b.command(i, mv.CMD_REQUEST_MESSAGE, 242) == mv.RESULT_ACCEPTED
        assert len(b.sent(i, "HOME_POSITION")) == 1
    assert len(uids) == 3
    assert b.command(0, 31337) == mv.RESULT_UNSUPPORTED


def test_takeoff_hold_land_autodisarm(bench_factory):
    b = bench_factory("px4", n=1)
    ap = b.aps[0]
    assert b.command(0, mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_ACCEPTED
    hb = b.sent(0, "HEARTBEAT")[-1]
    assert hb.base_mode & mv.BASE_MODE_ARMED and hb.system_status == mv.MAV_STATE_ACTIVE
    assert b.command(0, mv.CMD_NAV_TAKEOFF, *([NAN] * 7)) == mv.RESULT_ACCEPTED
    assert ap.mode == "AUTO.TAKEOFF" and ap.phase == Phase.TAKEOFF
    took = b.run_until(lambda: ap.mode == "AUTO.LOITER", 10.0)
    # 2.5 m at 1.5 m/s plus the lag: about 2 s
    assert 1.6 < took < 4.0
    assert ap.altitude_m == pytest.approx(2.5, abs=0.2)
    b.run(3.0)
    assert ap.altitude_m == pytest.approx(2.5, abs=0.05)  # holds
    assert b.command(0, mv.CMD_COMPONENT_ARM_DISARM, 0) == mv.RESULT_DENIED  # in air
    assert b.command(0, mv.CMD_NAV_LAND) == mv.RESULT_ACCEPTED
    assert ap.mode == "AUTO.LAND" and ap.phase == Phase.LANDING
    landed = b.run_until(lambda: ap.phase == Phase.GROUND, 10.0)
    assert 2.5 / 0.7 - 0.5 < landed < 2.5 / 0.7 + 1.5  # MPC_LAND_SPEED 0.7 m/s
    assert ap.armed
    disarm = b.run_until(lambda: not ap.armed, 5.0)
    assert disarm == pytest.approx(2.0, abs=0.05)  # COM_DISARM_LAND
    assert "Disarmed by landing" in b.texts(0)


def test_forced_disarm_in_air(bench_factory):
    b = bench_factory("px4", n=1)
    _fly_to_hold(b)
    assert b.command(0, mv.CMD_COMPONENT_ARM_DISARM, 0, mv.FORCE_DISARM_MAGIC) == mv.RESULT_ACCEPTED
    assert not b.aps[0].armed
    b.run_until(lambda: b.aps[0].on_ground, 5.0)  # falls


def test_offboard_entry_rule(bench_factory):
    b = bench_factory("px4", n=1)
    _fly_to_hold(b)
    r = b.command(0, mv.CMD_DO_SET_MODE, 1, mv.PX4_MAIN_OFFBOARD, 0)
    assert r == mv.RESULT_TEMPORARILY_REJECTED
    assert any("Offboard" in t for t in b.texts(0))
    b.setpoint(0, (0.0, 0.0, 0.0))
    b.run(0.5)
    b.setpoint(0, (0.0, 0.0, 0.0))
    assert b.command(0, mv.CMD_DO_SET_MODE, 1, mv.PX4_MAIN_OFFBOARD, 0) == mv.RESULT_ACCEPTED
    assert b.aps[0].mode == "OFFBOARD"
    hb = b.sent(0, "HEARTBEAT")[-1]  # the change is visible at once
    assert hb.custom_mode == mv.px4_custom_mode(mv.PX4_MAIN_OFFBOARD)


def test_offboard_body_velocity_and_yaw_rate_move_as_commanded(bench_factory):
    b = bench_factory("px4", n=1)
    ap = b.aps[0]
    _fly_to_hold(b)
    b.setpoint(0, (1.0, 0.0, 0.0), yaw_rate=0.0)
    assert b.command(0, mv.CMD_DO_SET_MODE, 1, mv.PX4_MAIN_OFFBOARD, 0) == mv.RESULT_ACCEPTED
    p0 = ap.p_ned.copy()
    yaw0 = float(b.server.world.yaw_rad[0])
    b.run(5.0, every=0.05, action=lambda: b.setpoint(0, (1.0, 0.0, 0.0), yaw_rate=0.0))
    d = ap.p_ned - p0
    # facing north: 1 m/s forward for 5 s minus the lag (tau 0.3 s) is about 4.7 m north
    assert d[0] == pytest.approx(5.0 - 0.3, abs=0.15)
    assert abs(d[1]) < 1e-6 and abs(d[2]) < 0.05
    # now turn at 0.2 rad/s while flying forward: the heading follows
    b.run(5.0, every=0.05, action=lambda: b.setpoint(0, (0.0, 0.0, 0.0), yaw_rate=0.2))
    yaw = float(b.server.world.yaw_rad[0])
    assert yaw - yaw0 == pytest.approx(1.0 - 0.2 * 0.2, abs=0.03)  # lag tau_yaw 0.2 s


def test_offboard_setpoint_loss_failsafe_on_time(bench_factory):
    b = bench_factory("px4", n=1)
    ap = b.aps[0]
    _fly_to_hold(b)
    b.setpoint(0, (1.0, 0.0, 0.0))
    assert b.command(0, mv.CMD_DO_SET_MODE, 1, mv.PX4_MAIN_OFFBOARD, 0) == mv.RESULT_ACCEPTED
    last: dict[str, float] = {}

    def send() -> None:
        b.setpoint(0, (1.0, 0.0, 0.0))
        last["t"] = b.t

    b.run(1.0, every=0.05, action=send)
    took = b.run_until(lambda: ap.mode != "OFFBOARD", 3.0)
    loss = b.t - last["t"]
    assert ap.mode == "AUTO.LOITER"
    assert loss == pytest.approx(1.0, abs=0.03)  # COM_OF_LOSS_T
    assert took < 1.0
    assert any("offboard" in t.lower() for t in b.texts(0))
    # it now holds where it stopped
    p = ap.p_ned.copy()
    b.run(4.0)
    assert np.linalg.norm(ap.p_ned - p) < 0.6


def test_nan_setpoint_is_stop_and_counted(bench_factory):
    b = bench_factory("px4", n=1)
    ap = b.aps[0]
    _fly_to_hold(b)
    b.setpoint(0, (2.0, 0.0, 0.0))
    assert b.command(0, mv.CMD_DO_SET_MODE, 1, mv.PX4_MAIN_OFFBOARD, 0) == mv.RESULT_ACCEPTED
    b.run(2.0, every=0.05, action=lambda: b.setpoint(0, (2.0, 0.0, 0.0)))
    assert np.linalg.norm(b.server.world.v_ned[0]) > 1.5
    b.run(2.0, every=0.05, action=lambda: b.setpoint(0, (NAN, 0.0, 0.0)))
    # from 2 m/s: 0.2 s at the 4 m/s^2 limit down to 1.2 m/s, then 1.8 s of e^(-t/0.3)
    assert np.linalg.norm(b.server.world.v_ned[0]) == pytest.approx(1.2 * math.exp(-6.0), rel=0.1)
    assert ap.mode == "OFFBOARD"  # NaN is proof of life, not loss
    assert ap.counters.nan_setpoints == 40


def test_setpoints_for_other_systems_and_frames_ignored(bench_factory):
    b = bench_factory("px4", n=2)
    _fly_to_hold(b, 0)
    b.setpoint(0, (1.0, 0.0, 0.0), target=2)
    assert b.aps[0].counters.foreign_target == 1
    assert (
        b.command(0, mv.CMD_DO_SET_MODE, 1, mv.PX4_MAIN_OFFBOARD, 0)
        == mv.RESULT_TEMPORARILY_REJECTED
    )
    b.setpoint(0, (1.0, 0.0, 0.0), frame=mv.FRAME_BODY_OFFSET_NED)  # PX4: 1 and 8 only
    assert b.aps[0].counters.ignored_setpoints == 1
    assert b.command(0, mv.CMD_COMPONENT_ARM_DISARM, 1, target=7) == -1  # no ACK, ignored
    assert not b.aps[1].armed
    assert b.command(1, mv.CMD_COMPONENT_ARM_DISARM, 1, target=0) == mv.RESULT_ACCEPTED  # broadcast


def test_set_mode_message_and_hold_modes(bench_factory):
    b = bench_factory("px4", n=1)
    _fly_to_hold(b)
    b.deliver(0, b.dialect.MAVLink_set_mode_message(1, 1, mv.px4_custom_mode(3)))
    assert b.aps[0].mode == "POSCTL"
    assert b.command(0, mv.CMD_DO_SET_MODE, 1, 4, 3) == mv.RESULT_ACCEPTED
    assert b.aps[0].mode == "AUTO.LOITER"
    assert b.command(0, mv.CMD_DO_SET_MODE, 1, 42, 0) == mv.RESULT_DENIED
    assert b.command(0, mv.CMD_DO_SET_MODE, 0, 4, 3) == mv.RESULT_UNSUPPORTED


def test_return_to_launch_lands_at_home(bench_factory):
    b = bench_factory("px4", n=1)
    ap = b.aps[0]
    _fly_to_hold(b)
    b.setpoint(0, (3.0, 0.0, 0.0))
    assert b.command(0, mv.CMD_DO_SET_MODE, 1, mv.PX4_MAIN_OFFBOARD, 0) == mv.RESULT_ACCEPTED
    b.run(3.0, every=0.05, action=lambda: b.setpoint(0, (3.0, 0.0, 0.0)))
    assert ap.p_ned[0] > 5.0
    assert b.command(0, mv.CMD_NAV_RETURN_TO_LAUNCH) == mv.RESULT_ACCEPTED
    b.run_until(lambda: not ap.armed, 60.0)
    assert np.linalg.norm(ap.p_ned[:2] - ap.home_ned[:2]) < 0.6


def test_params_list_read_set(bench_factory):
    b = bench_factory("px4", n=2)
    b.deliver(1, b.dialect.MAVLink_param_request_list_message(2, 1))
    values = b.sent(1, "PARAM_VALUE")
    assert len(values) == len(b.aps[1].params)
    assert [v.param_index for v in values] == list(range(len(values)))
    assert all(v.param_count == len(values) for v in values)
    by_name = {v.param_id: v for v in values}
    assert by_name["MIS_TAKEOFF_ALT"].param_value == pytest.approx(2.5)
    sysid = by_name["MAV_SYS_ID"]
    assert sysid.param_type == 6
    assert (
        np.frombuffer(np.float32(sysid.param_value).tobytes(), dtype=np.int32)[0] == 2
    )  # bytewise
    b.outbox[1].clear()
    b.deliver(1, b.dialect.MAVLink_param_set_message(2, 1, b"MIS_TAKEOFF_ALT", 4.0, 9))
    echo = b.sent(1, "PARAM_VALUE")
    assert len(echo) == 1 and echo[0].param_value == pytest.approx(4.0) and echo[0].param_type == 9
    b.outbox[1].clear()
    b.deliver(1, b.dialect.MAVLink_param_request_read_message(2, 1, b"COM_OF_LOSS_T", -1))
    assert b.sent(1, "PARAM_VALUE")[0].param_value == pytest.approx(1.0)
    # the new takeoff altitude is used
    assert b.command(1, mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_ACCEPTED
    assert b.command(1, mv.CMD_NAV_TAKEOFF, *([NAN] * 7)) == mv.RESULT_ACCEPTED
    b.run_until(lambda: b.aps[1].mode == "AUTO.LOITER", 10.0)
    assert b.aps[1].altitude_m == pytest.approx(4.0, abs=0.2)


def test_takeoff_mode_then_arm_takes_off(bench_factory):
    b = bench_factory("px4", n=1)
    assert b.command(0, mv.CMD_NAV_TAKEOFF, *([NAN] * 7)) == mv.RESULT_ACCEPTED
    assert b.aps[0].mode == "AUTO.TAKEOFF" and not b.aps[0].armed
    b.run(1.0)
    assert b.aps[0].on_ground
    assert b.command(0, mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_ACCEPTED
    b.run_until(lambda: b.aps[0].mode == "AUTO.LOITER", 10.0)


def test_command_int_ping_timesync_mission_ftp_and_status(bench_factory):
    b = bench_factory("px4", n=1)
    d = b.dialect
    b.outbox[0].clear()
    b.deliver(0, d.MAVLink_command_int_message(1, 1, 0, 400, 0, 0, 1, 0, 0, 0, 0, 0, 0.0))
    assert b.sent(0, "COMMAND_ACK")[-1].result == mv.RESULT_ACCEPTED and b.aps[0].armed
    b.deliver(0, d.MAVLink_ping_message(123, 7, 0, 0))
    ping = b.sent(0, "PING")[-1]
    assert (ping.time_usec, ping.seq, ping.target_system) == (123, 7, 245)
    b.run(0.5)
    b.deliver(0, d.MAVLink_timesync_message(0, 555))
    ts = b.sent(0, "TIMESYNC")[-1]
    assert ts.ts1 == 555 and ts.tc1 == round(b.t * 1e9)
    b.deliver(0, d.MAVLink_mission_request_list_message(1, 1, 0))
    assert b.sent(0, "MISSION_COUNT")[-1].count == 0
    req = [0, 0, 9, 4, 3, 0, 0, 0, 0, 0, 0, 0, *([0] * 239)]  # OpenFileRO, session 9
    b.deliver(0, d.MAVLink_file_transfer_protocol_message(0, 1, 1, req))
    nak = bytes(b.sent(0, "FILE_TRANSFER_PROTOCOL")[-1].payload)
    assert nak[3] == 129 and nak[5] == 4 and nak[2] == 9 and nak[12] == 10  # NAK, FileNotFound
    status = b.server.status()
    assert "armed 1/1" in status and "AUTO.LOITER:1" in status
