"""Telemetry streams of a simulated autopilot: rates, scheduling and message builders.

:class:`Telemetry` is a mixin of :class:`sim.autopilot.common.Autopilot`: it keeps one interval
and one next-due time (simulation seconds) per streamed message, honours SET_MESSAGE_INTERVAL
and (where a real ArduPilot does) REQUEST_DATA_STREAM, and builds each message from the
vehicle's state and the world's latest :class:`~sim.world.Observation`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from types import ModuleType
from typing import Any

import numpy as np

from messages import mavlink as mv
from sim.autopilot.link import LinkCounters
from sim.autopilot.state import LANDED_STATE, AutopilotOptions, Phase
from sim.world import Observation

DEFAULT_STREAM_HZ: dict[str, float] = {
    "ATTITUDE": 20.0,
    "ATTITUDE_QUATERNION": 20.0,
    "LOCAL_POSITION_NED": 20.0,
    "GLOBAL_POSITION_INT": 20.0,
    "SYS_STATUS": 2.0,
    "EXTENDED_SYS_STATE": 2.0,
    "GPS_RAW_INT": 2.0,
    "SYSTEM_TIME": 1.0,
    "HOME_POSITION": 0.5,
    "BATTERY_STATUS": 0.5,
}
"""Stream rates (Hz of simulation time) at boot; SET_MESSAGE_INTERVAL changes them."""
MIN_HEARTBEAT_HZ = 1.0
"""SET_MESSAGE_INTERVAL may not slow HEARTBEAT below this or stop it (DENIED): clients mark a
vehicle lost after a few silent seconds (MAVSDK: 3 s), so a slower heartbeat silences it."""
MAX_STREAM_HZ = 100.0
"""Fastest stream (one message per 10 ms world step): a request for more is clamped, so one
SET_MESSAGE_INTERVAL(1 us) or REQUEST_DATA_STREAM(65535 Hz) cannot flood the links."""

STREAM_IDS: dict[str, int] = {
    "HEARTBEAT": 0,
    "SYS_STATUS": 1,
    "SYSTEM_TIME": 2,
    "GPS_RAW_INT": 24,
    "ATTITUDE": 30,
    "ATTITUDE_QUATERNION": 31,
    "LOCAL_POSITION_NED": 32,
    "GLOBAL_POSITION_INT": 33,
    "BATTERY_STATUS": 147,
    "AUTOPILOT_VERSION": 148,
    "EXTENDED_SYS_STATE": 245,
    "HOME_POSITION": 242,
}
STREAM_NAMES = {v: k for k, v in STREAM_IDS.items()}


class Telemetry:
    """Stream scheduling and builders (state attributes come from the Autopilot)."""

    dialect: ModuleType
    autopilot_type: int
    capabilities: int
    flight_sw_version: int
    index: int
    sys_id: int
    t_s: float
    armed: bool
    armed_t_s: float
    booted: bool
    phase: Phase
    home_ned: np.ndarray
    options: AutopilotOptions
    obs: Observation | None
    intervals_s: dict[str, float]
    next_due_s: dict[str, float]
    _next_any_s: float
    send: Callable[[Any], None]
    counters: LinkCounters

    def init_streams(self, on: bool) -> None:
        """Default streams (or only HEARTBEAT), phase-staggered across vehicles."""
        rates = DEFAULT_STREAM_HZ if on else {}
        self.intervals_s = {name: 1.0 / hz for name, hz in rates.items()}
        self.intervals_s["HEARTBEAT"] = 1.0
        phase = (self.index * 0.137) % 1.0  # vehicles' packets do not all coincide
        self.next_due_s = {name: self.t_s + phase * iv for name, iv in self.intervals_s.items()}
        self._next_any_s = min(self.next_due_s.values())

    def heartbeat_modes(self) -> tuple[int, int]:
        raise NotImplementedError

    def arm_refusal(self) -> tuple[int, str] | None:
        raise NotImplementedError

    def stream_ready(self, name: str) -> bool:
        """Whether message ``name`` can be sent now (a flavour withholds what its estimator
        does not have yet; the stream keeps its schedule and starts by itself)."""
        return True

    def landed_state(self) -> int:
        """MAV_LANDED_STATE of EXTENDED_SYS_STATE."""
        return LANDED_STATE[self.phase]

    @property
    def altitude_m(self) -> float:
        raise NotImplementedError

    # --- streams ---------------------------------------------------------------------------------
    def set_message_interval(self, msg_id: float, interval_us: float) -> int:
        if not (math.isfinite(msg_id) and math.isfinite(interval_us)):
            return mv.RESULT_DENIED
        name = STREAM_NAMES.get(int(msg_id))
        if name is None or name == "AUTOPILOT_VERSION":
            return mv.RESULT_UNSUPPORTED
        if name == "HEARTBEAT" and (interval_us < 0 or interval_us > 1e6 / MIN_HEARTBEAT_HZ):
            self.counters.intervals_refused += 1  # a silent vehicle is a lost vehicle
            return mv.RESULT_DENIED
        if interval_us < 0:
            self.set_rate(name, 0.0)
        else:
            hz = DEFAULT_STREAM_HZ.get(name, 1.0) if interval_us == 0 else 1e6 / interval_us
            self.set_rate(name, hz)
        return mv.RESULT_ACCEPTED

    def set_rate(self, name: str, hz: float) -> None:
        """Stream ``name`` at ``hz`` (at most :data:`MAX_STREAM_HZ`); ``hz <= 0`` stops it."""
        hz = min(hz, MAX_STREAM_HZ)
        if hz <= 0.0:
            self.intervals_s.pop(name, None)
            self.next_due_s.pop(name, None)
        else:
            self.intervals_s[name] = 1.0 / hz
            self.next_due_s[name] = self.t_s
        self._next_any_s = min(self.next_due_s.values(), default=math.inf)

    def _on_request_data_stream(self, msg: Any) -> None:
        """Legacy stream groups: applied only where a real ArduPilot applies them (strict)."""
        if not self._for_me(msg.target_system, msg.target_component):
            return
        if self.streams_on_boot():
            return  # accept and ignore: our default streams already cover what clients need
        groups = {  # ArduCopter's GCS_MAVLink_Copter.cpp; EXTENDED_SYS_STATE is in none
            2: ("SYS_STATUS", "GPS_RAW_INT"),
            6: ("GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"),
            10: ("ATTITUDE",),
            12: ("SYSTEM_TIME", "BATTERY_STATUS"),
        }
        chosen = [n for g in groups.values() for n in g] if msg.req_stream_id == 0 else []
        chosen += list(groups.get(int(msg.req_stream_id), ()))
        hz = float(msg.req_message_rate) if msg.start_stop else 0.0
        for name in chosen:
            self.set_rate(name, hz)

    def due(self, t_s: float) -> bool:
        """True if some stream is due at ``t_s`` (so the server computes observations)."""
        return t_s >= self._next_any_s

    def send_streams(self, t_s: float, obs: Observation) -> None:
        """Send every stream message that is due at ``t_s``."""
        self.obs = obs
        if t_s < self._next_any_s:
            return
        for name, due in self.next_due_s.items():
            if t_s >= due:
                nxt = due + self.intervals_s[name]
                self.next_due_s[name] = nxt if nxt > t_s else t_s + self.intervals_s[name]
                if self.stream_ready(name):
                    self.send(self.build(name))
        self._next_any_s = min(self.next_due_s.values(), default=math.inf)

    def send_once(self, msg_id: int) -> None:
        name = STREAM_NAMES.get(msg_id)
        if (
            name is not None
            and self.stream_ready(name)
            and (
                self.obs is not None or name in ("AUTOPILOT_VERSION", "HEARTBEAT", "HOME_POSITION")
            )
        ):
            self.send(self.build(name))

    def send_heartbeat(self) -> None:
        self.send(self.build("HEARTBEAT"))

    # --- telemetry builders ---------------------------------------------------------------------
    def time_boot_ms(self) -> int:
        return int(self.t_s * 1000.0) & 0xFFFFFFFF

    def build(self, name: str) -> Any:
        return getattr(self, "_build_" + name.lower())()

    def _build_heartbeat(self) -> Any:
        base, custom = self.heartbeat_modes()
        if self.armed:
            base |= mv.BASE_MODE_ARMED
        state = mv.MAV_STATE_ACTIVE if self.armed else mv.MAV_STATE_STANDBY
        return self.dialect.MAVLink_heartbeat_message(
            mv.MAV_TYPE_QUADROTOR, self.autopilot_type, base, custom, state, 3
        )

    def _row(self) -> tuple[Observation, int]:
        assert self.obs is not None
        return self.obs, self.index

    def _build_attitude(self) -> Any:
        o, i = self._row()
        return self.dialect.MAVLink_attitude_message(
            self.time_boot_ms(),
            float(o.roll_rad[i]),
            float(o.pitch_rad[i]),
            float(o.yaw_rad[i]),
            0.0,
            0.0,
            float(o.yaw_rate_rad_s[i]),
        )

    def _build_attitude_quaternion(self) -> Any:
        o, i = self._row()
        q = quaternion_from_euler(float(o.roll_rad[i]), float(o.pitch_rad[i]), float(o.yaw_rad[i]))
        return self.dialect.MAVLink_attitude_quaternion_message(
            self.time_boot_ms(), *q, 0.0, 0.0, float(o.yaw_rate_rad_s[i])
        )

    def _build_local_position_ned(self) -> Any:
        o, i = self._row()
        p = o.p_ned[i] - self.home_ned  # each autopilot's local origin is where it booted
        v = o.v_ned[i]
        return self.dialect.MAVLink_local_position_ned_message(
            self.time_boot_ms(), *(float(x) for x in p), *(float(x) for x in v)
        )

    def _build_global_position_int(self) -> Any:
        o, i = self._row()
        lat, lon, alt = self.options.home.to_global(o.p_ned[i])
        v = o.v_ned[i]
        hdg = round(math.degrees(float(o.yaw_rad[i])) * 100.0) % 36000
        return self.dialect.MAVLink_global_position_int_message(
            self.time_boot_ms(),
            round(lat * 1e7),
            round(lon * 1e7),
            round(alt * 1000.0),
            round(self.altitude_m * 1000.0),
            _i16(v[0] * 100.0),
            _i16(v[1] * 100.0),
            _i16(v[2] * 100.0),
            hdg,
        )

    def _build_sys_status(self) -> Any:
        sensors = mv.SENSOR_GYRO | mv.SENSOR_ACCEL | mv.SENSOR_MAG | mv.SENSOR_ABS_PRESSURE
        sensors |= mv.SENSOR_GPS
        present = sensors | mv.SENSOR_PREARM_CHECK
        health = sensors | (mv.SENSOR_PREARM_CHECK if self.arm_refusal() is None else 0)
        if not self.booted:
            health &= ~mv.SENSOR_GPS
        return self.dialect.MAVLink_sys_status_message(
            present, present, health, 200, 16200, 500 if self.armed else 50,
            self.battery_remaining(), 0, 0, 0, 0, 0, 0,
        )  # fmt: skip

    def battery_remaining(self) -> int:
        """Percent: a 20-minute battery that drains only while armed."""
        flown = (self.t_s - self.armed_t_s) if self.armed else 0.0
        return max(0, int(100 - flown / 12.0))

    def _build_extended_sys_state(self) -> Any:
        return self.dialect.MAVLink_extended_sys_state_message(0, self.landed_state())

    def _build_gps_raw_int(self) -> Any:
        o, i = self._row()
        lat, lon, alt = self.options.home.to_global(o.p_ned[i])
        v = o.v_ned[i]
        speed = math.hypot(float(v[0]), float(v[1]))
        cog = round(math.degrees(math.atan2(float(v[1]), float(v[0]))) * 100.0) % 36000
        fix, sats = (3, 12) if self.booted else (1, 4)
        return self.dialect.MAVLink_gps_raw_int_message(
            int(self.t_s * 1e6), fix, round(lat * 1e7), round(lon * 1e7),
            round(alt * 1000.0), 80, 120, int(speed * 100.0), cog, sats,
        )  # fmt: skip

    def _build_system_time(self) -> Any:
        return self.dialect.MAVLink_system_time_message(
            int((SIM_EPOCH_UNIX_S + self.t_s) * 1e6), self.time_boot_ms()
        )

    def _build_home_position(self) -> Any:
        lat, lon, alt = self.options.home.to_global(self.home_ned)
        return self.dialect.MAVLink_home_position_message(
            round(lat * 1e7), round(lon * 1e7), round(alt * 1000.0),
            0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, int(self.t_s * 1e6),
        )  # fmt: skip

    def _build_battery_status(self) -> Any:
        cells = [4050] * 4 + [65535] * 6
        return self.dialect.MAVLink_battery_status_message(
            0, 0, 1, 32767, cells, 500 if self.armed else 50, -1, -1, self.battery_remaining()
        )

    def _build_autopilot_version(self) -> Any:
        uid = 0x0BF0_0000_0000_0000 | self.sys_id
        uid2 = list(b"bearingflock" + self.sys_id.to_bytes(6, "big"))
        return self.dialect.MAVLink_autopilot_version_message(
            self.capabilities, self.flight_sw_version, 0, 0, 0,
            [0] * 8, [0] * 8, [0] * 8, 0, 0, uid, uid2,
        )  # fmt: skip


SIM_EPOCH_UNIX_S = 1_735_689_600.0
"""Unix time that simulation time 0 maps to in SYSTEM_TIME (2025-01-01 00:00 UTC)."""


def quaternion_from_euler(
    roll: float, pitch: float, yaw: float
) -> tuple[float, float, float, float]:
    """(w, x, y, z) of the ZYX Euler angles (yaw, then pitch, then roll), as MAVLink uses."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def _i16(x: float) -> int:
    return int(max(-32768, min(32767, round(x))))
