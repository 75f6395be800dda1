"""Pure logic of the autopilot link: no sockets, no threads, no clock of its own.

* flavours and modes: which firmware a HEARTBEAT comes from, the name of its mode, the
  ``DO_SET_MODE`` parameters of a mode name (encodings from :mod:`messages.mavlink`);
* frames: the heading-frame velocity ``v_body = R_z(yaw)^T v_ned`` (``onboard/geometry.py``,
  agent model ``pdot_i = R_z(psi_i) u_i``);
* safety: saturation of a velocity + yaw-rate setpoint, NaN/inf replaced by a stop;
* retries: the backoff schedule;
* :class:`TelemetryState`: folds parsed MAVLink messages (any object with pymavlink's attribute
  names and ``get_type()``) into the latest values with their receive times, dropping messages
  with non-finite numbers. The pymavlink backend runs it in its receive thread, under a lock.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from messages import mavlink as mv
from messages.limits import POSITION_MAX_M, RATE_MAX_RAD_S, SPEED_MAX_M_S
from onboard.autopilot.base import (
    Flavour,
    LinkConfig,
    LinkCounters,
    StreamState,
    Telemetry,
    Vec3,
)
from onboard.geometry import FloatArray, rot_z

MAV_TYPE_GCS = 6
MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_AUTOPILOT_INVALID = 8

CONTROL_MODE = {Flavour.PX4: "OFFBOARD", Flavour.ARDUPILOT: "GUIDED"}
"""The mode in which each autopilot flies companion velocity setpoints."""
HOLD_MODE = {Flavour.PX4: "AUTO.LOITER", Flavour.ARDUPILOT: "BRAKE"}
"""Stop and hold position without pilot input (ArduCopter BRAKE needs no RC sticks)."""
LAND_MODE = {Flavour.PX4: "AUTO.LAND", Flavour.ARDUPILOT: "LAND"}

DATA_STREAM_GROUP: dict[str, int] = {
    "SYS_STATUS": 2,
    "GPS_RAW_INT": 2,
    "BATTERY_STATUS": 12,
    "GLOBAL_POSITION_INT": 6,
    "LOCAL_POSITION_NED": 6,
    "ATTITUDE": 10,
    "SYSTEM_TIME": 12,
}
"""Legacy ``REQUEST_DATA_STREAM`` group (MAV_DATA_STREAM) that carries each message on
ArduCopter (``GCS_MAVLink_Copter.cpp``): EXTENDED_STATUS 2, POSITION 6, EXTRA1 10, EXTRA3 12.
EXTENDED_SYS_STATE is in no group (measured on ArduCopter 4.7 SITL): only SET_MESSAGE_INTERVAL
starts it."""


def stream_groups(names: list[str], rates_hz: dict[str, float]) -> tuple[dict[int, int], list[str]]:
    """The REQUEST_DATA_STREAM fallback for messages whose SET_MESSAGE_INTERVAL was refused:
    ``({group: rate Hz (integer, >= 1)}, messages no group carries)``. A message without a group
    is never mapped to group 0, which is MAV_DATA_STREAM_ALL: every stream at that rate."""
    groups: dict[int, float] = {}
    ungrouped = []
    for name in names:
        g = DATA_STREAM_GROUP.get(name)
        if g is None:
            ungrouped.append(name)
        else:
            groups[g] = max(groups.get(g, 0.0), rates_hz[name])
    return {g: max(1, round(hz)) for g, hz in groups.items()}, ungrouped


# --- flavours and modes ---------------------------------------------------------------------------
def is_autopilot_heartbeat(mav_type: int, autopilot: int) -> bool:
    """True for the heartbeat of a flight controller (not a GCS or companion computer)."""
    return autopilot != MAV_AUTOPILOT_INVALID and mav_type not in (
        MAV_TYPE_GCS,
        MAV_TYPE_ONBOARD_CONTROLLER,
    )


def flavour_from_autopilot(autopilot: int) -> Flavour | None:
    """HEARTBEAT ``autopilot`` -> flavour; ``None`` for firmware we do not fly."""
    if autopilot == mv.MAV_AUTOPILOT_PX4:
        return Flavour.PX4
    if autopilot == mv.MAV_AUTOPILOT_ARDUPILOTMEGA:
        return Flavour.ARDUPILOT
    return None


def mode_name(flavour: Flavour, base_mode: int, custom_mode: int) -> str:
    """Name of the mode a HEARTBEAT shows (``"UNKNOWN(...)"`` if it is not one we know)."""
    if not base_mode & mv.BASE_MODE_CUSTOM:
        return f"UNKNOWN(base={base_mode})"
    if flavour is Flavour.PX4:
        main, sub = mv.px4_decode_custom_mode(custom_mode)
        name = mv.px4_mode_name(main, sub)
        return name if name is not None else f"UNKNOWN({main},{sub})"
    name = mv.COPTER_MODE_NAMES.get(custom_mode)
    return name if name is not None else f"UNKNOWN({custom_mode})"


def mode_command_params(flavour: Flavour, name: str) -> tuple[float, float, float]:
    """``DO_SET_MODE`` params 1-3 for mode ``name``; raises ``ValueError`` for an unknown mode."""
    if flavour is Flavour.PX4:
        if name not in mv.PX4_MODES:
            raise ValueError(f"unknown PX4 mode {name!r}; known: {sorted(mv.PX4_MODES)}")
        main, sub = mv.PX4_MODES[name]
        return float(mv.BASE_MODE_CUSTOM), float(main), float(sub)
    if name not in mv.COPTER_MODES:
        raise ValueError(f"unknown ArduCopter mode {name!r}; known: {sorted(mv.COPTER_MODES)}")
    return float(mv.BASE_MODE_CUSTOM), float(mv.COPTER_MODES[name]), 0.0


def is_armed(base_mode: int) -> bool:
    return bool(base_mode & mv.BASE_MODE_ARMED)


# --- frames --------------------------------------------------------------------------------------
def body_velocity(v_ned: np.ndarray, yaw_rad: np.ndarray | float) -> FloatArray:
    """Heading-frame velocity ``R_z(yaw)^T v_ned`` (rows of ``v_ned`` and ``yaw`` broadcast)."""
    r = rot_z(yaw_rad)
    return np.einsum("...ji,...j->...i", r, np.asarray(v_ned, dtype=float))


# --- safety --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Saturated:
    """A setpoint after :func:`saturate_setpoint`."""

    v_body: Vec3
    yaw_rate_rad_s: float
    non_finite: bool
    """The input had a NaN/inf: the output is a stop (zero velocity and yaw rate)."""
    clipped: bool
    """A limit was applied."""


def saturate_setpoint(
    v_body: Any, yaw_rate_rad_s: float, max_xy_m_s: float, max_z_m_s: float, max_rate_rad_s: float
) -> Saturated:
    """Limit the horizontal speed (norm, direction kept), the vertical speed and the yaw rate.

    Anything non-finite (or a ``v_body`` that is not three numbers) becomes a stop: a safe
    setpoint, never an exception in the stream.
    """
    try:
        v = np.asarray(v_body, dtype=float).reshape(3)
        r = float(yaw_rate_rad_s)
    except (TypeError, ValueError):
        return Saturated((0.0, 0.0, 0.0), 0.0, non_finite=True, clipped=False)
    if not (np.all(np.isfinite(v)) and math.isfinite(r)):
        return Saturated((0.0, 0.0, 0.0), 0.0, non_finite=True, clipped=False)
    clipped = False
    speed_xy = float(np.hypot(v[0], v[1]))
    if speed_xy > max_xy_m_s:
        v[:2] *= max_xy_m_s / speed_xy
        clipped = True
    if abs(v[2]) > max_z_m_s:
        v[2] = math.copysign(max_z_m_s, v[2])
        clipped = True
    if abs(r) > max_rate_rad_s:
        r = math.copysign(max_rate_rad_s, r)
        clipped = True
    return Saturated((float(v[0]), float(v[1]), float(v[2])), r, non_finite=False, clipped=clipped)


# --- retries -------------------------------------------------------------------------------------
def backoff_s(attempt: int, initial_s: float, max_s: float) -> float:
    """Delay before retry ``attempt`` (0-based): ``initial * 2^attempt``, capped at ``max_s``."""
    return float(min(max_s, initial_s * 2.0 ** max(0, attempt)))


RETRYABLE_RESULTS = frozenset(
    {mv.RESULT_TEMPORARILY_REJECTED, mv.RESULT_DENIED, mv.RESULT_FAILED, mv.RESULT_IN_PROGRESS}
)
"""ACK results a booting autopilot gives and a later retry may turn into ACCEPTED (PX4 denies
arming with DENIED, ArduPilot with FAILED, while the estimator warms up)."""


def retryable(result: int | None) -> bool:
    """Whether an action that ended with ``result`` (``None``: timeout) is worth retrying."""
    return result is None or result in RETRYABLE_RESULTS


@dataclass(frozen=True)
class Attempt:
    """One try of an action: did it work, the last MAV_RESULT, how many commands went out,
    and whether another try may succeed."""

    ok: bool
    result: int | None
    sends: int
    detail: str = ""
    retry: bool = False


def retry_loop(
    attempt: Callable[[], Attempt],
    clock: Callable[[], float],
    wait: Callable[[float], bool],
    timeout_s: float,
    initial_s: float,
    max_s: float,
) -> tuple[Attempt, int, str]:
    """Run ``attempt`` until it works, says retrying is pointless, or the next backoff would
    end after ``timeout_s``. ``wait(delay)`` sleeps and returns True if the caller is shutting
    down. Returns (last attempt, commands sent in all attempts, why it stopped: ``""`` when it
    stopped by itself, ``"gave up retrying"`` or ``"link closed"``)."""
    deadline = clock() + timeout_s
    sends, k = 0, 0
    while True:
        a = attempt()
        sends += a.sends
        if a.ok or not a.retry:
            return a, sends, ""
        delay = backoff_s(k, initial_s, max_s)
        k += 1
        if clock() + delay > deadline:
            return a, sends, "gave up retrying"
        if wait(delay):
            return a, sends, "link closed"


def climb_done(st: TelemetryState, altitude_m: float) -> bool:
    """A takeoff is over: in the air (no longer "taking off") and within 10% (at least 0.2 m)
    of the target altitude. ArduCopter ignores velocity targets before that."""
    tol = max(0.2, 0.1 * altitude_m)
    return st.landed_state == mv.LANDED_IN_AIR and st.altitude_m >= altitude_m - tol


# --- telemetry accumulator ------------------------------------------------------------------------
_FLOAT_FIELDS: dict[str, tuple[str, ...]] = {
    "ATTITUDE": ("roll", "pitch", "yaw", "yawspeed"),
    "LOCAL_POSITION_NED": ("x", "y", "z", "vx", "vy", "vz"),
}
ATTITUDE_MAX_RAD = 2.0 * math.pi
"""Roll, pitch and yaw of ATTITUDE (MAVLink sends them in ``[-pi, pi]``)."""
TELEMETRY_LIMITS: dict[str, dict[str, float]] = {
    "ATTITUDE": {
        "roll": ATTITUDE_MAX_RAD,
        "pitch": ATTITUDE_MAX_RAD,
        "yaw": ATTITUDE_MAX_RAD,
        "yawspeed": RATE_MAX_RAD_S,
    },
    "LOCAL_POSITION_NED": {
        "x": POSITION_MAX_M,
        "y": POSITION_MAX_M,
        "z": POSITION_MAX_M,
        "vx": SPEED_MAX_M_S,
        "vy": SPEED_MAX_M_S,
        "vz": SPEED_MAX_M_S,
    },
}
"""Plausibility bounds (absolute value) of the autopilot telemetry the agent uses: the physical
ranges of :mod:`messages.limits` (100 km, 100 m/s, 20 rad/s). Corrupted but finite telemetry
(altitude 1e6 m, velocity 1e4 m/s, yaw rate 100 rad/s) once passed and kept the estimates
100-150 % off for a minute (issue 23)."""


def plausible(values: dict[str, float], limits: dict[str, float]) -> bool:
    """Whether every ``values[name]`` with a limit is within ``[-limit, limit]`` (finite)."""
    return all(abs(values[n]) <= lim for n, lim in limits.items() if n in values)


@dataclass
class TelemetryState:
    """Latest autopilot values with their receive times (link clock); ``-inf``: never."""

    flavour: Flavour | None = None
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    yaw_rad: float = 0.0
    yaw_rate_rad_s: float = 0.0
    v_ned: Vec3 = (0.0, 0.0, 0.0)
    altitude_m: float = 0.0
    north_m: float = 0.0
    east_m: float = 0.0
    t_boot_s: float | None = None
    t_boot_attitude_s: float | None = None
    t_boot_velocity_s: float | None = None
    base_mode: int = 0
    custom_mode: int = 0
    mode: str = "UNKNOWN"
    armed: bool = False
    landed_state: int = mv.LANDED_UNDEFINED
    ready: bool = False
    sys_status_seen: bool = False
    battery_remaining_pct: float | None = None
    battery_voltage_v: float | None = None
    t_heartbeat_s: float = -math.inf
    t_attitude_s: float = -math.inf
    t_velocity_s: float = -math.inf
    t_sys_status_s: float = -math.inf
    t_implausible_s: float = -math.inf
    """When the last implausible (finite but out of :data:`TELEMETRY_LIMITS`) message came."""
    implausible: int = 0
    """Messages dropped as implausible."""
    statustexts: list[tuple[float, int, str]] = field(default_factory=list)
    max_statustexts: int = 100

    def apply(self, msg: Any, now_s: float) -> bool:
        """Fold one message from the target autopilot in; ``False`` if it had invalid numbers
        (then nothing changes). Types the link does not use are accepted and ignored."""
        kind = msg.get_type()
        names = _FLOAT_FIELDS.get(kind)
        if names is not None and not all(math.isfinite(getattr(msg, n)) for n in names):
            return False
        limits = TELEMETRY_LIMITS.get(kind)
        if limits is not None and not plausible(
            {n: float(getattr(msg, n, 0.0)) for n in limits}, limits
        ):
            self.implausible_at(now_s)
            return False
        handler = getattr(self, "_on_" + kind.lower(), None)
        if handler is not None:
            handler(msg, now_s)
        return True

    def implausible_at(self, now_s: float) -> None:
        """Count a message dropped as implausible, received at ``now_s``."""
        self.implausible += 1
        self.t_implausible_s = now_s

    def _on_heartbeat(self, msg: Any, now_s: float) -> None:
        self.heartbeat(int(msg.base_mode), int(msg.custom_mode), now_s)

    def heartbeat(self, base_mode: int, custom_mode: int, now_s: float) -> None:
        """A HEARTBEAT of the target: mode and armed flag."""
        self.t_heartbeat_s = now_s
        self.base_mode = base_mode
        self.custom_mode = custom_mode
        self.armed = is_armed(base_mode)
        if self.flavour is not None:
            self.mode = mode_name(self.flavour, base_mode, custom_mode)

    def _on_attitude(self, msg: Any, now_s: float) -> None:
        self.t_attitude_s = now_s
        self.roll_rad = float(msg.roll)
        self.pitch_rad = float(msg.pitch)
        self.yaw_rad = float(msg.yaw)
        self.yaw_rate_rad_s = float(msg.yawspeed)
        self.t_boot_s = self.t_boot_attitude_s = msg.time_boot_ms / 1000.0

    def _on_local_position_ned(self, msg: Any, now_s: float) -> None:
        self.t_velocity_s = now_s
        self.v_ned = (float(msg.vx), float(msg.vy), float(msg.vz))
        self.altitude_m = -float(msg.z)
        self.north_m, self.east_m = float(msg.x), float(msg.y)
        self.t_boot_s = self.t_boot_velocity_s = msg.time_boot_ms / 1000.0

    def _on_extended_sys_state(self, msg: Any, _now_s: float) -> None:
        self.landed_state = int(msg.landed_state)

    def _on_sys_status(self, msg: Any, now_s: float) -> None:
        self.t_sys_status_s = now_s
        self.sys_status_seen = True
        self.ready = bool(msg.onboard_control_sensors_health & mv.SENSOR_PREARM_CHECK) and bool(
            msg.onboard_control_sensors_present & mv.SENSOR_PREARM_CHECK
        )
        if msg.battery_remaining >= 0:
            self.battery_remaining_pct = float(msg.battery_remaining)
        if msg.voltage_battery != 65535:
            self.battery_voltage_v = msg.voltage_battery / 1000.0

    def _on_battery_status(self, msg: Any, _now_s: float) -> None:
        if msg.battery_remaining >= 0:
            self.battery_remaining_pct = float(msg.battery_remaining)

    def _on_statustext(self, msg: Any, now_s: float) -> None:
        text = msg.text
        if isinstance(text, bytes):
            text = text.decode("utf-8", errors="replace")
        self.statustext(int(msg.severity), str(text), now_s)

    def statustext(self, severity: int, text: str, now_s: float) -> None:
        """Remember a STATUSTEXT (the last ``max_statustexts``)."""
        self.statustexts.append((now_s, severity, text.rstrip("\x00")))
        del self.statustexts[: -self.max_statustexts]

    def texts_since(self, t_s: float) -> tuple[str, ...]:
        """STATUSTEXT messages received at or after ``t_s``."""
        return tuple(text for t, _sev, text in self.statustexts if t >= t_s)

    def v_body(self) -> Vec3:
        v = body_velocity(np.array(self.v_ned), self.yaw_rad)
        return (float(v[0]), float(v[1]), float(v[2]))


def snapshot(
    st: TelemetryState,
    now_s: float,
    config: LinkConfig,
    system_id: int | None,
    stream: StreamState,
    setpoint: Saturated,
    counters: LinkCounters,
) -> Telemetry:
    """The :class:`Telemetry` a link returns: ``st`` with ages and stale flags at ``now_s``."""
    hb_age = now_s - st.t_heartbeat_s
    att_age = now_s - st.t_attitude_s
    vel_age = now_s - st.t_velocity_s
    return Telemetry(
        t_s=now_s,
        connected=system_id is not None and hb_age <= config.heartbeat_timeout_s,
        flavour=st.flavour,
        system_id=system_id,
        t_boot_s=st.t_boot_s,
        t_boot_attitude_s=st.t_boot_attitude_s,
        t_boot_velocity_s=st.t_boot_velocity_s,
        roll_rad=st.roll_rad,
        pitch_rad=st.pitch_rad,
        yaw_rad=st.yaw_rad,
        yaw_rate_rad_s=st.yaw_rate_rad_s,
        v_ned=st.v_ned,
        v_body=st.v_body(),
        altitude_m=st.altitude_m,
        north_m=st.north_m,
        east_m=st.east_m,
        mode=st.mode,
        armed=st.armed,
        landed_state=st.landed_state,
        ready=st.ready,
        battery_remaining_pct=st.battery_remaining_pct,
        battery_voltage_v=st.battery_voltage_v,
        heartbeat_age_s=hb_age,
        attitude_age_s=att_age,
        velocity_age_s=vel_age,
        stale_heartbeat=hb_age > config.heartbeat_timeout_s,
        stale_attitude=att_age > config.stale_after_s,
        stale_velocity=vel_age > config.stale_after_s,
        stream_state=stream,
        setpoint_v_body=setpoint.v_body,
        setpoint_yaw_rate_rad_s=setpoint.yaw_rate_rad_s,
        counters=counters,
        implausible_age_s=now_s - st.t_implausible_s,
        implausible=st.implausible,
    )
