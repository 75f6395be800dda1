"""Ground station -> agent commands and their acknowledgements (over Zenoh).

``bf/<fleet>/<id>/command`` carries a :class:`FleetCommand` addressed to one agent (the ground
station publishes one per selected vehicle at the same moment); the agent answers on
``bf/<fleet>/<id>/command/ack`` with a :class:`CommandAck` that echoes ``request_id``.
Arming, takeoff and landing go to the autopilots over MAVLink; the agents take the mission
commands below (and ``land``/``stop`` too, so an operator reaches a vehicle whose link to the
ground station is only Zenoh).

``bf/<fleet>/<id>/command/formation`` carries a :class:`FormationChange`: a new desired formation
(paper 002's formation changes at run time, eq. 20 with new ``beta*_ij``), optionally with a
leader that holds its position while the others follow its bearings, and optionally with the
formation's distances (eq. 23's ``f_D`` term: a scale change). The agent ramps from the formation
it flies to the new one over ``ramp_s`` and answers through its status
(``VehicleStatus.formation_id``); one it cannot fly is counted and dropped.

``bf/<fleet>/<id>/command/leader`` carries a :class:`LeaderDrive`: the external velocity of
paper 002's leader (``apply_leaders``), a constant NED velocity for a time or a list of NED
waypoints in the leader's own odometry frame flown at a bounded speed. Only the formation's
leader takes it (others count it ``command_foreign``); it answers through
``VehicleStatus.leader_drive_id``.
"""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec
import numpy as np

from messages.codec import Payload
from messages.formation import COINCIDENT_TOLERANCE_M
from messages.limits import (
    LIST_MAX,
    SEQ_MAX,
    SPEED_MAX_M_S,
    AgentId,
    Angle,
    Name,
    PositionVec3,
    SpeedVec3,
)

COMMAND_TOPIC = "command"
ACK_TOPIC = "command/ack"
FORMATION_TOPIC = "command/formation"
LEADER_TOPIC = "command/leader"

RAMP_MAX_S = 600.0
"""Longest switch from one formation to the next an operator may ask for, s."""
DRIVE_DURATION_MAX_S = 3600.0
"""Longest constant-velocity leg of a :class:`LeaderDrive`, s."""
TOLERANCE_MAX_M = 100.0
"""Largest waypoint acceptance radius, m."""

Action = Literal["start", "hold", "land", "stop"]
"""``start``: fly the mission; ``hold``: zero velocity, keep streaming; ``land``: command the
autopilot to land; ``stop``: emergency: hold at once, then land."""


class FleetCommand(Payload, tag="command"):
    """One command for agent ``target``; ``sender`` is the ground station's id (0 by convention)."""

    target: int
    action: Action
    request_id: int


class CommandAck(Payload, tag="command.ack"):
    """Agent ``sender``'s answer to ``request_id``: accepted or not, and why."""

    request_id: int
    action: Action
    accepted: bool
    detail: str = ""


