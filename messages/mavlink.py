"""MAVLink vocabulary shared by the simulator and the onboard autopilot link.

Plain integers and small pure functions, no I/O and no pymavlink import, so both sides of a
link agree on one spelling of: the ``SET_POSITION_TARGET_LOCAL_NED`` type-mask bits and frames,
the PX4 ``custom_mode`` encoding (``(main << 16) | (sub << 24)``) and the ArduCopter mode
numbers, the HEARTBEAT ``base_mode`` flags, and the COMMAND_ACK results we use
(``docs/mavlink.md``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

# --- identities --------------------------------------------------------------------------------
MAV_TYPE_QUADROTOR = 2
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_PX4 = 12
COMPONENT_AUTOPILOT = 1

# --- HEARTBEAT ----------------------------------------------------------------------------------
BASE_MODE_CUSTOM = 1
BASE_MODE_TEST = 2
BASE_MODE_AUTO = 4
BASE_MODE_GUIDED = 8
BASE_MODE_STABILIZE = 16
BASE_MODE_HIL = 32
BASE_MODE_MANUAL = 64
BASE_MODE_ARMED = 128

MAV_STATE_STANDBY = 3
MAV_STATE_ACTIVE = 4

# --- COMMAND_ACK results -----------------------------------------------------------------------
RESULT_ACCEPTED = 0
RESULT_TEMPORARILY_REJECTED = 1
RESULT_DENIED = 2
RESULT_UNSUPPORTED = 3
RESULT_FAILED = 4
RESULT_IN_PROGRESS = 5

# --- commands ----------------------------------------------------------------------------------
CMD_NAV_LAND = 21
CMD_NAV_TAKEOFF = 22
CMD_NAV_RETURN_TO_LAUNCH = 20
CMD_NAV_LOITER_UNLIM = 17
CMD_DO_SET_MODE = 176
CMD_COMPONENT_ARM_DISARM = 400
CMD_SET_MESSAGE_INTERVAL = 511
CMD_REQUEST_MESSAGE = 512
CMD_REQUEST_AUTOPILOT_CAPABILITIES = 520
FORCE_DISARM_MAGIC = 21196

# --- EXTENDED_SYS_STATE landed_state -------------------------------------------------------------
LANDED_UNDEFINED = 0
LANDED_ON_GROUND = 1
LANDED_IN_AIR = 2
LANDED_TAKEOFF = 3
LANDED_LANDING = 4

# --- SYS_STATUS sensor bits --------------------------------------------------------------------
SENSOR_GYRO = 1
SENSOR_ACCEL = 2
SENSOR_MAG = 4
SENSOR_ABS_PRESSURE = 8
SENSOR_GPS = 32
SENSOR_PREARM_CHECK = 268435456
"""``MAV_SYS_STATUS_PREARM_CHECK``: MAVSDK's ``is_armable`` reads this bit."""

# --- SET_POSITION_TARGET_LOCAL_NED frames -------------------------------------------------------
FRAME_LOCAL_NED = 1
FRAME_LOCAL_OFFSET_NED = 7
FRAME_BODY_NED = 8
FRAME_BODY_OFFSET_NED = 9
BODY_FRAMES = frozenset({FRAME_BODY_NED, FRAME_BODY_OFFSET_NED})
"""Frames whose velocity is given in the vehicle's heading frame (rotated by the current yaw)."""

# --- type-mask bits (a set bit means "ignore this field") ----------------------------------------
IGNORE_PX = 1
IGNORE_PY = 2
IGNORE_PZ = 4
IGNORE_VX = 8
IGNORE_VY = 16
IGNORE_VZ = 32
IGNORE_AX = 64
IGNORE_AY = 128
IGNORE_AZ = 256
FORCE_SETPOINT = 512
IGNORE_YAW = 1024
IGNORE_YAW_RATE = 2048

IGNORE_POSITION = IGNORE_PX | IGNORE_PY | IGNORE_PZ
IGNORE_VELOCITY = IGNORE_VX | IGNORE_VY | IGNORE_VZ
IGNORE_ACCEL = IGNORE_AX | IGNORE_AY | IGNORE_AZ

MASK_VELOCITY_YAW_RATE = IGNORE_POSITION | IGNORE_ACCEL | IGNORE_YAW
"""1479: velocity + yaw rate (MAVSDK ``VelocityBodyYawspeed``, frame 8)."""
MASK_VELOCITY_YAW = IGNORE_POSITION | IGNORE_ACCEL | IGNORE_YAW_RATE
"""2503: velocity + yaw angle (MAVSDK ``VelocityNedYaw``, frame 1)."""


@dataclass(frozen=True)
class VelocitySetpoint:
    """What a ``SET_POSITION_TARGET_LOCAL_NED`` asks of a velocity-controlled vehicle.

    ``v_m_s`` is in the message's frame (NED for frames 1/7, heading frame for 8/9);
    ``yaw_rad`` / ``yaw_rate_rad_s`` is ``None`` when its mask bit says to ignore it.
    ``stop`` is True when a used field is NaN or infinite: autopilots treat that as "stop".
    """

    frame: int
    v_m_s: tuple[float, float, float]
    yaw_rad: float | None
    yaw_rate_rad_s: float | None
    stop: bool

    @property
    def body(self) -> bool:
        return self.frame in BODY_FRAMES


