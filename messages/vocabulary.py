"""The words that cross processes, defined once: alarms, phases, drop reasons and core modes.

An alarm travels as text in :attr:`messages.agent.VehicleStatus.alarms`: its kind, and for the
kinds about one neighbour the neighbour's id after a colon (``peer_lost:3``). Senders build it
with :func:`alarm_text`, receivers read it with :func:`parse_alarm` (:func:`alarm_kind` for the
kind alone), so both ends use the same word and format by construction (they once did not: the
daemon raised ``rigidity_lost`` while the ground station looked for ``rigidity_low``).

The daemon's :class:`Phase` travels in :attr:`messages.agent.VehicleStatus.phase`, the
:class:`DropReason` words are the keys of its ``dropped`` counters (optionally behind a
:class:`DropScope` prefix, :func:`drop_key`), and :data:`Mode` names the agent core's modes
(:data:`FleetMode` the ones a fleet file may choose). All are ``str`` on the wire (a
``StrEnum`` member *is* its string), so the schema did not change when they became types.
"""

from __future__ import annotations

import typing
from enum import StrEnum
from typing import Literal, NamedTuple

Mode = Literal["active", "random", "formation", "formation-active", "hold", "rigidity-tracking"]
"""The agent core's modes (:mod:`onboard.core.modes` maps each to its layers)."""
MODES: tuple[Mode, ...] = typing.get_args(Mode)
FleetMode = Literal["active", "random", "formation", "formation-active", "hold"]
"""The modes a fleet file's ``mode`` may name (paper 003's maintenance is its ``[rigidity]``
table on top of one of them, not a mode of its own)."""
FLEET_MODES: tuple[FleetMode, ...] = typing.get_args(FleetMode)
Localization = Literal["paper000", "paper002"]
"""Which estimate of the team's positions the core flies on (a fleet file's ``[core]
localization``): paper 000's filter (eq. 6, :mod:`onboard.estimation.localization`) or paper
002's distributed gradient localization with one SfM range per reciprocal edge (eq. 16-17 and
22, :mod:`onboard.core.localization002`)."""
LOCALIZATIONS: tuple[Localization, ...] = typing.get_args(Localization)


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
    RIGIDITY_UNCERTAIN = "rigidity_uncertain"
    """Agent: the distributed rigidity-eigenvalue estimate's uncertainty exceeds 10% of it (it
    lags a fast-changing framework): the reported eigenvalue is not to be trusted; no hold."""
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
    TICKS_LATE = "ticks_late"
    """Agent: its core ticks ran late for over a quarter of the last 2 s (the machine is too
    slow for the simulation speed; onboard/daemon/lateness.py): its estimates degrade."""
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


class AlarmWord(NamedTuple):
    """One alarm read back from its wire form: its kind, and the neighbour for
    :data:`PER_PEER` kinds (``None`` for the others)."""

    kind: Alarm
    peer: int | None


def parse_alarm(text: str) -> AlarmWord | None:
    """The one parser of an alarm's wire form (the inverse of :func:`alarm_text`), or ``None``
    for a word this version does not know or a per-neighbour kind without a valid id."""
    word, sep, peer_text = text.partition(":")
    try:
        kind = Alarm(word)
    except ValueError:
        return None
    if kind not in PER_PEER:
        return AlarmWord(kind, None) if not sep else None
    if not (peer_text.isascii() and peer_text.isdigit()):
        return None
    return AlarmWord(kind, int(peer_text))


def alarm_kind(text: str) -> Alarm | None:
    """The kind of an alarm's wire form, or None for a word this version does not know."""
    parsed = parse_alarm(text)
    return None if parsed is None else parsed.kind


