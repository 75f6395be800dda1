"""What the ground station knows about each autopilot from the MAVLink messages it hears.

Pure state, no sockets: :class:`MavlinkState` folds parsed pymavlink messages (any object with
pymavlink's attribute names, ``get_type()``, ``get_srcSystem()``, ``get_srcComponent()`` and
``get_seq()``) with their receive times into one :class:`SystemTelemetry` per system id.
:mod:`groundstation.gcs.mavlink_listener` feeds it from a socket, tests feed it directly.

Loss is measured from MAVLink 2 sequence numbers: every sender increments an 8-bit counter per
packet, so a jump of ``k > 1`` means ``k - 1`` packets were lost on the way (counted per system
and component over a window of recent packets, so the figure recovers after a bad spell).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from messages import mavlink as mv

MAV_TYPE_GCS = 6
MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_AUTOPILOT_INVALID = 8
MAV_STATE_CRITICAL = 5
MAV_STATE_EMERGENCY = 6

LOSS_WINDOW_PACKETS = 256
"""Loss percentage is computed over this many received packets per (system, component)."""
REORDER_GAP = 200
"""A sequence jump larger than this is taken as a restart or reordering, not as loss."""


def flavour_name(autopilot: int) -> str:
    """HEARTBEAT ``autopilot`` field -> ``"px4"``, ``"ardupilot"`` or ``"other"``."""
    if autopilot == mv.MAV_AUTOPILOT_PX4:
        return "px4"
    if autopilot == mv.MAV_AUTOPILOT_ARDUPILOTMEGA:
        return "ardupilot"
    return "other"


def heartbeat_mode_name(autopilot: int, base_mode: int, custom_mode: int) -> str:
    """Name of the mode a HEARTBEAT shows, with the encodings of :mod:`messages.mavlink`
    (PX4: ``(main << 16) | (sub << 24)``; ArduCopter: the mode number)."""
    if not base_mode & mv.BASE_MODE_CUSTOM:
        return f"BASE({base_mode})"
    if autopilot == mv.MAV_AUTOPILOT_PX4:
        main, sub = mv.px4_decode_custom_mode(custom_mode)
        name = mv.px4_mode_name(main, sub)
        return name if name is not None else f"PX4({main},{sub})"
    if autopilot == mv.MAV_AUTOPILOT_ARDUPILOTMEGA:
        return mv.COPTER_MODE_NAMES.get(custom_mode, f"COPTER({custom_mode})")
    return f"CUSTOM({custom_mode})"


def is_vehicle_heartbeat(mav_type: int, autopilot: int) -> bool:
    """True for a flight controller's heartbeat (not a GCS's or a companion computer's)."""
    return autopilot != MAV_AUTOPILOT_INVALID and mav_type not in (
        MAV_TYPE_GCS,
        MAV_TYPE_ONBOARD_CONTROLLER,
    )


def sequence_gap(previous: int, current: int) -> int:
    """Packets lost between two consecutive 8-bit sequence numbers (0 if in order; 0 also for a
    jump larger than :data:`REORDER_GAP`, which is a restart or reordering rather than loss)."""
    gap = (current - previous - 1) % 256
    return 0 if gap > REORDER_GAP else gap


@dataclass
class LossWindow:
    """Lost-packet counts of the last :data:`LOSS_WINDOW_PACKETS` packets of one sender."""

    last_seq: int | None = None
    gaps: deque[int] = field(default_factory=lambda: deque(maxlen=LOSS_WINDOW_PACKETS))
    received: int = 0
    lost: int = 0

    def add(self, seq: int) -> None:
        gap = 0 if self.last_seq is None else sequence_gap(self.last_seq, seq)
        self.last_seq = seq
        self.gaps.append(gap)
        self.received += 1
        self.lost += gap

    def loss_pct(self) -> float:
        """Lost / (lost + received) over the window, in percent."""
        lost = sum(self.gaps)
        total = lost + len(self.gaps)
        return 100.0 * lost / total if total else 0.0


@dataclass
class SystemTelemetry:
    """The latest of everything one autopilot (system id) said, with receive times (s)."""

    sysid: int
    first_seen_s: float
    last_message_s: float
    last_heartbeat_s: float | None = None
    flavour: str = "other"
    mode: str | None = None
    """``None`` until the first HEARTBEAT."""
    armed: bool | None = None
    system_status: int = 0
    battery_pct: float | None = None
    altitude_m: float | None = None
    speed_m_s: float | None = None
    in_air: bool | None = None
    statustext: str = ""
    messages: int = 0
    loss: dict[int, LossWindow] = field(default_factory=dict)
    """Per source component."""
    last_seen_s: dict[str, float] = field(default_factory=dict)
    """Receive time of the newest message of each type (what is streaming, what is not)."""

    def loss_pct(self) -> float:
        """Loss over all components, weighted by their packet counts."""
        lost = sum(sum(w.gaps) for w in self.loss.values())
        total = lost + sum(len(w.gaps) for w in self.loss.values())
        return 100.0 * lost / total if total else 0.0

    def heartbeat_age_s(self, now_s: float) -> float | None:
        return None if self.last_heartbeat_s is None else now_s - self.last_heartbeat_s


@dataclass(frozen=True)
class Ack:
    """One COMMAND_ACK: who answered which command with what, and when we received it."""

    sysid: int
    command: int
    result: int
    t_s: float


