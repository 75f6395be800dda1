"""The ground station's MAVLink side without sockets: what it sends and what it asks for."""

from __future__ import annotations

import math

import pytest

from groundstation.gcs.commands import mavlink_steps
from groundstation.gcs.mavlink_listener import command_params
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
