"""The own odometry handed to the agent core (onboard.daemon.odometry) and the follower of the
simulator's clock (onboard.daemon.clock): data stamped with the instant it describes."""

from __future__ import annotations

import math
import time

import pytest
from pymavlink.dialects.v20 import common as dialect

from messages import mavlink as mv
from onboard.autopilot.base import Flavour, LinkConfig, LinkCounters, StreamState
from onboard.autopilot.states import Saturated, TelemetryState, snapshot
from onboard.daemon.clock import SimClockFollower
from onboard.daemon.odometry import odometry


def _telemetry(t_att_ms: int, t_vel_ms: int, yaw: float, yaw_rate: float, v_ned):
    st = TelemetryState(flavour=Flavour.PX4)
    st.apply(dialect.MAVLink_heartbeat_message(2, 12, mv.BASE_MODE_CUSTOM, 0, 3, 3), 10.0)
    st.apply(dialect.MAVLink_attitude_message(t_att_ms, 0.0, 0.0, yaw, 0, 0, yaw_rate), 10.0)
    st.apply(dialect.MAVLink_local_position_ned_message(t_vel_ms, 0, 0, -5.0, *v_ned), 10.01)
    return snapshot(
        st,
        10.02,
        LinkConfig(),
        1,
        StreamState.IDLE,
        Saturated((0.0, 0.0, 0.0), 0.0, False, False),
        LinkCounters(),
    )


def test_odometry_takes_the_yaw_of_the_velocity_instant():
    tel = _telemetry(2000, 2010, yaw=0.5, yaw_rate=0.8, v_ned=(1.0, 0.0, 0.0))
    odo = odometry(tel, now_s=2.03, sim=True)
    assert odo.stamp_s == pytest.approx(2.01)  # simulation time: the autopilot's own stamp
    yaw = 0.5 + 0.8 * 0.01
    assert odo.yaw_rad == pytest.approx(yaw)
    assert odo.v_body == pytest.approx((math.cos(yaw), -math.sin(yaw), 0.0))
    # on a real vehicle the boot clock is not the fleet's: the instant of arrival instead
    real = odometry(tel, now_s=100.0, sim=False)
    assert real.stamp_s == pytest.approx(100.0 - tel.velocity_age_s)


def test_sim_clock_follower_extrapolates_at_most_the_cap_and_never_runs_backwards():
    clock = SimClockFollower(max_extrapolation_s=0.05)
    assert clock.now() is None
    clock.update(10.0, speedup=100.0, lockstep=False)
    time.sleep(0.01)  # 100x: 1 s of simulation would pass, the cap allows 0.05
    assert clock.now() == pytest.approx(10.05)
    clock.observe(10.5)  # an autopilot stamp: the simulation is at least there
    t = clock.now()
    assert 10.5 <= t <= 10.55
    clock.observe(10.2)  # older than the clock: ignored
    clock.update(10.3, speedup=100.0, lockstep=False)  # a late SimClock: ignored
    assert clock.now() >= t


def test_levelling_attitude_carries_the_attitude_messages_own_stamp():
    """Roll and pitch are stamped with ATTITUDE's ``time_boot_ms``, not with the newer
    LOCAL_POSITION_NED's (levelling pairs them with camera frames by that stamp)."""
    from types import SimpleNamespace

    from onboard.daemon.cli import _attitude

    tel = _telemetry(2000, 2040, yaw=0.5, yaw_rate=0.0, v_ned=(1.0, 0.0, 0.0))
    assert tel.t_boot_s == pytest.approx(2.04)  # the newest autopilot time is the velocity's
    link = SimpleNamespace(telemetry=lambda: tel)
    clock = SimpleNamespace(now=lambda: 2.05)
    sample = _attitude(link, clock, "sim")()
    assert sample is not None and sample.t_s == pytest.approx(2.0)
