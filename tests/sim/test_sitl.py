"""ArduCopter SITL in the loop, the pure parts: finding the binary, instance ports and homes,
SIM_STATE to the common NED frame, the bridge's clocks and frames, and what it publishes.
The processes themselves: ``tests/e2e/test_sitl.py``."""

from __future__ import annotations

import math
import stat

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as dialect

from messages.codec import decode
from messages.sim import CameraBearings, SimClock, Truth
from sim.autopilot.state import Home
from sim.camera import CameraConfig
from sim.sitl import (
    ENV_VAR,
    SITL_HOME,
    SitlError,
    SitlPorts,
    default_param_files,
    find_sitl,
    home_of,
    parse_params,
)
from sim.sitl_bridge import SitlBridge, SitlFrame, SitlPublisher, truth_from_sim_state


def _executable(path):
    path.write_text("#!/bin/sh\n")
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


def test_the_binary_comes_from_the_option_the_environment_or_path(tmp_path, monkeypatch):
    binary = _executable(tmp_path / "arducopter")
    monkeypatch.delenv(ENV_VAR, raising=False)
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    with pytest.raises(SitlError, match=r"pass --sitl PATH, set \$BEARINGFLOCK_SITL") as info:
        find_sitl()
    assert "\n" not in str(info.value)
    monkeypatch.setenv("PATH", str(tmp_path))
    assert find_sitl() == binary
    other = _executable(tmp_path / "elsewhere")
    monkeypatch.setenv(ENV_VAR, str(other))
    assert find_sitl() == other
    assert find_sitl(binary) == binary
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "missing"))
    with pytest.raises(SitlError, match=r"in \$BEARINGFLOCK_SITL is not an executable file"):
        find_sitl()


def test_parameter_files_next_to_the_binary(tmp_path):
    binary = _executable(tmp_path / "arducopter")
    (tmp_path / "copter.parm").write_text("FRAME_CLASS 1\n")
    assert default_param_files(binary, "gps") == (tmp_path / "copter.parm",)
    with pytest.raises(SitlError, match=r"no copter-optflow\.parm, copter-nogps\.parm next to"):
        default_param_files(binary, "flow")
    with pytest.raises(SitlError, match="unknown SITL sensors"):
        default_param_files(binary, "lidar")


def test_instance_ports_and_homes():
    p = SitlPorts(3)
    assert (p.serial0, p.serial1) == (5790, 5792)
    assert {port for _, port in p.bound()} == {5790, 5791, 5792, 5793, 5531, 9035}
    home = home_of(SITL_HOME, (10.0, -5.0, 0.0), math.radians(-90.0))
    lat, lon, alt, heading = (float(x) for x in home.split(","))
    assert heading == pytest.approx(270.0)
    assert alt == SITL_HOME.alt_amsl_m
    # 10 m north, 5 m west of the origin, by the flat earth the simulator uses
    assert (lat - SITL_HOME.lat_deg) * math.pi / 180 * 6378137.0 == pytest.approx(10.0, abs=1e-3)
    east = (
        (lon - SITL_HOME.lon_deg)
        * math.pi
        / 180
        * 6378137.0
        * math.cos(math.radians(SITL_HOME.lat_deg))
    )
    assert east == pytest.approx(-5.0, abs=1e-3)


def _sim_state(lat_deg, lon_deg, alt, roll=0.0, pitch=0.0, yaw=0.0, q=0.0, r=0.0, v=(0, 0, 0)):
    return dialect.MAVLink_sim_state_message(
        1, 0, 0, 0, roll, pitch, yaw, 0, 0, -9.8, 0.0, q, r, lat_deg * 1e7, lon_deg * 1e7,
        alt, 0, 0, *v, round(lat_deg * 1e7), round(lon_deg * 1e7),
    )  # fmt: skip


def test_sim_state_to_the_common_ned_frame():
    origin = Home(-35.36, 149.16, 584.0)
    lat, lon, _ = origin.to_global(np.array([12.3, -4.5, 0.0]))
    p, v, yaw, rate = truth_from_sim_state(
        _sim_state(lat, lon, 590.0, yaw=0.7, r=0.4, v=(1.0, 2.0, -0.5)), origin
    )
    assert p == pytest.approx([12.3, -4.5, -6.0], abs=0.02)  # 1e-7 degree is 1.1 cm
    assert v == pytest.approx([1.0, 2.0, -0.5]) and yaw == 0.7 and rate == pytest.approx(0.4)
    # the Euler yaw rate of body rates when tilted: (q sin(roll) + r cos(roll)) / cos(pitch)
    _, _, _, rate = truth_from_sim_state(
        _sim_state(lat, lon, 590.0, roll=0.3, pitch=0.2, q=0.1, r=0.4), origin
    )
    assert rate == pytest.approx((0.1 * math.sin(0.3) + 0.4 * math.cos(0.3)) / math.cos(0.2))