def is_velocity_mask(type_mask: int) -> bool:
    """True when the mask uses velocity only (position and acceleration ignored)."""
    return (
        type_mask & IGNORE_POSITION == IGNORE_POSITION
        and type_mask & IGNORE_ACCEL == IGNORE_ACCEL
        and type_mask & IGNORE_VELOCITY == 0
    )


def velocity_setpoint(
    frame: int,
    type_mask: int,
    v_m_s: tuple[float, float, float],
    yaw_rad: float,
    yaw_rate_rad_s: float,
) -> VelocitySetpoint | None:
    """Interpret a velocity setpoint; ``None`` if the mask is not velocity-only."""
    if not is_velocity_mask(type_mask):
        return None
    use_yaw = not type_mask & IGNORE_YAW
    use_rate = not type_mask & IGNORE_YAW_RATE
    used = [*v_m_s]
    if use_yaw:
        used.append(yaw_rad)
    if use_rate:
        used.append(yaw_rate_rad_s)
    stop = not all(math.isfinite(x) for x in used)
    return VelocitySetpoint(
        frame=frame,
        v_m_s=(float(v_m_s[0]), float(v_m_s[1]), float(v_m_s[2])),
        yaw_rad=float(yaw_rad) if use_yaw else None,
        yaw_rate_rad_s=float(yaw_rate_rad_s) if use_rate else None,
        stop=stop,
    )


# --- PX4 modes -----------------------------------------------------------------------------------
PX4_MAIN_MANUAL = 1
PX4_MAIN_ALTCTL = 2
PX4_MAIN_POSCTL = 3
PX4_MAIN_AUTO = 4
PX4_MAIN_ACRO = 5
PX4_MAIN_OFFBOARD = 6
PX4_MAIN_STABILIZED = 7

PX4_SUB_AUTO_READY = 1
PX4_SUB_AUTO_TAKEOFF = 2
PX4_SUB_AUTO_LOITER = 3
PX4_SUB_AUTO_MISSION = 4
PX4_SUB_AUTO_RTL = 5
PX4_SUB_AUTO_LAND = 6

PX4_MODES: dict[str, tuple[int, int]] = {
    "MANUAL": (PX4_MAIN_MANUAL, 0),
    "ALTCTL": (PX4_MAIN_ALTCTL, 0),
    "POSCTL": (PX4_MAIN_POSCTL, 0),
    "AUTO.READY": (PX4_MAIN_AUTO, PX4_SUB_AUTO_READY),
    "AUTO.TAKEOFF": (PX4_MAIN_AUTO, PX4_SUB_AUTO_TAKEOFF),
    "AUTO.LOITER": (PX4_MAIN_AUTO, PX4_SUB_AUTO_LOITER),
    "AUTO.MISSION": (PX4_MAIN_AUTO, PX4_SUB_AUTO_MISSION),
    "AUTO.RTL": (PX4_MAIN_AUTO, PX4_SUB_AUTO_RTL),
    "AUTO.LAND": (PX4_MAIN_AUTO, PX4_SUB_AUTO_LAND),
    "OFFBOARD": (PX4_MAIN_OFFBOARD, 0),
    "STABILIZED": (PX4_MAIN_STABILIZED, 0),
}
"""PX4 mode name -> (main mode, sub mode)."""


def px4_custom_mode(main: int, sub: int = 0) -> int:
    """HEARTBEAT ``custom_mode`` of a PX4 mode: ``(main << 16) | (sub << 24)``."""
    return ((main & 0xFF) << 16) | ((sub & 0xFF) << 24)


def px4_decode_custom_mode(custom_mode: int) -> tuple[int, int]:
    """Inverse of :func:`px4_custom_mode`: ``(main, sub)``."""
    return (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF


def px4_mode_name(main: int, sub: int = 0) -> str | None:
    """Name of a PX4 (main, sub) mode, e.g. ``(4, 3) -> "AUTO.LOITER"``; ``None`` if unknown.
    Non-AUTO modes ignore ``sub``."""
    if main != PX4_MAIN_AUTO:
        sub = 0
    for name, pair in PX4_MODES.items():
        if pair == (main, sub):
            return name
    return None


# --- ArduCopter modes ----------------------------------------------------------------------------
COPTER_MODES: dict[str, int] = {
    "STABILIZE": 0,
    "ACRO": 1,
    "ALT_HOLD": 2,
    "AUTO": 3,
    "GUIDED": 4,
    "LOITER": 5,
    "RTL": 6,
    "CIRCLE": 7,
    "LAND": 9,
    "BRAKE": 17,
    "POSHOLD": 16,
    "GUIDED_NOGPS": 20,
}
"""ArduCopter mode name -> HEARTBEAT ``custom_mode`` number."""
COPTER_MODE_NAMES: dict[int, str] = {v: k for k, v in COPTER_MODES.items()}
COPTER_GUIDED_LIKE = frozenset({COPTER_MODES["GUIDED"], COPTER_MODES["AUTO"], COPTER_MODES["RTL"]})
"""Modes in which ArduCopter sets ``MAV_MODE_FLAG_GUIDED_ENABLED`` in its heartbeat."""
