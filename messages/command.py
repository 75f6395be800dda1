"""Ground station -> agent commands and their acknowledgements (over Zenoh).

``bf/<fleet>/<id>/command`` carries a :class:`FleetCommand` addressed to one agent (the ground
station publishes one per selected vehicle at the same moment); the agent answers on
``bf/<fleet>/<id>/command/ack`` with a :class:`CommandAck` that echoes ``request_id``.
Arming, takeoff and landing go to the autopilots over MAVLink; the agents take the mission
commands below (and ``land``/``stop`` too, so an operator reaches a vehicle whose link to the
ground station is only Zenoh).

``bf/<fleet>/<id>/command/formation`` carries a :class:`FormationChange`: a new desired formation
(paper 002's formation changes at run time, eq. 20 with new ``beta*_ij``), optionally with a
leader that holds its position while the others follow its bearings. The agent answers through
its status (``VehicleStatus.formation_id``); one it cannot fly is counted and dropped.
"""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

from messages.codec import Payload
from messages.limits import LIST_MAX, SEQ_MAX, AgentId, Angle, Name, PositionVec3

COMMAND_TOPIC = "command"
ACK_TOPIC = "command/ack"
FORMATION_TOPIC = "command/formation"

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
    ``leader`` is the vehicle that holds its position (``None``: no leader)."""

    target: AgentId
    formation_id: FormationId
    agents: Annotated[list[FormationSlot], msgspec.Meta(min_length=2, max_length=LIST_MAX)]
    name: Name = ""
    leader: AgentId | None = None


def formation_problem(change: FormationChange, fleet_ids: set[int] | frozenset[int]) -> str:
    """Why a fleet with ``fleet_ids`` cannot fly ``change`` (``""``: it can): duplicate,
    unknown or missing vehicle ids, an unknown leader, coincident vehicles."""
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
    seen: set[tuple[float, float, float]] = set()
    for a in change.agents:
        if a.position_ned in seen:
            return f"coincident vehicles in formation {change.formation_id}"
        seen.add(a.position_ned)
    return ""
