"""The ground station's MAVLink side without sockets: what it sends and what it asks for."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import ardupilotmega as dialect

from groundstation.gcs.commands import mavlink_steps
from groundstation.gcs.mavlink_listener import command_params
from groundstation.gcs.mavlink_state import (
    GCS_STREAMS_HZ,
    STREAM_STALE_S,
    MavlinkState,
    SystemTelemetry,
    streams_to_request,
)
from messages import mavlink as mv


def test_unused_command_parameters_are_zero_not_nan():
    """Issue 22, bug 2: ARM_DISARM's unused params were NaN; ArduCopter compares param 2 with
    the force-disarm code 21196 and SITL aborted on the floating-point exception."""
    (arm,) = mavlink_steps("arm", "ardupilot", 2.5)
    p = command_params(arm.params)
    assert p == [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    # NaN stays where the caller puts it on purpose (NAV_TAKEOFF's yaw: "use the current one")
    _, takeoff = mavlink_steps("takeoff", "ardupilot", 3.0)
    p = command_params(takeoff.params)
    assert math.isnan(p[3]) and p[6] == 3.0 and p[4] == p[5] == 0.0
    assert takeoff.command == mv.CMD_NAV_TAKEOFF
    with pytest.raises(ValueError, match="7 parameters"):
        command_params([0.0] * 8)


def _system(flavour: str, heard: dict[str, float]) -> SystemTelemetry:
    sys = SystemTelemetry(1, 0.0, 0.0, last_heartbeat_s=0.0, flavour=flavour)
    sys.last_seen_s.update(heard)
    return sys


def test_an_ardupilot_is_asked_for_the_streams_it_does_not_send():
    """Issue 22, bug 3: ArduCopter streams nothing on a port until asked, so the monitor showed
    no altitude, speed, battery or in-air state."""
    quiet = _system("ardupilot", {"HEARTBEAT": 9.0})
    assert streams_to_request(quiet, 10.0, None) == list(GCS_STREAMS_HZ.items())
    assert streams_to_request(quiet, 10.0, 10.0 - STREAM_STALE_S / 2) == []  # asked recently
    fresh = {name: 9.5 for name in GCS_STREAMS_HZ}
    assert streams_to_request(_system("ardupilot", fresh), 10.0, None) == []
    one_stopped = {**fresh, "SYS_STATUS": 10.0 - 2 * STREAM_STALE_S}  # e.g. after a reboot
    assert streams_to_request(_system("ardupilot", one_stopped), 10.0, 0.0) == [
        ("SYS_STATUS", GCS_STREAMS_HZ["SYS_STATUS"])
    ]
    assert streams_to_request(_system("px4", {}), 10.0, None) == []  # PX4 streams by itself
    assert streams_to_request(SystemTelemetry(1, 0.0, 0.0, flavour="ardupilot"), 1.0, None) == []


def test_state_remembers_when_each_message_type_was_last_heard():
    state = MavlinkState()
    enc = dialect.MAVLink(None, srcSystem=3, srcComponent=1)
    parser = dialect.MAVLink(None)
    for t, msg in (
        (1.0, dialect.MAVLink_heartbeat_message(2, 3, 81, 0, 3, 3)),
        (2.0, dialect.MAVLink_sys_status_message(0, 0, 0, 0, 0, 0, 80, 0, 0, 0, 0, 0, 0)),
        (3.0, dialect.MAVLink_heartbeat_message(2, 3, 81, 0, 3, 3)),
    ):
        (parsed,) = parser.parse_buffer(msg.pack(enc))
        state.fold(parsed, t)
    sys = state.systems[3]
    assert sys.last_seen_s == {"HEARTBEAT": 3.0, "SYS_STATUS": 2.0}
    assert sys.flavour == "ardupilot" and sys.battery_pct == 80.0
