"""The autopilot link's interface, its typed results and its configuration.

An :class:`AutopilotLink` is the daemon's only way to the flight controller. Two backends
implement it: :class:`onboard.autopilot.pymavlink_link.PymavlinkLink` (the main one: raw
MAVLink over UDP/TCP/serial with pymavlink) and :class:`onboard.autopilot.mavsdk_link.MavsdkLink`
(MAVSDK v4, the native binding). The agent loop calls it from its own thread:

* ``connect(url)`` waits for the autopilot's HEARTBEAT, picks the target system and detects the
  flavour (PX4 or ArduPilot) from the heartbeat's ``autopilot`` field;
* ``telemetry()`` returns a :class:`Telemetry` snapshot (never blocks);
* ``request_streams()``, ``wait_ready()``, ``arm()``, ``takeoff()``, ``land()``, ``hold()``,
  ``disarm()``, ``set_mode()`` and ``start_velocity_control()`` block until done and return an
  :class:`ActionResult` (they never raise on a refusal or a timeout);
* ``set_setpoint(setpoint)`` stores the latest :class:`messages.agent.Setpoint` (saturated,
  NaN-safe); a
  background sender streams it at :attr:`LinkConfig.rate_hz` while velocity control is active;
* ``stop_streaming()`` stops the stream (the autopilot then fails safe: PX4 leaves OFFBOARD after
  ``COM_OF_LOSS_T``, ArduPilot zeroes the velocity after ``GUID_TIMEOUT``), and the link stops it by
  itself when the pilot takes the vehicle out of OFFBOARD/GUIDED, reporting a :class:`LinkEvent`;
* ``close()`` stops every thread and releases the connection.

Frames: ``v_body`` is the velocity in the vehicle's heading frame (FRD with roll and pitch
removed, ``v_body = R_z(yaw)^T v_ned``): the frame of the agent model ``pdot = R_z(psi) u``
(``onboard/geometry.py``) and of MAVLink's ``MAV_FRAME_BODY_NED`` velocity setpoints, which
both autopilots rotate by the current yaw only.
"""

from __future__ import annotations

import enum
import math
import time
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field

from messages.agent import Setpoint

Vec3 = tuple[float, float, float]


class Flavour(enum.Enum):
    """Which autopilot firmware is on the other end (from HEARTBEAT ``autopilot``)."""

    PX4 = "px4"
    ARDUPILOT = "ardupilot"


class StreamState(enum.Enum):
    """Where the velocity-setpoint stream is."""

    IDLE = "idle"
    """Nothing is sent."""
    PRIMING = "priming"
    """Setpoints are sent, the control mode is being entered (PX4 needs setpoints first)."""
    ACTIVE = "active"
    """The vehicle is in OFFBOARD/GUIDED and flies the streamed setpoints."""


DEFAULT_STREAM_RATES_HZ: Mapping[str, float] = {
    "ATTITUDE": 20.0,
    "LOCAL_POSITION_NED": 20.0,
    "GLOBAL_POSITION_INT": 5.0,
    "EXTENDED_SYS_STATE": 2.0,
    "SYS_STATUS": 2.0,
    "BATTERY_STATUS": 0.5,
}
"""Telemetry the link needs, with the rates it asks an ArduPilot for."""


