"""The words that cross processes, defined once: alarms, phases, drop reasons and core modes.

An alarm travels as text in :attr:`messages.agent.AgentStatus.alarms`: its kind, and for the
kinds about one neighbour the neighbour's id after a colon (``peer_lost:3``). Senders build it
with :func:`alarm_text`, receivers read it with :func:`alarm_kind`, so both ends use the same
word by construction (they once did not: the daemon raised ``rigidity_lost`` while the ground
station looked for ``rigidity_low``).

The daemon's :class:`Phase` travels in :attr:`messages.agent.AgentStatus.phase`, the
:class:`DropReason` words are the keys of its ``dropped`` counters (optionally behind a
:class:`DropScope` prefix, :func:`drop_key`), and :data:`Mode` names the agent core's modes
(:data:`FleetMode` the ones a fleet file may choose). All are ``str`` on the wire (a
``StrEnum`` member *is* its string), so the schema did not change when they became types.
"""

from __future__ import annotations

import typing
from enum import StrEnum
from typing import Literal

Mode = Literal["active", "random", "formation", "formation-active", "hold", "rigidity-tracking"]
"""The agent core's modes (:mod:`onboard.core.modes` maps each to its layers)."""
MODES: tuple[Mode, ...] = typing.get_args(Mode)
FleetMode = Literal["active", "random", "formation", "formation-active", "hold"]
"""The modes a fleet file's ``mode`` may name (paper 003's maintenance is its ``[rigidity]``
table on top of one of them, not a mode of its own)."""
FLEET_MODES: tuple[FleetMode, ...] = typing.get_args(FleetMode)


class Phase(StrEnum):
    """The agent daemon's phase (:class:`onboard.daemon.loop.DaemonState`)."""

    CONNECTING = "connecting"
    """No autopilot link yet."""
    WAITING = "waiting"
    """Linked; the estimators warm up (or a readiness check fails)."""
    READY = "ready"
    """Ready for ``start``."""
    FLYING = "flying"
    """The core's setpoints go to the autopilot."""
    HOLDING = "holding"
    """The operator's ``hold`` (or a guard) holds the vehicle."""
    PILOT = "pilot"
    """A pilot took the vehicle (a stick mode, :func:`onboard.daemon.guards.takeover_kind`)."""
    FAILSAFE = "failsafe"
    """The autopilot left OFFBOARD/GUIDED by itself (its failsafe)."""
    LANDING = "landing"
    """The operator's ``land``."""
    STOPPED = "stopped"
    """The daemon stopped."""


class Alarm(StrEnum):
    """Every alarm kind, with what raises it."""

    PEER_LOST = "peer_lost"
    """Agent: a neighbour's liveliness or messages are gone (``peer_lost:<id>``)."""
    PEER_CLOCK = "peer_clock"
    """Agent: a neighbour's clock disagrees with this vehicle's (``peer_clock:<id>``)."""
    RIGIDITY_LOST = "rigidity_lost"
    """Agent: without its lost neighbours the sensing graph is no longer rigid; it holds."""
    AUTOPILOT_STALE = "autopilot_stale"
    """Agent: the autopilot's telemetry is older than the stale limit; it holds."""
    BEARINGS_STALE = "bearings_stale"
    """Agent: the camera's bearings are older than the stale limit; it holds."""
    FAILSAFE = "failsafe"
    """Agent: the autopilot left offboard/guided control by itself (its failsafe: a stalled
    stream, a lost link, a hold/land/return mode); the operator's ``start`` rejoins. Ground
    station: the autopilot reports a critical system state."""
    PILOT_TAKEOVER = "pilot_takeover"
    """Agent: a pilot switched the autopilot to a manual mode; the pilot has the vehicle (a
    ``start`` is refused until the autopilot is in a hold mode again)."""
    AUTOPILOT_LOST = "autopilot_lost"
    """Agent: no autopilot heartbeat within the link's limit (or never connected): the core
    does not run; the status still goes out."""
    TELEMETRY_IMPLAUSIBLE = "telemetry_implausible"
    """Agent: the autopilot sent finite but physically impossible values (dropped); it holds
    for a moment."""
    ESTIMATE_NONFINITE = "estimate_nonfinite"
    """Agent: its own estimates are not finite (its status carries zeros for them); it holds."""
    ESTIMATE_DIVERGING = "estimate_diverging"
    """Agent: the core produced a non-finite setpoint; it holds."""
    ALTITUDE_FLOOR = "altitude_floor"
    """Agent: the setpoint was bounded by the minimum altitude."""
    ALTITUDE_CEILING = "altitude_ceiling"
    """Agent: the setpoint was bounded by the maximum altitude."""
    FENCE = "fence"
    """Agent: the setpoint was bounded by the horizontal fence."""
    STEP_ERROR = "step_error"
    """Agent: one core tick raised; it was counted and the vehicle holds for a moment."""
    CLOCK_JUMP = "clock_jump"
    """Agent: a simulation or autopilot time implausibly far from its own was rejected."""
    CLOCK_RESYNC = "clock_resync"
    """Agent: it followed a new timeline (a restarted simulator) after consistent samples."""
    HEARTBEAT_LOST = "heartbeat_lost"
    """Ground station: no autopilot heartbeat within its limit."""
    BATTERY_LOW = "battery_low"
    """Ground station: battery below its limit."""
    AGENT_LOST = "agent_lost"
    """Ground station: the vehicle's agent daemon is gone or silent."""


PER_PEER = frozenset({Alarm.PEER_LOST, Alarm.PEER_CLOCK})
"""The kinds that name one neighbour."""


def alarm_text(kind: Alarm, peer: int | None = None) -> str:
    """The wire form of an alarm: ``kind``, or ``kind:peer`` for the per-neighbour kinds."""
    if (kind in PER_PEER) != (peer is not None):
        raise ValueError(
            f"alarm {kind.value!r} {'needs' if kind in PER_PEER else 'takes no'} peer id"
        )
    return kind.value if peer is None else f"{kind.value}:{peer}"


def alarm_kind(text: str) -> Alarm | None:
    """The kind of an alarm's wire form, or None for a word this version does not know."""
    try:
        return Alarm(text.partition(":")[0])
    except ValueError:
        return None