def _system_time(boot_s: float):
    return dialect.MAVLink_system_time_message(0, round(boot_s * 1000))


def test_bridge_clocks_take_the_least_delayed_time_and_frames_share_one_instant():
    origin = Home(0.0, 0.0, 0.0)
    bridge = SitlBridge([1, 2], origin, speedup=2.0)
    # instance 1's clock runs 30 ms behind instance 0's; its messages arrive late, up to 40 ms
    for k, (wall, delay) in enumerate([(10.0, 0.0), (10.1, 0.04), (10.2, 0.01)]):
        bridge.feed(0, _system_time(2.0 * wall - 5.0), wall + delay)
        bridge.feed(1, _system_time(2.0 * wall - 5.03), wall + 0.02 + delay)
        del k
    clocks = bridge.clocks(11.0)
    assert clocks == pytest.approx([17.0, 16.93], abs=1e-9)  # 0.02 s late at best, x2
    lat, lon, _ = origin.to_global(np.array([1.0, 0.0, -5.0]))
    bridge.feed(0, _sim_state(lat, lon, 5.0, v=(1.0, 0.0, 0.0)), 10.2)  # read with its time
    assert bridge.truth[0].t_s == pytest.approx(15.4)
    assert bridge.frame_at(11.0) is None  # instance 1 has no truth yet
    lat, lon, _ = origin.to_global(np.array([-1.0, 0.0, -5.0]))
    bridge.feed(1, _sim_state(lat, lon, 5.0, yaw=0.5, r=0.1), 10.3)
    frame = bridge.frame_at(10.3)
    assert frame is not None and frame.t_s == pytest.approx(min(frame.stamps_s))
    # both carried to the same instant: instance 0 moved on for 0.2 s of its time at 1 m/s
    assert frame.p_ned[0] == pytest.approx([1.0 + 0.2, 0.0, -5.0], abs=0.02)
    assert frame.yaw_rad[1] == 0.5  # instance 1's truth is of this very instant
    later = bridge.frame_at(10.35)  # 0.1 s of instance 1's time later, turning at 0.1 rad/s
    assert later is not None and later.yaw_rad[1] == pytest.approx(0.51)
    assert later.stamps_s == pytest.approx([15.7, 15.63])
    assert later.p_ned[0, 0] == pytest.approx(1.2, abs=0.02)  # never carried past 0.2 s


def test_publisher_stamps_each_vehicle_on_its_own_clock():
    out: list[tuple[str, bytes]] = []
    pub = SitlPublisher(CameraConfig(fov_deg=360.0), "f", lambda k, b: out.append((k, b)), 2.0)
    frame = SitlFrame(
        t_s=20.0, stamps_s=np.array([20.0, 20.03]),
        p_ned=np.array([[0.0, 0.0, -5.0], [3.0, 4.0, -5.0]]), yaw_rad=np.array([0.0, math.pi]),
        v_ned=np.zeros((2, 3)), yaw_rate_rad_s=np.zeros(2),
    )  # fmt: skip
    pub(frame)
    got = dict(out)
    b1 = decode(got["bf/f/1/camera/bearings"], CameraBearings)
    assert b1.stamp_s == pytest.approx(20.03) and b1.targets == [0]
    assert b1.beta_body[0] == pytest.approx((0.6, 0.8, 0.0))  # R_z(pi)^T (p0 - p1) / 5
    assert decode(got["bf/f/0/truth"], Truth).stamp_s == 20.0
    clock = decode(got["bf/f/sim/clock"], SimClock)
    assert (clock.t_s, clock.speedup, clock.lockstep) == (20.0, 2.0, False)
    common = SitlPublisher(
        CameraConfig(), "f", lambda k, b: out.append((k, b)), 1.0, None, "common"
    )
    out.clear()
    common(frame)
    assert decode(dict(out)["bf/f/1/truth"], Truth).stamp_s == 20.0
    with pytest.raises(ValueError, match="own or common"):
        SitlPublisher(CameraConfig(), "f", print, 1.0, None, "local")


def test_extra_parameters():
    assert parse_params(["arming_check=786374", " SIM_SPEEDUP = 2 "]) == {
        "ARMING_CHECK": 786374.0,
        "SIM_SPEEDUP": 2.0,
    }
    for bad in ("ARMING_CHECK", "=3", "X=nan", "X=fast"):
        with pytest.raises(SitlError, match="expected NAME=VALUE"):
            parse_params([bad])
