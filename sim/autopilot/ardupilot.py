"""The ArduCopter flavour (``shared/notes/mavlink.md``; ArduCopter ``GCS_MAVLink_Copter.cpp``,
``mode_guided.cpp``).

* identity: autopilot 3, ``custom_mode`` = Copter mode number, boots in STABILIZE;
  DO_SET_MODE needs the custom-mode bit (else UNSUPPORTED), SET_MODE (id 11) works too;
  unknown mode numbers FAIL;
* NAV_TAKEOFF (altitude in param 7) only armed, landed, in GUIDED and above the current
  altitude; the vehicle stays in GUIDED;
* velocity setpoints in frames 1, 7 (NED) and 8, 9 (heading frame; a yaw angle in these frames
  is relative to the current heading), only in GUIDED and airborne; NaN means stop; after
  ``GUID_TIMEOUT`` without setpoints the velocity goes to zero and the vehicle stays in GUIDED;
* LAND and RTL disarm one second after touchdown; otherwise ``DISARM_DELAY``;
* strict: nothing but HEARTBEAT streams until requested, velocity targets ignored while a
  takeoff climbs, and everything common strict mode does.
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import ardupilotmega as ap_dialect

from messages import mavlink as mv
from sim.autopilot.common import Autopilot, Phase

_NEEDS_POSITION = frozenset({"GUIDED", "LOITER", "RTL", "AUTO", "POSHOLD", "BRAKE", "CIRCLE"})
_NOT_ARMABLE = frozenset({"LAND", "RTL", "AUTO", "CIRCLE", "BRAKE"})
_SUPPORTED = frozenset(
    {"STABILIZE", "ACRO", "ALT_HOLD", "AUTO", "GUIDED", "LOITER", "RTL", "CIRCLE", "LAND"}
    | {"POSHOLD", "BRAKE", "GUIDED_NOGPS"}
)
ABSURD_SPEED_MPS = 100.0


class ArduPilotAutopilot(Autopilot):
    autopilot_type = mv.MAV_AUTOPILOT_ARDUPILOTMEGA
    dialect = ap_dialect
    land_mode = "LAND"
    return_mode = "RTL"
    boot_mode = "STABILIZE"
    setpoint_frames = frozenset(
        {mv.FRAME_LOCAL_NED, mv.FRAME_LOCAL_OFFSET_NED, mv.FRAME_BODY_NED, mv.FRAME_BODY_OFFSET_NED}
    )
    denied_result = mv.RESULT_FAILED
    not_ready_text = "PreArm: EKF3 still initialising"
    flight_sw_version = (4 << 24) | (5 << 16) | (7 << 8) | 255
    capabilities = 1 | 2 | 4 | 8 | 64 | 128 | 256 | 8192 | 131072

    def streams_on_boot(self) -> bool:
        return not self.options.strict

    def heartbeat_modes(self) -> tuple[int, int]:
        base = mv.BASE_MODE_CUSTOM | mv.BASE_MODE_STABILIZE
        number = mv.COPTER_MODES[self.mode]
        if number in mv.COPTER_GUIDED_LIKE:
            base |= mv.BASE_MODE_GUIDED
        return base, number

    def mode_from_command(self, p1: float, p2: float, p3: float) -> str | int | None:
        if not (math.isfinite(p1) and math.isfinite(p2)) or not int(p1) & mv.BASE_MODE_CUSTOM:
            return None
        return self._mode_name(int(p2))

    def mode_from_set_mode(self, base_mode: int, custom_mode: int) -> str | int | None:
        if not base_mode & mv.BASE_MODE_CUSTOM:
            return None
        return self._mode_name(custom_mode)

    @staticmethod
    def _mode_name(number: int) -> str | int:
        name = mv.COPTER_MODE_NAMES.get(number)
        return name if name in _SUPPORTED else mv.RESULT_FAILED

    def enter_mode(self, mode: str) -> tuple[int, str]:
        if not self.booted and mode in _NEEDS_POSITION:
            return mv.RESULT_FAILED, f"Mode change to {mode} failed: requires position"
        self.set_mode(mode)
        if mode == "LAND":
            if self.airborne:
                self.start_landing()
        elif mode == "RTL":
            if self.airborne:
                self.start_return(float(self.params.get("RTL_ALT")) / 100.0)
        elif self.airborne or self.armed:
            self.hold_or_idle()
        return mv.RESULT_ACCEPTED, ""

    def arm_refusal(self) -> tuple[int, str] | None:
        refusal = super().arm_refusal()
        if refusal is None and self.mode in _NOT_ARMABLE:
            return mv.RESULT_FAILED, "Arm: Mode not armable"
        return refusal

    def on_takeoff_command(self, p: list[float]) -> tuple[int, str]:
        alt = p[6]
        if self.mode != "GUIDED":
            return mv.RESULT_FAILED, "Takeoff: not in GUIDED"
        if not self.armed:
            return mv.RESULT_FAILED, "Takeoff: not armed"
        if self.phase != Phase.GROUND:
            return mv.RESULT_FAILED, "Takeoff: already flying"
        if not math.isfinite(alt) or alt <= self.altitude_m:
            return mv.RESULT_FAILED, "Takeoff: altitude below current"
        self.start_takeoff(alt)
        return mv.RESULT_ACCEPTED, ""

    def on_velocity_setpoint(self, sp: mv.VelocitySetpoint) -> None:
        if self.mode != "GUIDED" or not self.armed or self.phase not in (Phase.AIR, Phase.TAKEOFF):
            self.counters.ignored_setpoints += 1
            return
        if self.phase == Phase.TAKEOFF and self.options.strict:
            self.counters.ignored_setpoints += 1  # a real Copter finishes its takeoff first
            return
        self.last_setpoint_t_s = self.t_s
        if max(abs(v) for v in sp.v_mps) > ABSURD_SPEED_MPS:
            sp = mv.VelocitySetpoint(sp.frame, (0.0, 0.0, 0.0), None, None, stop=True)
        self.fly_velocity(sp, yaw_relative=sp.body)

    def check_setpoint_loss(self) -> None:
        if not self.velocity_active or self.mode != "GUIDED":
            return
        if self.t_s - self.last_setpoint_t_s > float(self.params.get("GUID_TIMEOUT")):
            self.events.append("guided timeout: velocity to zero")
            self.velocity_active = False
            self.world.command_velocity(self.index, (0.0, 0.0, 0.0), body=False)
            self.world.command_yaw_rate(self.index, 0.0)

    def disarm_after_land_s(self) -> float:
        return 1.0 if self.mode in ("LAND", "RTL") else float(self.params.get("DISARM_DELAY"))

    def autodisarm_unflown_s(self) -> float:
        return float(self.params.get("DISARM_DELAY"))
