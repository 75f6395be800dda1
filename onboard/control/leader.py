"""A driven leader (paper 002, "leader" of the formation experiments, docs/papers.md; the law in
docs/equations.md, "Formation control and vision"; docs/distributed.md).

Paper 002's leader is an agent whose state is driven from outside while the others keep
descending the formation cost, so they follow it through their edges
(:func:`onboard.distributed.flow.apply_leaders`); its third experiment velocity-controls the
leader. :class:`LeaderPlan` is that external velocity for one vehicle, from the ground station's
:class:`messages.command.LeaderDrive`:

* a constant NED velocity, for a duration (then zero: the leader holds) or until replaced;
* a list of NED waypoints, flown in order: towards waypoint ``k`` at
  ``v = e min(speed / |e|, k_p)``, ``e = w_k - p`` (the speed bound far away, a proportional
  approach of time constant ``1 / k_p`` near it); the next one once ``|e| < tolerance``; the last
  one is held the same way.

Both are NED in the leader's own odometry frame (the autopilot's yaw and local position; nothing
is shared with the team). The core turns the result into the body frame with the odometry yaw and
saturates it with ``v_max`` (:class:`onboard.core.config.Safety`) like every command.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

Vec3 = tuple[float, float, float]

K_WAYPOINT = 1.0
"""``k_p`` of the waypoint approach, 1/s."""
_ZERO: Vec3 = (0.0, 0.0, 0.0)


def waypoint_velocity(p_ned: Vec3, waypoint_ned: Vec3, speed_m_s: float,
                      k_p: float = K_WAYPOINT) -> Vec3:  # fmt: skip
    """``e min(speed / |e|, k_p)`` with ``e = waypoint - p``: at most ``speed_m_s``."""
    e = (waypoint_ned[0] - p_ned[0], waypoint_ned[1] - p_ned[1], waypoint_ned[2] - p_ned[2])
    n = math.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
    if n < 1e-12:
        return _ZERO
    g = min(speed_m_s / n, k_p)
    return (g * e[0], g * e[1], g * e[2])


def ned_to_body(v_ned: Vec3, yaw_rad: float) -> Vec3:
    """``R_z(yaw)^T v``: a NED vector in the heading frame the setpoints use."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return (c * v_ned[0] + s * v_ned[1], -s * v_ned[0] + c * v_ned[1], v_ned[2])


@dataclass
class LeaderPlan:
    """One drive of the leader (module docstring). ``step`` gives the NED velocity and a short
    state for the status."""

    velocity_ned: Vec3 | None = None
    duration_s: float | None = None
    waypoints_ned: Sequence[Vec3] = ()
    speed_m_s: float = 0.5
    tolerance_m: float = 0.3
    t0_s: float | None = None
    """When the drive started: the first step after it was taken."""
    next_waypoint: int = 0

    def step(self, t_s: float, p_ned: Vec3 | None) -> tuple[Vec3, str]:
        """The external velocity at ``t_s`` (NED, m/s) from the odometry position ``p_ned``
        (``None``: unknown; a waypoint drive then holds)."""
        if self.t0_s is None:
            self.t0_s = t_s
        if self.velocity_ned is not None:
            if self.duration_s is not None and t_s - self.t0_s >= self.duration_s:
                return _ZERO, "velocity done"
            return self.velocity_ned, "velocity"
        n = len(self.waypoints_ned)
        if n == 0:
            return _ZERO, "hold"
        if p_ned is None:
            return _ZERO, "no odometry position"
        while self.next_waypoint < n - 1 and (
            math.dist(p_ned, self.waypoints_ned[self.next_waypoint]) < self.tolerance_m
        ):
            self.next_waypoint += 1
        wp = self.waypoints_ned[self.next_waypoint]
        v = waypoint_velocity(p_ned, wp, self.speed_m_s)
        last = self.next_waypoint == n - 1
        if last and math.dist(p_ned, wp) < self.tolerance_m:
            return v, "waypoints done"
        return v, f"waypoint {self.next_waypoint + 1}/{n}"
