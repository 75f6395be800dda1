"""What every simulated autopilot does, whatever its flavour.

One :class:`Autopilot` per vehicle owns the vehicle's flight logic (armed state, mode, the
takeoff / hold / land / return state machine, auto-disarm), its parameter table and its
telemetry streams, and turns MAVLink messages into commands on the shared
:class:`~sim.world.World`. It never touches sockets: it receives parsed messages through
:meth:`Autopilot.handle` and emits messages through the ``send`` callable its link gives it.

The flavour subclasses (:mod:`sim.autopilot.px4`, :mod:`sim.autopilot.ardupilot`) decide the
identity and mode encoding, which modes exist and when they may be entered, how takeoff
commands and velocity setpoints are interpreted, and the setpoint-loss behaviour
(docs/sim.md).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from types import ModuleType
from typing import Any

import numpy as np

from messages import mavlink as mv
from sim.autopilot.link import LinkCounters
from sim.autopilot.params import PARAM_TYPE_REAL32, ParamTable
from sim.autopilot.state import LANDED_STATE, AutopilotOptions, Home, Phase
from sim.autopilot.telemetry import STREAM_IDS, STREAM_NAMES, Telemetry
from sim.world import Observation, World

__all__ = ["LANDED_STATE", "Autopilot", "AutopilotOptions", "Home", "Phase"]

LAND_DETECT_S = 1.0
"""A vehicle resting on the ground this long in a non-landing phase counts as landed."""
GROUND_EPS_M = 0.05
TAKEOFF_TOLERANCE_M = 0.15
RETURN_TOLERANCE_M = 0.5


class Autopilot(Telemetry):
    """Flavour-independent autopilot of vehicle ``index`` (system id ``index + 1``)."""

    autopilot_type = 0
    dialect: ModuleType
    land_mode = ""
    return_mode = ""
    boot_mode = ""

    def __init__(
        self,
        index: int,
        world: World,
        params: ParamTable,
        options: AutopilotOptions,
        counters: LinkCounters,
    ) -> None:
        self.index = index
        self.sys_id = index + 1
        self.world = world
        self.params = params
        self.options = options
        self.counters = counters
        self.send: Callable[[Any], None] = lambda _msg: None
        self.t_s = world.t_s
        self.armed = False
        self.armed_t_s = 0.0
        self.flew_since_arm = False
        self.phase = Phase.GROUND
        self.takeoff_target_z = 0.0
        self.landed_t_s: float | None = None
        self.ground_since_s: float | None = None
        self.mode = self.boot_mode
        self.booted = not options.strict
        self.home_ned = world.p_ned[index].copy()
        self.return_target_ned = self.home_ned.copy()
        self.last_setpoint_t_s = -math.inf
        self.velocity_active = False
        self.events: list[str] = []
        self.obs: Observation | None = None
        self.init_streams(self.streams_on_boot())
        self._handlers: dict[str, Callable[[Any], None]] = {
            "COMMAND_LONG": self._on_command_long,
            "COMMAND_INT": self._on_command_int,
            "SET_MODE": self._on_set_mode,
            "SET_POSITION_TARGET_LOCAL_NED": self._on_setpoint,
            "PARAM_REQUEST_LIST": self._on_param_request_list,
            "PARAM_REQUEST_READ": self._on_param_request_read,
            "PARAM_SET": self._on_param_set,
            "REQUEST_DATA_STREAM": self._on_request_data_stream,
            "PING": self._on_ping,
            "TIMESYNC": self._on_timesync,
            "MISSION_REQUEST_LIST": self._on_mission_request_list,
            "FILE_TRANSFER_PROTOCOL": self._on_ftp,
        }

    # ------------------------------------------------------------------------------------------
    # flavour hooks
    # ------------------------------------------------------------------------------------------
    def heartbeat_modes(self) -> tuple[int, int]:
        """(base_mode without the armed bit, custom_mode) of the current mode."""
        raise NotImplementedError

    def mode_from_command(self, p1: float, p2: float, p3: float) -> str | int | None:
        """Mode requested by DO_SET_MODE (``None``: not understood)."""
        raise NotImplementedError

    def mode_from_set_mode(self, base_mode: int, custom_mode: int) -> str | int | None:
        raise NotImplementedError

    def enter_mode(self, mode: str) -> tuple[int, str]:
        """Try to switch to ``mode``: (COMMAND_ACK result, STATUSTEXT reason if refused)."""
        raise NotImplementedError

    def on_takeoff_command(self, p: list[float]) -> tuple[int, str]:
        raise NotImplementedError

    def on_velocity_setpoint(self, sp: mv.VelocitySetpoint) -> None:
        raise NotImplementedError

    def check_setpoint_loss(self) -> None:
        raise NotImplementedError

    def on_takeoff_complete(self) -> None:
        self.hold_here(z_ned=self.takeoff_target_z)

    def streams_on_boot(self) -> bool:
        """Whether the default streams run without being requested."""
        return True

    def takeoff_step(self) -> None:
        """Called every step while taking off (the flavour shapes the climb; default: the
        world's position hold climbs to the target at once)."""

    def landing_step(self) -> None:
        """Called every step while landing (default: the world's hold descends)."""

    def autodisarm_unflown(self) -> bool:
        """Whether an armed vehicle that never took off disarms after
        :meth:`autodisarm_unflown_s` (default: only in strict mode)."""
        return self.options.strict

    landing_disarm_text = "Disarmed by landing"
    unflown_disarm_text = "Disarmed by auto preflight disarming"

    def arm_refusal(self) -> tuple[int, str] | None:
        """``None`` if arming is allowed now, else (result, reason)."""
        if not self.booted:
            return self.denied_result, self.not_ready_text
        return None

    def disarm_after_land_s(self) -> float:
        """Delay between touchdown and automatic disarm."""
        return 2.0

    def autodisarm_unflown_s(self) -> float:
        """Strict mode: disarm when armed this long without taking off."""
        return 10.0

    denied_result = mv.RESULT_DENIED
    not_ready_text = "Arming denied: estimator not ready"
    flight_sw_version = 0
    capabilities = 0

    # ------------------------------------------------------------------------------------------
    # flight logic
    # ------------------------------------------------------------------------------------------
    @property
    def p_ned(self) -> np.ndarray:
        return self.world.p_ned[self.index]

    @property
    def altitude_m(self) -> float:
        """Height above home (m, up positive)."""
        return float(self.home_ned[2] - self.p_ned[2])

    @property
    def on_ground(self) -> bool:
        return bool(self.p_ned[2] > -GROUND_EPS_M)

    @property
    def airborne(self) -> bool:
        return self.phase in (Phase.AIR, Phase.TAKEOFF, Phase.RETURN, Phase.LANDING)

    def statustext(self, severity: int, text: str) -> None:
        self.events.append(text)
        self.send(self.dialect.MAVLink_statustext_message(severity, text[:50].encode()))

    def set_mode(self, mode: str) -> None:
        if mode != self.mode:
            self.mode = mode
            self.send_heartbeat()  # show the change at once, not up to a second later

    def hold_or_idle(self) -> None:
        """Hold position if armed (leaving any takeoff/landing/return), else stay idle."""
        if not self.armed:
            self.idle()
            return
        if self.phase in (Phase.TAKEOFF, Phase.LANDING, Phase.RETURN):
            self.phase = Phase.AIR
        self.hold_here()

    def hold_here(self, z_ned: float | None = None) -> None:
        """Hold the current position (at height ``z_ned`` if given)."""
        self.velocity_active = False
        target = self.p_ned.copy()
        if z_ned is not None:
            target[2] = z_ned
        self.world.command_hold(self.index, target)
        self.world.command_yaw_rate(self.index, 0.0)

    def idle(self) -> None:
        """Disarmed: motors off. A disarmed vehicle in the air falls."""
        self.velocity_active = False
        w = self.world
        w.command_velocity(self.index, (0.0, 0.0, w.config.v_max_down_m_s), body=False)
        w.command_yaw_rate(self.index, 0.0)

    def start_takeoff(self, altitude_m: float) -> None:
        self.phase = Phase.TAKEOFF
        self.flew_since_arm = True
        self.velocity_active = False
        target = self.p_ned.copy()
        target[2] = self.home_ned[2] - altitude_m
        self.takeoff_target_z = float(target[2])
        self.world.command_hold(self.index, target)
        self.world.command_yaw_rate(self.index, 0.0)

    def start_landing(self) -> None:
        if not self.airborne or self.on_ground:
            return
        self.phase = Phase.LANDING
        self.velocity_active = False
        target = self.p_ned.copy()
        target[2] = 1.0  # below the ground: descend at the landing speed until touchdown
        self.world.command_hold(self.index, target)
        self.world.command_yaw_rate(self.index, 0.0)

    def start_return(self, return_alt_m: float) -> None:
        if not self.airborne:
            return
        self.phase = Phase.RETURN
        self.velocity_active = False
        target = self.home_ned.copy()
        target[2] = min(float(self.p_ned[2]), float(self.home_ned[2]) - return_alt_m)
        self.return_target_ned = target
        self.world.command_hold(self.index, target)
        self.world.command_yaw_rate(self.index, 0.0)

    def fly_velocity(self, sp: mv.VelocitySetpoint, yaw_relative: bool = False) -> None:
        """Track a velocity setpoint; NaN (``sp.stop``) means stop where you are."""
        w, i = self.world, self.index
        self.velocity_active = True
        if self.phase in (Phase.GROUND, Phase.TAKEOFF, Phase.RETURN, Phase.LANDING):
            if self.phase != Phase.GROUND:
                self.phase = Phase.AIR
        if sp.stop:
            w.command_velocity(i, (0.0, 0.0, 0.0), body=False)
            w.command_yaw_rate(i, 0.0)
            return
        w.command_velocity(i, sp.v_m_s, body=sp.body)
        if sp.yaw_rate_rad_s is not None:
            w.command_yaw_rate(i, sp.yaw_rate_rad_s)
        elif sp.yaw_rad is not None:
            yaw = sp.yaw_rad + (float(w.yaw_rad[i]) if yaw_relative else 0.0)
            w.command_yaw(i, yaw)
        else:
            w.command_yaw_rate(i, 0.0)

    def arm(self) -> None:
        if not self.armed:
            self.armed = True
            self.armed_t_s = self.t_s
            self.flew_since_arm = False
            self.landed_t_s = None
            if self.phase == Phase.GROUND:
                self.hold_here()
            self.send_heartbeat()

    def disarm(self, reason: str = "") -> None:
        if self.armed:
            self.armed = False
            self.landed_t_s = None
            self.idle()
            if reason:
                self.statustext(mv_severity("info"), reason)
            self.send_heartbeat()

    def update(self, t_s: float) -> None:
        """Advance the flight logic to simulation time ``t_s`` (called after each world step)."""
        self.t_s = t_s
        if not self.booted and t_s >= self.options.warmup_s:
            self.end_boot()
        on_ground = self.on_ground
        if not self.armed:
            if on_ground:
                self.phase = Phase.GROUND
        elif self.phase == Phase.TAKEOFF:
            if self.p_ned[2] <= self.takeoff_target_z + TAKEOFF_TOLERANCE_M:
                self.phase = Phase.AIR
                self.on_takeoff_complete()
            else:
                self.takeoff_step()
        elif self.phase == Phase.LANDING:
            if on_ground:
                self.touchdown()
            else:
                self.landing_step()
        elif self.phase == Phase.RETURN:
            d_xy = float(np.linalg.norm(self.p_ned[:2] - self.return_target_ned[:2]))
            if d_xy < RETURN_TOLERANCE_M:
                self.start_landing()
        elif self.phase == Phase.AIR:
            if on_ground:
                if self.ground_since_s is None:
                    self.ground_since_s = t_s
                elif t_s - self.ground_since_s >= LAND_DETECT_S:
                    self.touchdown()
            else:
                self.ground_since_s = None
        elif self.phase == Phase.GROUND and self.p_ned[2] < -2.0 * GROUND_EPS_M:
            self.phase = Phase.AIR  # climbing under velocity control
            self.flew_since_arm = True
            self.ground_since_s = None
        if self.armed and self.phase == Phase.GROUND:
            if self.landed_t_s is not None and t_s - self.landed_t_s >= self.disarm_after_land_s():
                self.disarm(self.landing_disarm_text)
            elif (
                self.autodisarm_unflown()
                and not self.flew_since_arm
                and t_s - self.armed_t_s >= self.autodisarm_unflown_s()
            ):
                self.disarm(self.unflown_disarm_text)
        self.check_setpoint_loss()

    def touchdown(self) -> None:
        self.phase = Phase.GROUND
        self.landed_t_s = self.t_s
        self.ground_since_s = None
        self.hold_here()

    def end_boot(self) -> None:
        """Strict mode: the estimator is ready; a mode chosen during boot is reverted."""
        self.booted = True
        if self.mode != self.boot_mode:
            self.statustext(
                mv_severity("warning"), f"Boot complete: mode reverted to {self.boot_mode}"
            )
            self.set_mode(self.boot_mode)
        else:
            self.statustext(mv_severity("info"), "Estimator ready")

    # ------------------------------------------------------------------------------------------
    # message handling
    # ------------------------------------------------------------------------------------------
    def handle(self, msg: Any) -> None:
        """React to one valid message from a client."""
        h = self._handlers.get(msg.get_type())
        if h is not None:
            h(msg)

    def _for_me(self, target_system: int, target_component: int | None = None) -> bool:
        if target_system not in (0, self.sys_id):
            self.counters.foreign_target += 1
            return False
        if target_component is not None and target_component not in (0, mv.COMPONENT_AUTOPILOT):
            return False
        return True

    def _ack(self, msg: Any, command: int, result: int) -> None:
        self.send(
            self.dialect.MAVLink_command_ack_message(
                command,
                result,
                0,
                0,
                msg.get_srcSystem(),
                msg.get_srcComponent(),
            )
        )

    def _on_command_long(self, msg: Any) -> None:
        if not self._for_me(msg.target_system, msg.target_component):
            return
        p = [msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7]
        self._command(msg, int(msg.command), p)

    def _on_command_int(self, msg: Any) -> None:
        if not self._for_me(msg.target_system, msg.target_component):
            return
        p = [msg.param1, msg.param2, msg.param3, msg.param4, float(msg.x), float(msg.y), msg.z]
        self._command(msg, int(msg.command), p)

    def _command(self, msg: Any, command: int, p: list[float]) -> None:
        result, reason = self.run_command(command, p)
        self._ack(msg, command, result)
        if reason:
            self.statustext(mv_severity("critical"), reason)
        if result == mv.RESULT_ACCEPTED and command == mv.CMD_REQUEST_MESSAGE:
            self.send_once(int(p[0]))
        elif result == mv.RESULT_ACCEPTED and command == mv.CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            self.send_once(STREAM_IDS["AUTOPILOT_VERSION"])

    def run_command(self, command: int, p: list[float]) -> tuple[int, str]:
        """Execute a command: (COMMAND_ACK result, STATUSTEXT reason or '')."""
        if command == mv.CMD_COMPONENT_ARM_DISARM:
            return self.cmd_arm_disarm(p)
        if command == mv.CMD_DO_SET_MODE:
            mode = self.mode_from_command(p[0], p[1], p[2])
            if mode is None:
                return mv.RESULT_UNSUPPORTED, ""
            if isinstance(mode, int):  # understood, but not a mode we have
                return mode, "Unsupported mode"
            return self.enter_mode(mode)
        if command == mv.CMD_NAV_TAKEOFF:
            return self.on_takeoff_command(p)
        if command == mv.CMD_NAV_LAND:
            return self.enter_mode(self.land_mode)
        if command == mv.CMD_NAV_RETURN_TO_LAUNCH:
            return self.enter_mode(self.return_mode)
        if command == mv.CMD_SET_MESSAGE_INTERVAL:
            return self.set_message_interval(p[0], p[1]), ""
        if command == mv.CMD_REQUEST_MESSAGE:
            ok = int(p[0]) in STREAM_NAMES if math.isfinite(p[0]) else False
            return (mv.RESULT_ACCEPTED if ok else mv.RESULT_UNSUPPORTED), ""
        if command == mv.CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            return mv.RESULT_ACCEPTED, ""
        return mv.RESULT_UNSUPPORTED, ""

    def cmd_arm_disarm(self, p: list[float]) -> tuple[int, str]:
        if p[0] == 1.0:
            if self.armed:
                return mv.RESULT_ACCEPTED, ""
            refusal = self.arm_refusal()
            if refusal is not None:
                return refusal
            self.arm()
            return mv.RESULT_ACCEPTED, ""
        if p[0] == 0.0:
            forced = p[1] == mv.FORCE_DISARM_MAGIC
            if self.armed and self.phase != Phase.GROUND and not forced:
                return self.denied_result, "Disarming denied: not landed"
            self.disarm()
            return mv.RESULT_ACCEPTED, ""
        return self.denied_result, ""

    def _on_set_mode(self, msg: Any) -> None:
        if not self._for_me(msg.target_system):
            return
        mode = self.mode_from_set_mode(int(msg.base_mode), int(msg.custom_mode))
        if isinstance(mode, str):
            result, reason = self.enter_mode(mode)
        else:
            result, reason = mv.RESULT_UNSUPPORTED, "Unsupported mode"
        self._ack(msg, 11, result)  # ArduPilot acks SET_MODE with command id 11
        if reason:
            self.statustext(mv_severity("critical"), reason)

    def _on_setpoint(self, msg: Any) -> None:
        if not self._for_me(msg.target_system, msg.target_component):
            return
        sp = mv.velocity_setpoint(
            int(msg.coordinate_frame),
            int(msg.type_mask),
            (msg.vx, msg.vy, msg.vz),
            msg.yaw,
            msg.yaw_rate,
        )
        if sp is None or sp.frame not in self.setpoint_frames:
            self.counters.ignored_setpoints += 1
            return
        if sp.stop:
            self.counters.nan_setpoints += 1
        self.on_velocity_setpoint(sp)

    setpoint_frames: frozenset[int] = frozenset()

    # --- parameters ------------------------------------------------------------------------------
    def _param_value(self, index: int) -> Any:
        p = self.params.by_index(index)
        assert p is not None
        return self.dialect.MAVLink_param_value_message(
            p.name.encode(), self.params.wire_value(p), p.param_type, len(self.params), index
        )

    def _on_param_request_list(self, msg: Any) -> None:
        if self._for_me(msg.target_system, msg.target_component):
            for k in range(len(self.params)):
                self.send(self._param_value(k))

    def _on_param_request_read(self, msg: Any) -> None:
        if not self._for_me(msg.target_system, msg.target_component):
            return
        if msg.param_index >= 0:
            if self.params.by_index(msg.param_index) is not None:
                self.send(self._param_value(msg.param_index))
            return
        found = self.params.by_name(_param_name(msg.param_id))
        if found is not None:
            self.send(self._param_value(found[0]))

    def _on_param_set(self, msg: Any) -> None:
        """Apply and echo the new value; an invalid one (wrong type, non-finite, outside the
        documented range, :mod:`sim.autopilot.params`) is refused: the table is unchanged, a
        STATUSTEXT names the range, and PARAM_VALUE carries the current value, as the parameter
        protocol asks of a failed set."""
        if not self._for_me(msg.target_system, msg.target_component):
            return
        name = _param_name(msg.param_id)
        found = self.params.by_name(name)
        if found is None:
            return
        value = float(msg.param_value)
        if self.params.set_from_wire(name, value, int(msg.param_type)) is None:
            self.counters.params_refused += 1
            p = found[1]
            shown = (
                f"{value:g}"
                if p.param_type == PARAM_TYPE_REAL32 or not self.params.bytewise
                else "value"
            )
            self.statustext(
                mv_severity("warning"), f"{name}: {shown} out of range {p.range_text()}"
            )
        self.send(self._param_value(found[0]))

    def _on_ping(self, msg: Any) -> None:
        if msg.target_system == 0 and msg.target_component == 0:
            self.send(
                self.dialect.MAVLink_ping_message(
                    msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent()
                )
            )

    def _on_timesync(self, msg: Any) -> None:
        if msg.tc1 == 0:
            self.send(self.dialect.MAVLink_timesync_message(int(self.t_s * 1e9), msg.ts1))

    def _on_mission_request_list(self, msg: Any) -> None:
        if self._for_me(msg.target_system, msg.target_component):
            self.send(
                self.dialect.MAVLink_mission_count_message(
                    msg.get_srcSystem(), msg.get_srcComponent(), 0, msg.mission_type
                )
            )

    def _on_ftp(self, msg: Any) -> None:
        """MAVLink FTP is not offered: NAK every request with "file not found", so clients
        (MAVProxy's parameter download) fall back to the parameter protocol at once."""
        if not self._for_me(msg.target_system, msg.target_component):
            return
        req = bytes(msg.payload[:12]).ljust(12, b"\0")
        seq, session, opcode = struct.unpack_from("<HBB", req)
        nak = struct.pack("<HBBBBBBI", (seq + 1) & 0xFFFF, session, FTP_NAK, 1, opcode, 0, 0, 0)
        payload = list(nak + bytes([FTP_ERR_FILE_NOT_FOUND])) + [0] * (251 - len(nak) - 1)
        self.send(
            self.dialect.MAVLink_file_transfer_protocol_message(
                0, msg.get_srcSystem(), msg.get_srcComponent(), payload
            )
        )


FTP_NAK = 129
FTP_ERR_FILE_NOT_FOUND = 10


def mv_severity(name: str) -> int:
    """MAV_SEVERITY by name."""
    return {"critical": 2, "error": 3, "warning": 4, "notice": 5, "info": 6}[name]


def _param_name(raw: Any) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", errors="replace")
    return str(raw).rstrip("\x00")
