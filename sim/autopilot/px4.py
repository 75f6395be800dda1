"""The PX4 flavour (docs/sim.md; PX4 ``commander`` and ``mavlink_receiver``).

* identity: autopilot 12, modes as ``custom_mode = (main << 16) | (sub << 24)``, boots in
  AUTO.LOITER (MAVSDK: HOLD);
* NAV_TAKEOFF switches to AUTO.TAKEOFF (``MIS_TAKEOFF_ALT`` above home; taking off at once
  if armed, on arming otherwise) and to AUTO.LOITER when the altitude is reached;
* velocity setpoints in frames 1 and 8; every valid one is proof of life, but only OFFBOARD
  flies them. OFFBOARD may be entered only with a setpoint younger than ``COM_OF_LOSS_T``
  (else TEMPORARILY_REJECTED); setpoints lost for longer than ``COM_OF_LOSS_T`` in OFFBOARD
  switch to AUTO.LOITER (failsafe, with a STATUSTEXT);
* auto-disarm ``COM_DISARM_LAND`` after landing, and (strict) ``COM_DISARM_PRFLT`` after
  arming without taking off.
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as px4_dialect

from messages import mavlink as mv
from sim.autopilot.common import Autopilot, Phase, mv_severity

_NEEDS_POSITION = frozenset(
    {"POSCTL", "OFFBOARD", "AUTO.LOITER", "AUTO.TAKEOFF", "AUTO.LAND", "AUTO.RTL", "AUTO.MISSION"}
)
_AUTO_FLAGS = mv.BASE_MODE_AUTO | mv.BASE_MODE_GUIDED | mv.BASE_MODE_STABILIZE


class Px4Autopilot(Autopilot):
    autopilot_type = mv.MAV_AUTOPILOT_PX4
    dialect = px4_dialect
    land_mode = "AUTO.LAND"
    return_mode = "AUTO.RTL"
    boot_mode = "AUTO.LOITER"
    setpoint_frames = frozenset({mv.FRAME_LOCAL_NED, mv.FRAME_BODY_NED})
    denied_result = mv.RESULT_DENIED
    not_ready_text = "Arming denied: Preflight Fail: ekf2 not ready"
    flight_sw_version = (1 << 24) | (15 << 16) | (0 << 8) | 255
    capabilities = 1 | 2 | 4 | 8 | 16 | 64 | 128 | 8192
    last_setpoint: mv.VelocitySetpoint | None = None

    def heartbeat_modes(self) -> tuple[int, int]:
        main, sub = mv.PX4_MODES[self.mode]
        base = mv.BASE_MODE_CUSTOM
        if main in (mv.PX4_MAIN_AUTO, mv.PX4_MAIN_OFFBOARD):
            base |= _AUTO_FLAGS
        elif main in (mv.PX4_MAIN_POSCTL, mv.PX4_MAIN_ALTCTL):
            base |= mv.BASE_MODE_MANUAL | mv.BASE_MODE_STABILIZE
        elif main == mv.PX4_MAIN_MANUAL:
            base |= mv.BASE_MODE_MANUAL
        return base, mv.px4_custom_mode(main, sub)

    def mode_from_command(self, p1: float, p2: float, p3: float) -> str | int | None:
        if not all(math.isfinite(x) for x in (p1, p2, p3)) or not int(p1) & mv.BASE_MODE_CUSTOM:
            return None
        name = mv.px4_mode_name(int(p2), int(p3))
        return mv.RESULT_DENIED if name is None else name

    def mode_from_set_mode(self, base_mode: int, custom_mode: int) -> str | int | None:
        if not base_mode & mv.BASE_MODE_CUSTOM:
            return None
        return mv.px4_mode_name(*mv.px4_decode_custom_mode(custom_mode))

    def enter_mode(self, mode: str) -> tuple[int, str]:
        if not self.booted and mode in _NEEDS_POSITION:
            return (
                mv.RESULT_TEMPORARILY_REJECTED,
                f"Switching to {mode} denied: no position estimate",
            )
        if mode == "OFFBOARD":
            if self.t_s - self.last_setpoint_t_s > float(self.params.get("COM_OF_LOSS_T")):
                return mv.RESULT_TEMPORARILY_REJECTED, "Switching to Offboard denied: no setpoints"
            self.set_mode(mode)
            if self.armed and self.last_setpoint is not None:
                self.fly_velocity(self.last_setpoint)
            return mv.RESULT_ACCEPTED, ""
        if mode == "AUTO.TAKEOFF":
            return self.on_takeoff_command([math.nan] * 7)
        self.set_mode(mode)
        if mode == "AUTO.LAND":
            if self.airborne:
                self.start_landing()
        elif mode == "AUTO.RTL":
            if self.airborne:
                self.start_return(float(self.params.get("RTL_RETURN_ALT")))
        elif self.airborne or self.armed:
            self.hold_or_idle()
        return mv.RESULT_ACCEPTED, ""

    def takeoff_altitude_m(self) -> float:
        return float(self.params.get("MIS_TAKEOFF_ALT"))

    def on_takeoff_command(self, p: list[float]) -> tuple[int, str]:
        if not self.booted:
            return mv.RESULT_TEMPORARILY_REJECTED, "Takeoff denied: no position estimate"
        self.set_mode("AUTO.TAKEOFF")
        if self.armed and self.phase in (Phase.GROUND, Phase.AIR):
            self.start_takeoff(max(self.takeoff_altitude_m(), self.altitude_m))
        return mv.RESULT_ACCEPTED, ""

    def arm(self) -> None:
        super().arm()
        if self.mode == "AUTO.TAKEOFF" and self.phase == Phase.GROUND:
            self.start_takeoff(self.takeoff_altitude_m())
        elif self.mode == "OFFBOARD" and self.last_setpoint is not None:
            self.fly_velocity(self.last_setpoint)

    def on_takeoff_complete(self) -> None:
        self.set_mode("AUTO.LOITER")
        self.hold_here(z_ned=self.takeoff_target_z)

    def on_velocity_setpoint(self, sp: mv.VelocitySetpoint) -> None:
        self.last_setpoint_t_s = self.t_s
        self.last_setpoint = sp
        if self.mode == "OFFBOARD" and self.armed:
            self.fly_velocity(sp)

    def check_setpoint_loss(self) -> None:
        if self.mode != "OFFBOARD":
            return
        if self.t_s - self.last_setpoint_t_s > float(self.params.get("COM_OF_LOSS_T")):
            self.statustext(mv_severity("critical"), "Failsafe: offboard signal lost, Hold")
            self.set_mode("AUTO.LOITER")
            self.hold_or_idle()

    def disarm_after_land_s(self) -> float:
        return float(self.params.get("COM_DISARM_LAND"))

    def autodisarm_unflown_s(self) -> float:
        return float(self.params.get("COM_DISARM_PRFLT"))