class FormationSlot(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """One vehicle's place in a desired formation (only relative positions and yaw differences
    matter: the desired bearings ``beta*_ij`` are computed from them, docs/equations.md)."""

    id: AgentId
    position_ned: PositionVec3
    yaw_rad: Angle = 0.0


FormationId = Annotated[int, msgspec.Meta(ge=1, le=SEQ_MAX)]
"""A formation change's id; 0 is the fleet file's planned formation."""


class FormationChange(Payload, tag="command.formation"):
    """A new desired formation for agent ``target`` (the ground station sends one per agent).

    ``agents`` must name every vehicle of the fleet exactly once (:func:`formation_problem`);
    ``leader`` is the vehicle that holds its position (``None``: no leader) or flies a
    :class:`LeaderDrive`. ``distances``: hold the slots' distances too (paper 002 eq. 23's
    ``f_D`` term on every sensing edge the agent has a distance estimate for; off: bearings
    only, the team keeps the size it has). ``ramp_s``: the time over which the agent moves its
    desired bearings, distances and yaws from the formation it flies to this one (``None``: its
    default, :attr:`onboard.core.config.FormationGains.change_ramp_s`; 0: at once)."""

    target: AgentId
    formation_id: FormationId
    agents: Annotated[list[FormationSlot], msgspec.Meta(min_length=2, max_length=LIST_MAX)]
    name: Name = ""
    leader: AgentId | None = None
    distances: bool = False
    ramp_s: Annotated[float, msgspec.Meta(ge=0.0, le=RAMP_MAX_S)] | None = None


def formation_problem(change: FormationChange, fleet_ids: set[int] | frozenset[int]) -> str:
    """Why a fleet with ``fleet_ids`` cannot fly ``change`` (``""``: it can): duplicate,
    unknown or missing vehicle ids, an unknown leader, coincident vehicles (closer than
    :data:`messages.formation.COINCIDENT_TOLERANCE_M`, as in a formation file: their desired
    bearing is undefined)."""
    ids = [a.id for a in change.agents]
    if len(set(ids)) != len(ids):
        return f"duplicate vehicle ids in formation {change.formation_id}"
    unknown = sorted(set(ids) - set(fleet_ids))
    if unknown:
        return f"unknown vehicle ids {unknown} in formation {change.formation_id}"
    missing = sorted(set(fleet_ids) - set(ids))
    if missing:
        return f"formation {change.formation_id} leaves out vehicles {missing}"
    if change.leader is not None and change.leader not in fleet_ids:
        return f"unknown leader {change.leader} in formation {change.formation_id}"
    # closer than the formation files' tolerance (not only equal): two slots 1e-200 m apart
    # passed an equality test, and their desired bearing (p_j - p_i) / |p_j - p_i| was NaN
    p = np.array([a.position_ned for a in change.agents], dtype=float)
    gaps = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=-1)
    np.fill_diagonal(gaps, np.inf)
    if gaps.min() < COINCIDENT_TOLERANCE_M:
        i, j = np.unravel_index(np.argmin(gaps), gaps.shape)
        return (
            f"coincident vehicles {change.agents[i].id} and {change.agents[j].id} (closer than "
            f"{COINCIDENT_TOLERANCE_M:g} m) in formation {change.formation_id}"
        )
    return ""


Waypoints = Annotated[list[PositionVec3], msgspec.Meta(max_length=LIST_MAX)]
DriveId = Annotated[int, msgspec.Meta(ge=1, le=SEQ_MAX)]
"""A leader drive's id; 0 in a status: none flown yet."""


class LeaderDrive(Payload, tag="command.leader"):
    """What the leader ``target`` flies (paper 002's leader with an external velocity).

    Exactly one of: ``velocity_ned`` (m/s, NED in the leader's odometry frame; for
    ``duration_s`` seconds, then it holds; ``None`` duration: until the next drive), or
    ``waypoints_ned`` (m, NED in the leader's odometry frame: the autopilot's local position),
    flown in order at ``speed_m_s`` at most, each reached within ``tolerance_m``; the last one is
    held. Neither: hold (stop driving). The core saturates the result by its ``v_max``."""

    target: AgentId
    drive_id: DriveId
    velocity_ned: SpeedVec3 | None = None
    duration_s: Annotated[float, msgspec.Meta(gt=0.0, le=DRIVE_DURATION_MAX_S)] | None = None
    waypoints_ned: Waypoints = msgspec.field(default_factory=list)
    speed_m_s: Annotated[float, msgspec.Meta(gt=0.0, le=SPEED_MAX_M_S)] = 0.5
    tolerance_m: Annotated[float, msgspec.Meta(gt=0.0, le=TOLERANCE_MAX_M)] = 0.3


def drive_problem(drive: LeaderDrive) -> str:
    """Why ``drive`` is not one drive (``""``: it is): both a velocity and waypoints, or a
    duration without a velocity."""
    if drive.velocity_ned is not None and drive.waypoints_ned:
        return f"leader drive {drive.drive_id}: both a velocity and waypoints"
    if drive.duration_s is not None and drive.velocity_ned is None:
        return f"leader drive {drive.drive_id}: a duration without a velocity"
    return ""
