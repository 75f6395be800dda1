"""Ground station -> agent commands and their acknowledgements (over Zenoh).

``bf/<fleet>/<id>/command`` carries a :class:`FleetCommand` addressed to one agent (the ground
station publishes one per selected vehicle at the same moment); the agent answers on
``bf/<fleet>/<id>/command/ack`` with a :class:`CommandAck` that echoes ``request_id``.
Arming, takeoff and landing go to the autopilots over MAVLink; the agents take the mission
commands below (and ``land``/``stop`` too, so an operator reaches a vehicle whose link to the
ground station is only Zenoh).
"""

from __future__ import annotations

from typing import Literal

from messages.codec import Payload

COMMAND_TOPIC = "command"
ACK_TOPIC = "command/ack"

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