class DropReason(StrEnum):
    """Why an input was counted and dropped: the keys of ``dropped`` counters
    (:attr:`messages.agent.VehicleStatus.dropped`), behind a :class:`DropScope` when the
    input was not a peer message (:func:`drop_key`)."""

    OVERSIZE = "oversize"
    """The codec: larger than ``MAX_PAYLOAD_BYTES``."""
    MALFORMED = "malformed"
    """The codec (not msgpack, not the schema) or a payload's inner consistency."""
    OUT_OF_RANGE = "out_of_range"
    """The codec: a field outside its bound (:mod:`messages.limits`)."""
    VERSION = "version"
    """The codec: another schema version."""
    UNKNOWN_SENDER = "unknown_sender"
    """The codec: a sender not in the fleet."""
    NONFINITE = "nonfinite"
    """The codec (or a camera): a NaN or an infinity."""
    SENDER_MISMATCH = "sender_mismatch"
    """A payload on another sender's key."""
    BAD_KEY = "bad_key"
    """A key expression this fleet does not use."""
    INJECTED_LOSS = "injected_loss"
    """Fault injection (``zenoh.inject_loss``)."""
    FOREIGN = "foreign"
    """A command for another agent, or a topic this version does not know."""
    WRONG_FLEET = "wrong_fleet"
    """Ground station: a key under another fleet."""
    SEQ_RESYNC = "seq_resync"
    """Replay window: a sender restarted its sequence numbers (the message is admitted)."""
    SEQ_REPLAY = "seq_replay"
    """Replay window: a sequence number seen before."""
    SEQ_WINDOW = "seq_window"
    """Replay window: a sequence number outside the window."""
    STEP_EXCEPTION = "step_exception"
    """An exception escaped one core tick."""
    STATUS_EXCEPTION = "status_exception"
    """An exception escaped building the status."""
    CLOCK_JUMP = "clock_jump"
    """A simulation or autopilot time implausibly far from the daemon's (:attr:`Alarm.CLOCK_JUMP`)."""
    CLOCK_RESYNC = "clock_resync"
    """The daemon followed a new simulation timeline (:attr:`Alarm.CLOCK_RESYNC`)."""
    NOT_NEIGHBOUR = "not_neighbour"
    """Core: a payload from an agent that is no neighbour for its kind."""
    UNKNOWN_TYPE = "unknown_type"
    """Core: a payload kind no layer of this mode handles."""
    FUTURE_STAMP = "future_stamp"
    """A stamp further ahead than ``STAMP_FUTURE_MAX_S``."""
    TIME_BACKWARDS = "time_backwards"
    """Core: a tick earlier than the previous one."""
    NONFINITE_OWN = "nonfinite_own"
    """Core: its own measurements are not finite."""
    BAD_BEARING = "bad_bearing"
    """Core: a bearing that is not a finite unit vector."""
    BAD_RANGE = "bad_range"
    """Core: a measured range that is not finite or outside ``messages.limits.RANGE_MIN_M ..
    RANGE_MAX_M``."""
    UNKNOWN_EDGE = "unknown_edge"
    """Core: an SfM share for an edge it does not observe."""
    UNKNOWN_NAME = "unknown_name"
    """Core: an SfM share with a name it does not know."""
    IMPLAUSIBLE_JUMP = "implausible_jump"
    """Core: a neighbour's consensus state or localization estimate that jumped further from the
    last one taken than an estimate moves between two samples, not (yet) confirmed by the
    sender's next sample (:class:`onboard.core.peers.JumpGate`; limits
    ``onboard.core.scale.E_STEP_MAX_HIGHS``, ``CONSENSUS_STEP_MAX``, ``LOC_STEP_MAX_M``,
    ``LOC_STEP_MAX_RAD``)."""
    SFM_HOLE = "sfm_hole"
    """Core: SfM frames in a gap of the history (not used)."""
    UNKNOWN_TARGET = "unknown_target"
    """Camera: a bearing to a vehicle outside the fleet."""
    NOT_UNIT = "not_unit"
    """Camera: a bearing that is not a unit vector."""
    SENDER = "sender"
    """Camera: an image from another agent on this agent's key."""
    ID = "id"
    """Camera: a camera id the rig does not have."""
    NO_ATTITUDE = "no_attitude"
    """Camera: no autopilot attitude near the frame's capture time."""
    ATTITUDE_ERROR = "attitude_error"
    """Camera: the attitude interpolation raised."""
    DEVICE_READ = "device_read"
    """Camera: the capture device's read failed."""
    EMPTY = "empty"
    """Camera: an image without pixels or bytes (:class:`messages.image.FrameError`)."""
    DTYPE = "dtype"
    """Camera: pixels that are not uint8."""
    SIZE = "size"
    """Camera: an image of the wrong shape or size."""
    ENCODING = "encoding"
    """Camera: an image encoding that is unknown or does not decode."""
    IMPLAUSIBLE = "implausible"
    """MAVLink: finite but physically impossible telemetry."""


class DropScope(StrEnum):
    """Where a dropped input came from when it was not a peer message: the key's prefix."""

    CAMERA = "camera"
    CLOCK = "clock"
    COMMAND = "command"
    OWN = "own"
    OWN_STATUS = "own_status"
    CORE = "core"
    MAVLINK = "mavlink"


def drop_key(reason: DropReason, scope: DropScope | None = None) -> str:
    """The counter key on the wire: ``reason``, or ``scope_reason`` (``camera_not_unit``)."""
    return reason.value if scope is None else f"{scope.value}_{reason.value}"
