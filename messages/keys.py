"""Zenoh key expressions: ``bf/<fleet>/<agent_id>/<topic>`` (docs/design.md)."""

from __future__ import annotations

import re

PREFIX = "bf"
SIM_ENTITY = "sim"
"""The simulator publishes fleet-wide topics under ``bf/<fleet>/sim/...`` (its clock)."""

# Topics of one agent, ``bf/<fleet>/<id>/<topic>``.
STATUS_TOPIC = "status"  # messages.agent.VehicleStatus, for the ground station
PEER_TOPIC = "peer"  # one messages.envelope.PeerEnvelope per publish tick (all peer kinds)
ALIVE_TOPIC = "alive"  # liveliness token of a running agent
_NAME = re.compile(r"^[A-Za-z0-9_-]+$")


def _check_fleet(fleet: str) -> str:
    if not _NAME.match(fleet):
        raise ValueError(f"fleet name {fleet!r} must be letters, digits, '_' or '-'")
    return fleet


def key(fleet: str, agent_id: int, topic: str) -> str:
    """Key of one agent's topic, e.g. ``key("alpha", 3, "state") == "bf/alpha/3/state"``."""
    if agent_id < 0:
        raise ValueError(f"agent id must be >= 0, got {agent_id}")
    if not topic or topic.startswith("/") or topic.endswith("/") or "*" in topic:
        raise ValueError(f"bad topic {topic!r}")
    return f"{PREFIX}/{_check_fleet(fleet)}/{agent_id}/{topic}"


def alive_key(fleet: str, agent_id: int) -> str:
    """Liveliness token of a running agent."""
    return key(fleet, agent_id, ALIVE_TOPIC)


def peer_key(fleet: str, agent_id: int) -> str:
    """Key of an agent's peer envelopes (:mod:`messages.envelope`), e.g. ``bf/alpha/3/peer``:
    every kind of peer payload it sends travels on it (until issue 27, each kind had its own
    key ``.../peer/<kind>``)."""
    return key(fleet, agent_id, PEER_TOPIC)


def fleet_keys(fleet: str) -> str:
    """Everything under a fleet: what the ground station subscribes to."""
    return f"{PREFIX}/{_check_fleet(fleet)}/**"


def topic_keys(fleet: str, topic: str) -> str:
    """One topic of every agent of a fleet, e.g. ``bf/alpha/*/state``."""
    return f"{PREFIX}/{_check_fleet(fleet)}/*/{topic}"


def parse_key(k: str) -> tuple[str, int, str]:
    """Split ``bf/<fleet>/<id>/<topic>`` into ``(fleet, id, topic)``; ``ValueError`` otherwise
    (also for the simulator's ``bf/<fleet>/sim/...`` keys: check :func:`is_sim_key` first)."""
    parts = str(k).split("/", 3)
    if len(parts) != 4 or parts[0] != PREFIX or not _NAME.match(parts[1]):
        raise ValueError(f"not a bearingflock key: {k!r}")
    try:
        agent_id = int(parts[2])
    except ValueError:
        raise ValueError(f"agent id in {k!r} is not an integer") from None
    return parts[1], agent_id, parts[3]


def is_sim_key(k: str) -> bool:
    """Whether ``k`` is a fleet-wide simulator key ``bf/<fleet>/sim/<topic>``."""
    parts = str(k).split("/", 3)
    return len(parts) == 4 and parts[0] == PREFIX and parts[2] == SIM_ENTITY