@dataclass
class MavlinkState:
    """Everything heard on the ground-station link, per system id."""

    systems: dict[int, SystemTelemetry] = field(default_factory=dict)
    acks: list[Ack] = field(default_factory=list)
    counters: dict[str, int] = field(default_factory=dict)
    max_acks: int = 1000

    def count(self, reason: str, k: int = 1) -> None:
        self.counters[reason] = self.counters.get(reason, 0) + k

    def fold(self, msg: Any, t_s: float) -> SystemTelemetry | None:
        """Fold one parsed message received at ``t_s``; returns the system it updated (``None``
        for messages from ground stations and companion computers, which are only counted)."""
        kind = msg.get_type()
        sysid = int(msg.get_srcSystem())
        if kind == "HEARTBEAT" and not is_vehicle_heartbeat(msg.type, msg.autopilot):
            self.count("other_heartbeats")
            return None
        sys = self.systems.get(sysid)
        if sys is None:  # telemetry before the first heartbeat also reveals a vehicle
            sys = self.systems[sysid] = SystemTelemetry(sysid, t_s, t_s)
        sys.last_message_s = t_s
        sys.last_seen_s[kind] = t_s
        sys.messages += 1
        window = sys.loss.setdefault(int(msg.get_srcComponent()), LossWindow())
        window.add(int(msg.get_seq()))
        handler = _HANDLERS.get(kind)
        if handler is not None:
            if not _finite_fields(msg):
                self.count("nonfinite")
                return sys
            handler(self, sys, msg, t_s)
        return sys


def _finite_fields(msg: Any) -> bool:
    for name in msg.get_fieldnames():
        value = getattr(msg, name, 0)
        if isinstance(value, float) and not math.isfinite(value):
            return False
    return True


def _heartbeat(state: MavlinkState, sys: SystemTelemetry, msg: Any, t_s: float) -> None:
    sys.last_heartbeat_s = t_s
    sys.flavour = flavour_name(msg.autopilot)
    sys.mode = heartbeat_mode_name(msg.autopilot, msg.base_mode, msg.custom_mode)
    sys.armed = bool(msg.base_mode & mv.BASE_MODE_ARMED)
    sys.system_status = int(msg.system_status)


def _sys_status(state: MavlinkState, sys: SystemTelemetry, msg: Any, t_s: float) -> None:
    if msg.battery_remaining >= 0:
        sys.battery_pct = float(msg.battery_remaining)


def _battery_status(state: MavlinkState, sys: SystemTelemetry, msg: Any, t_s: float) -> None:
    if msg.battery_remaining >= 0:
        sys.battery_pct = float(msg.battery_remaining)


def _global_position(state: MavlinkState, sys: SystemTelemetry, msg: Any, t_s: float) -> None:
    sys.altitude_m = msg.relative_alt / 1000.0
    sys.speed_m_s = math.sqrt(msg.vx**2 + msg.vy**2 + msg.vz**2) / 100.0


def _local_position(state: MavlinkState, sys: SystemTelemetry, msg: Any, t_s: float) -> None:
    sys.speed_m_s = math.sqrt(msg.vx**2 + msg.vy**2 + msg.vz**2)
    if sys.altitude_m is None:  # GLOBAL_POSITION_INT's relative altitude wins when present
        sys.altitude_m = -float(msg.z)


def _extended_sys_state(state: MavlinkState, sys: SystemTelemetry, msg: Any, t_s: float) -> None:
    if msg.landed_state != mv.LANDED_UNDEFINED:
        sys.in_air = msg.landed_state != mv.LANDED_ON_GROUND


def _statustext(state: MavlinkState, sys: SystemTelemetry, msg: Any, t_s: float) -> None:
    text = msg.text
    if isinstance(text, bytes):
        text = text.decode("utf-8", "replace")
    sys.statustext = str(text).rstrip("\0")


def _command_ack(state: MavlinkState, sys: SystemTelemetry, msg: Any, t_s: float) -> None:
    state.acks.append(Ack(sys.sysid, int(msg.command), int(msg.result), t_s))
    if len(state.acks) > state.max_acks:
        del state.acks[: len(state.acks) - state.max_acks]


GCS_STREAMS_HZ: dict[str, float] = {
    "GLOBAL_POSITION_INT": 5.0,
    "SYS_STATUS": 2.0,
    "EXTENDED_SYS_STATE": 2.0,
    "BATTERY_STATUS": 0.5,
}
"""What the monitor shows (altitude and speed, battery, in the air) and the rate it asks an
ArduPilot for. ArduCopter streams nothing on a port until asked (its ``SRn_`` rates default to
0). The rates are the onboard daemons' own: the built-in simulator keeps one rate per message
for all its clients (a real ArduPilot keeps them per port), and the ground station must not
slow what a daemon asked for."""
STREAM_STALE_S = 5.0
"""A stream older than this (or never seen) is asked for again, at most this often: an
autopilot that rebooted forgets what it was asked."""


def streams_to_request(
    sys: SystemTelemetry, now_s: float, last_request_s: float | None
) -> list[tuple[str, float]]:
    """The ``(message, rate Hz)`` of :data:`GCS_STREAMS_HZ` to ask system ``sys`` for now:
    only an ArduPilot (PX4 streams to a ground station by default), only streams that are
    missing or stale, and at most once per :data:`STREAM_STALE_S`."""
    if sys.flavour != "ardupilot" or sys.last_heartbeat_s is None:
        return []
    if last_request_s is not None and now_s - last_request_s < STREAM_STALE_S:
        return []
    return [
        (name, hz)
        for name, hz in GCS_STREAMS_HZ.items()
        if now_s - sys.last_seen_s.get(name, -math.inf) > STREAM_STALE_S
    ]


_HANDLERS = {
    "HEARTBEAT": _heartbeat,
    "SYS_STATUS": _sys_status,
    "BATTERY_STATUS": _battery_status,
    "GLOBAL_POSITION_INT": _global_position,
    "LOCAL_POSITION_NED": _local_position,
    "EXTENDED_SYS_STATE": _extended_sys_state,
    "STATUSTEXT": _statustext,
    "COMMAND_ACK": _command_ack,
}
