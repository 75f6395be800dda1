"""The own odometry the agent core receives: velocity and yaw of one instant, stamped with it.

An autopilot streams attitude (ATTITUDE: yaw, yaw rate) and velocity (LOCAL_POSITION_NED)
as separate messages, usually a few milliseconds apart; the link holds the newest of each. The
SfM observers of paper 000 pair the body-frame velocity ``u_i = R_z(yaw)^T v_ned`` with camera
frames by time, and during the formation's rotation (0.5-0.8 rad/s) 10 ms between the yaw and
the velocity already turn ``u_i`` by half a degree. So the odometry is taken at the velocity's
instant, with the yaw carried to it along the reported yaw rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from onboard.autopilot.base import Telemetry
from onboard.daemon.clock import autopilot_stamp

Vec3 = tuple[float, float, float]

MAX_YAW_SHIFT_S = 0.2
"""Longest interval the yaw is carried along its rate (a stale attitude is not extrapolated
further: the link flags it stale long before)."""


@dataclass(frozen=True, slots=True)
class Odometry:
    stamp_s: float | None
    """When it was measured, in the daemon's clock (``None``: unknown, use the tick time)."""
    yaw_rad: float
    yaw_rate_rad_s: float
    v_body: Vec3
    """``R_z(yaw)^T v_ned`` with the yaw of the same instant."""


def odometry(tel: Telemetry, now_s: float, sim: bool) -> Odometry:
    """The odometry at the instant of the newest velocity (module docstring).

    ``sim``: the autopilot's ``time_boot_ms`` is simulation time, the daemon's clock; otherwise
    instants are the daemon's clock at arrival (:func:`onboard.daemon.clock.autopilot_stamp`).
    """
    if tel.t_boot_attitude_s is not None and tel.t_boot_velocity_s is not None:
        shift = tel.t_boot_velocity_s - tel.t_boot_attitude_s
    else:
        shift = tel.attitude_age_s - tel.velocity_age_s
    if not math.isfinite(shift):
        shift = 0.0
    shift = max(-MAX_YAW_SHIFT_S, min(MAX_YAW_SHIFT_S, shift))
    yaw = tel.yaw_rad + tel.yaw_rate_rad_s * shift
    c, s = math.cos(yaw), math.sin(yaw)
    vn, ve, vd = tel.v_ned
    t_boot = tel.t_boot_velocity_s if tel.t_boot_velocity_s is not None else tel.t_boot_s
    return Odometry(
        stamp_s=autopilot_stamp(t_boot, tel.velocity_age_s, now_s, sim),
        yaw_rad=math.remainder(yaw, math.tau),
        yaw_rate_rad_s=tel.yaw_rate_rad_s,
        v_body=(c * vn + s * ve, -s * vn + c * ve, vd),
    )