@dataclass(frozen=True)
class LinkConfig:
    """Tuning of a link; defaults suit a companion computer next to a real autopilot."""

    rate_hz: float = 50.0
    """Setpoint stream rate (wall clock); the daemon passes ``[rates] setpoint`` (50 Hz)."""
    max_speed_xy_m_s: float = 2.0
    """Saturation of the horizontal body velocity (norm)."""
    max_speed_z_m_s: float = 1.0
    """Saturation of the vertical body velocity."""
    max_yaw_rate_rad_s: float = 0.8
    """Saturation of the yaw rate."""
    setpoint_timeout_s: float = 0.5
    """While streaming, a setpoint older than this is replaced by zero velocity (hold)."""
    stale_after_s: float = 0.5
    """Attitude/velocity older than this is flagged stale in :class:`Telemetry`."""
    heartbeat_timeout_s: float = 3.0
    """A heartbeat older than this means the link is lost."""
    ack_timeout_s: float = 1.0
    """Wait this long for a COMMAND_ACK before re-sending the command."""
    command_sends: int = 3
    """Sends of one command (the first plus re-sends) before it counts as timed out."""
    retry_timeout_s: float = 30.0
    """Refused actions are retried with backoff for at most this long."""
    backoff_initial_s: float = 0.5
    backoff_max_s: float = 4.0
    mode_settle_s: float = 1.0
    """After a mode change is seen, watch this long for a revert before trusting it."""
    source_system: int = 245
    source_component: int = 191
    """MAV_COMP_ID_ONBOARD_COMPUTER."""
    system_id: int | None = None
    """Talk only to this system id (``None``: the first autopilot heard)."""
    stream_rates_hz: Mapping[str, float] = field(
        default_factory=lambda: dict(DEFAULT_STREAM_RATES_HZ)
    )
    clock: Callable[[], float] = time.monotonic
    """Wall clock used for ages and timeouts (injected for tests)."""
    signing_key: bytes | None = field(default=None, repr=False)
    """MAVLink 2 signing key of this autopilot link: sign everything sent, accept only what is
    correctly signed (:mod:`messages.mavsign`); ``None``: no signing."""
    signing_link_id: int = 1
    """Link id in our signatures (the autopilot's streams are per link id, system, component)."""

    def __post_init__(self) -> None:
        for name in (
            "rate_hz",
            "max_speed_xy_m_s",
            "max_speed_z_m_s",
            "max_yaw_rate_rad_s",
            "setpoint_timeout_s",
            "stale_after_s",
            "heartbeat_timeout_s",
            "ack_timeout_s",
            "backoff_initial_s",
            "backoff_max_s",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be finite and > 0, got {value}")
        if self.command_sends < 1:
            raise ValueError(f"command_sends must be >= 1, got {self.command_sends}")
        if self.signing_key is not None and len(self.signing_key) != 32:
            raise ValueError(f"signing_key must be 32 bytes, got {len(self.signing_key)}")
        if not 0 <= self.signing_link_id <= 255:
            raise ValueError(f"signing_link_id must be in 0..255, got {self.signing_link_id}")
        if not (math.isfinite(self.retry_timeout_s) and self.retry_timeout_s >= 0.0):
            raise ValueError(f"retry_timeout_s must be finite and >= 0, got {self.retry_timeout_s}")


@dataclass(frozen=True)
class LinkCounters:
    """What the link received, dropped and sent since it connected."""

    received: int = 0
    """Valid messages from the target autopilot."""
    bad_data: int = 0
    """Garbage bytes, bad CRCs, unparsable packets (pymavlink ``BAD_DATA``)."""
    foreign: int = 0
    """Valid messages from another system or component (dropped)."""
    invalid_values: int = 0
    """Messages from the target with NaN/inf where a number was expected (dropped)."""
    setpoints_sent: int = 0
    nan_setpoints: int = 0
    """``set_setpoint`` calls with a NaN/inf component (replaced by zero)."""
    saturated_setpoints: int = 0
    stale_setpoints: int = 0
    """Stream periods where the agent's setpoint was too old and zero was sent instead."""
    link_errors: int = 0
    """Socket errors while reading or writing."""
    signed_ok: int = 0
    """With signing on: correctly signed messages (before the system/component checks)."""
    bad_signature: int = 0
    """With signing on: wrong signature (dropped before anything looks at them)."""
    unsigned_rejected: int = 0
    """With signing on: unsigned messages not on the allow-list (dropped)."""
    replayed: int = 0
    """With signing on: correctly signed but not newer than the stream's last (dropped)."""
    signing_unavailable: int = 0
    """With signing on: sends skipped while pymavlink still spoke MAVLink 1 (it switches to 2
    on the autopilot's first v2 frame), which cannot sign."""


SIGNING_REJECTIONS = ("bad_signature", "unsigned_rejected", "replayed", "signing_unavailable")


def signing_rejections(counters: LinkCounters) -> dict[str, int]:
    """The MAVLink signing rejections that are not zero (none without signing or attack): what
    the daemon adds to its status's ``dropped`` as ``mavlink_<name>``."""
    return {k: v for k in SIGNING_REJECTIONS if (v := getattr(counters, k))}


@dataclass(frozen=True)
class Telemetry:
    """One consistent snapshot of what the autopilot reported (never simulator truth)."""

    t_s: float
    """Link clock when the snapshot was taken."""
    connected: bool
    flavour: Flavour | None
    system_id: int | None
    t_boot_s: float | None
    """Autopilot time (``time_boot_ms``) of the latest attitude or position message."""
    t_boot_attitude_s: float | None
    """Autopilot time of the attitude (roll, pitch, yaw, yaw rate) held."""
    t_boot_velocity_s: float | None
    """Autopilot time of the velocity (``v_ned``) held. Autopilots stream attitude and
    position separately, so the two are usually a few milliseconds apart."""
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    yaw_rate_rad_s: float
    v_ned: Vec3
    v_body: Vec3
    """Heading-frame velocity ``R_z(yaw)^T v_ned`` (module docstring)."""
    altitude_m: float
    """Height above the autopilot's local origin (``-z`` of LOCAL_POSITION_NED)."""
    north_m: float
    east_m: float
    """Horizontal position from the autopilot's local origin (``x``, ``y`` of
    LOCAL_POSITION_NED; the origin is where its estimator started)."""
    mode: str
    armed: bool
    landed_state: int
    """MAV_LANDED_STATE: 0 unknown, 1 on ground, 2 in air, 3 taking off, 4 landing."""
    ready: bool
    """Pre-arm checks pass (SYS_STATUS ``MAV_SYS_STATUS_PREARM_CHECK`` healthy)."""
    battery_remaining_pct: float | None
    battery_voltage_v: float | None
    heartbeat_age_s: float
    attitude_age_s: float
    velocity_age_s: float
    stale_heartbeat: bool
    stale_attitude: bool
    stale_velocity: bool
    stream_state: StreamState
    setpoint_v_body: Vec3
    """The (saturated) setpoint being streamed."""
    setpoint_yaw_rate_rad_s: float
    counters: LinkCounters
    implausible_age_s: float = math.inf
    """Seconds since the autopilot last sent finite but physically impossible telemetry
    (dropped; ``inf``: never)."""
    implausible: int = 0
    """Telemetry messages dropped as implausible."""

    @property
    def in_air(self) -> bool:
        return self.landed_state in (2, 3, 4)

    @property
    def stale(self) -> bool:
        """Any input the agent relies on is stale."""
        return self.stale_heartbeat or self.stale_attitude or self.stale_velocity


@dataclass(frozen=True)
class ActionResult:
    """How one blocking action ended."""

    action: str
    ok: bool
    result: int | None
    """Last MAV_RESULT received (``None``: no ACK, or the action needs none)."""
    attempts: int
    """Commands sent that were answered or timed out (retries included)."""
    elapsed_s: float
    reasons: tuple[str, ...] = ()
    """STATUSTEXT messages the autopilot sent while the action ran (why it refused)."""
    detail: str = ""

    @property
    def timed_out(self) -> bool:
        return not self.ok and self.result is None

    @property
    def result_name(self) -> str:
        return result_name(self.result)


@dataclass(frozen=True)
class LinkEvent:
    """Something the agent loop should know about (drained with ``events()``)."""

    t_s: float
    kind: str
    """``stream_stopped``, ``mode_changed``, ``armed``, ``disarmed``, ``link_lost``,
    ``link_restored``, ``mode_reverted``, ``statustext``."""
    detail: str


_RESULT_NAMES = {
    0: "ACCEPTED",
    1: "TEMPORARILY_REJECTED",
    2: "DENIED",
    3: "UNSUPPORTED",
    4: "FAILED",
    5: "IN_PROGRESS",
    6: "CANCELLED",
}


def result_name(result: int | None) -> str:
    """MAV_RESULT name (``TIMEOUT`` for ``None``)."""
    if result is None:
        return "TIMEOUT"
    return _RESULT_NAMES.get(result, f"RESULT_{result}")


SERIAL_DEFAULT_BAUD = 115200
"""pymavlink's default; PX4's companion port (TELEM2) runs at 921600 by default."""


def serial_device(url: str) -> tuple[str, int] | None:
    """A serial link URL as ``(device, baud)``; ``None`` for a network URL.

    Accepted: ``/dev/ttyACM0``, ``/dev/ttyACM0:921600``, ``serial:/dev/ttyACM0:921600``,
    MAVSDK's ``serial:///dev/ttyACM0:921600`` and ``COM3[:57600]``. Without a baud rate,
    :data:`SERIAL_DEFAULT_BAUD`. Raises ``ValueError`` for a baud rate that is not a positive
    integer.
    """
    rest = url
    for prefix in ("serial://", "serial:"):
        if url.startswith(prefix):
            rest = url[len(prefix) :]
            break
    else:
        if not (url.startswith("/dev/") or url.upper().startswith("COM")):
            return None
    device, sep, baud_text = rest.rpartition(":")
    if not sep:
        return rest, SERIAL_DEFAULT_BAUD
    if not baud_text.isdigit() or int(baud_text) <= 0:
        raise ValueError(f"{url!r}: the baud rate after the last ':' must be a positive integer")
    return device, int(baud_text)


def wrong_system_message(url: str, wanted: int, heard: Iterable[int], timeout_s: float) -> str:
    """The error of a link that heard autopilots, but not the system it must talk to."""
    ids = ", ".join(str(i) for i in sorted(set(heard)))
    return (
        f"no heartbeat of autopilot system {wanted} on {url!r} within {timeout_s} s, only of "
        f"system {ids}: set the autopilot's MAV_SYS_ID (PX4) or MAV_SYSID (ArduPilot 4.7; "
        f"SYSID_THISMAV before) to "
        f"{wanted}, or the fleet's [mavlink] system_id_base / the agent's --system-id"
    )


class LinkError(RuntimeError):
    """The link could not be opened (bad URL, no autopilot heard, unknown autopilot)."""


class AutopilotLink(ABC):
    """What the daemon needs from an autopilot (module docstring)."""

    config: LinkConfig
    setpoint_ages_s: deque[float]
    """For each setpoint sent with a ``source_t``: its age when it went on the wire (link
    clock, seconds; a bounded window). How stale the stream is: it includes the time the
    newest frame waits for the next one (up to a camera period)."""
    frame_to_wire_s: deque[float]
    """For each new ``source_t`` (a camera frame's first setpoint): its age when the first
    setpoint based on it went on the wire. The loop's latency, capture -> Zenoh -> core tick ->
    wire, without the camera's own sampling interval (issue 27's bearing -> setpoint target)."""

    @property
    @abstractmethod
    def flavour(self) -> Flavour | None: ...

    @property
    @abstractmethod
    def target_system(self) -> int | None: ...

    @abstractmethod
    def connect(self, url: str, timeout_s: float = 10.0) -> None:
        """Open ``url`` and wait for the autopilot's heartbeat; raises :class:`LinkError`."""

    @abstractmethod
    def telemetry(self) -> Telemetry: ...

    @abstractmethod
    def request_streams(self, rates_hz: Mapping[str, float] | None = None) -> ActionResult:
        """Ask for the telemetry the link needs and wait until it arrives."""

    @abstractmethod
    def wait_ready(self, timeout_s: float = 60.0) -> ActionResult:
        """Wait until the pre-arm checks pass (the estimator is ready)."""

    @abstractmethod
    def set_mode(self, mode: str, timeout_s: float | None = None) -> ActionResult: ...

    @abstractmethod
    def arm(self, timeout_s: float | None = None) -> ActionResult: ...

    @abstractmethod
    def takeoff(
        self, altitude_m: float, wait: bool = True, timeout_s: float | None = None
    ) -> ActionResult: ...

    @abstractmethod
    def land(self, wait: bool = False, timeout_s: float | None = None) -> ActionResult: ...

    @abstractmethod
    def hold(self, timeout_s: float | None = None) -> ActionResult: ...

    @abstractmethod
    def disarm(self, force: bool = False, timeout_s: float | None = None) -> ActionResult: ...

    @abstractmethod
    def start_velocity_control(self, timeout_s: float | None = None) -> ActionResult: ...

    @abstractmethod
    def set_setpoint(self, setpoint: Setpoint, source_t: float | None = None) -> Setpoint:
        """Store the command to stream (heading-frame ``v_body``, yaw rate); returns it
        saturated and NaN-free. ``source_t`` (link
        clock) is when the newest measurement it is based on was taken: each send then records
        its age in :attr:`setpoint_ages_s`, and the first send of a new ``source_t`` in
        :attr:`frame_to_wire_s` (the daemon's bearing-to-wire latency). A backend that streams
        sends a setpoint with a new ``source_t`` at once, not at the next stream period."""

    @abstractmethod
    def stop_streaming(self, reason: str = "requested") -> None: ...

    @abstractmethod
    def events(self) -> list[LinkEvent]:
        """Events since the last call (oldest first)."""

    @abstractmethod
    def close(self) -> None: ...

    def __enter__(self) -> AutopilotLink:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()
