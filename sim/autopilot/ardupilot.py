"""The ArduCopter flavour (docs/sim.md; ArduCopter ``GCS_MAVLink_Copter.cpp``,
``mode_guided.cpp``), made to behave like ArduCopter 4.7 SITL where it was measured
(docs/sim.md, "ArduPilot flavour"):

* identity: autopilot 3, ``custom_mode`` = Copter mode number, boots in STABILIZE;
  DO_SET_MODE needs the custom-mode bit (else UNSUPPORTED), SET_MODE (id 11) works too;
  unknown mode numbers FAIL;
* streams: nothing but HEARTBEAT (and the answers STATUSTEXT, PARAM_VALUE, COMMAND_ACK) until
  asked with SET_MESSAGE_INTERVAL or REQUEST_DATA_STREAM (``boot_streams`` restores streaming
  from boot); LOCAL_POSITION_NED and HOME_POSITION only once the EKF has a position
  (``ekf_warmup_s`` after boot; the request is accepted before and the stream starts by itself);
* modes: any mode while disarmed; a mode that needs a position is refused in flight without
  one; arming is refused with ArduCopter's texts ("Arm: Need Position Estimate", "Arm: Mode not
  armable", ...) until the EKF is ready, and an armed vehicle that does not take off disarms
  after ``DISARM_DELAY`` ("Disarming motors");
* NAV_TAKEOFF (altitude in param 7) only armed, landed, in GUIDED and above the current
  altitude, refused without a text as ArduCopter does; the motors spool up first, then the
  vehicle climbs with a limited acceleration and slows down towards the target (measured: lift
  off 1.7 s after the command, 5 m in 6.3 s, at most 1.8 m/s); it stays GUIDED and ignores
  velocity targets until the climb is over;
* velocity setpoints in frames 1, 7 (NED) and 8, 9 (heading frame; a yaw angle in these frames
  is relative to the current heading), only in GUIDED and airborne; NaN means stop; after
  ``GUID_TIMEOUT`` without setpoints the velocity goes to zero and the vehicle stays in GUIDED;
* LAND descends at ``LAND_SPEED`` (0.5 m/s; ``LAND_SPEED_HIGH``/``WPNAV_SPEED_DN`` above
  ``LAND_ALT_LOW``) and disarms 2 s after touchdown ("Disarming motors"), staying in LAND;
* a NaN where ArduCopter converts a command parameter to an integer or compares it (ARM_DISARM
  params 1-2, DO_SET_MODE 1-2, SET_MESSAGE_INTERVAL 1-2, REQUEST_MESSAGE 1) aborts the real
  SITL with a floating-point exception: here it is refused (DENIED, with a STATUSTEXT) and
  counted (``nan_commands``);
* strict: a mode set before the end of the boot (``warmup_s``, "ArduPilot Ready") is reverted
  to STABILIZE, and arming is refused until then.
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
NEEDS_POSITION_STREAMS = frozenset({"LOCAL_POSITION_NED", "HOME_POSITION"})
"""What ArduCopter sends only once its EKF has a position (origin set)."""

NAN_ABORTS: dict[int, tuple[int, ...]] = {
    mv.CMD_COMPONENT_ARM_DISARM: (0, 1),
    mv.CMD_DO_SET_MODE: (0, 1),
    mv.CMD_SET_MESSAGE_INTERVAL: (0, 1),
    mv.CMD_REQUEST_MESSAGE: (0,),
}
"""Command -> 0-based parameters whose NaN aborts ArduCopter 4.7 SITL (floating-point
exception; each measured). NAV_TAKEOFF's param 7 NaN is only refused (FAILED)."""

TAKEOFF_SPOOL_S = 1.3
"""Seconds from NAV_TAKEOFF to the climb command (the world's velocity lag adds ~0.3 s:
SITL's altitude rises 5 cm 1.7 s after the command)."""
TAKEOFF_ON_GROUND_S = 1.3
"""EXTENDED_SYS_STATE says ON_GROUND this long after the command, then TAKEOFF."""
TAKEOFF_ACCEL_M_S2 = 1.4
TAKEOFF_DECEL_M_S2 = 0.5
"""Climb profile ``min(PILOT_SPEED_UP, accel t, sqrt(2 decel remaining))``, fitted (least
squares over 12 heights, 0.05 m rms) to SITL's 5 m take-off: 1.46 m at 3.0 s, 3.19 m at
4.0 s, 4.37 m at 5.0 s, peak climb 1.77 m/s (here 1.80)."""
LAND_DISARM_S = 2.0
"""Touchdown to "Disarming motors" (SITL: 2.1 s)."""


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
    not_ready_text = "Arm: AHRS: EKF3 still initialising"
    flight_sw_version = (4 << 24) | (5 << 16) | (7 << 8) | 255
    capabilities = 1 | 2 | 4 | 8 | 64 | 128 | 256 | 8192 | 131072
    landing_disarm_text = "Disarming motors"
    unflown_disarm_text = "Disarming motors"

    takeoff_t0_s = 0.0

    # --- boot and estimator -------------------------------------------------------------------
    def streams_on_boot(self) -> bool:
        return self.options.boot_streams and not self.options.strict

    @property
    def position_ok(self) -> bool:
        """The EKF has a position (``ekf_warmup_s`` after boot)."""
        return self.booted and self.t_s >= self.options.ekf_warmup_s

    def stream_ready(self, name: str) -> bool:
        return name not in NEEDS_POSITION_STREAMS or self.position_ok

    def end_boot(self) -> None:
        """Strict: the end of ArduCopter's init ("ArduPilot Ready") puts it in STABILIZE,
        whatever mode was set before."""
        self.booted = True
        self.statustext(6, "ArduPilot Ready")
        if self.mode != self.boot_mode:
            self.set_mode(self.boot_mode)

    # --- modes ----------------------------------------------------------------------------------
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
        if self.armed and mode in _NEEDS_POSITION and not self.position_ok:
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
        if not self.booted:
            return mv.RESULT_FAILED, self.not_ready_text
        if self.mode in _NOT_ARMABLE:
            return mv.RESULT_FAILED, "Arm: Mode not armable"
        if not self.position_ok:
            if self.mode in _NEEDS_POSITION:
                return mv.RESULT_FAILED, "Arm: Need Position Estimate"
            return mv.RESULT_FAILED, "Arm: EKF attitude is bad"
        return None

    # --- commands -------------------------------------------------------------------------------
    def run_command(self, command: int, p: list[float]) -> tuple[int, str]:
        bad = [k + 1 for k in NAN_ABORTS.get(command, ()) if not math.isfinite(p[k])]
        if bad:
            self.counters.nan_commands += 1
            which = ", ".join(str(k) for k in bad)
            return mv.RESULT_DENIED, f"Refused: NaN in param {which} (ArduCopter SITL aborts)"
        return super().run_command(command, p)

    def on_takeoff_command(self, p: list[float]) -> tuple[int, str]:
        # ArduCopter refuses these without a STATUSTEXT (do_user_takeoff returns false)
        alt = p[6]
        if self.mode != "GUIDED" or not self.armed or self.phase != Phase.GROUND:
            return mv.RESULT_FAILED, ""
        if not math.isfinite(alt) or alt <= self.altitude_m:
            return mv.RESULT_FAILED, ""
        self.start_takeoff(alt)
        return mv.RESULT_ACCEPTED, ""

    # --- take-off and landing -------------------------------------------------------------------
    def start_takeoff(self, altitude_m: float) -> None:
        super().start_takeoff(altitude_m)
        self.takeoff_t0_s = self.t_s
        self.world.command_hold(self.index, self.p_ned.copy())  # on the ground: spooling up

    def takeoff_step(self) -> None:
        """Spool-up, then the climb profile (module constants)."""
        dt = self.t_s - self.takeoff_t0_s - TAKEOFF_SPOOL_S
        if dt < 0.0:
            return
        remaining = max(0.0, float(self.p_ned[2]) - self.takeoff_target_z)
        v_up = min(
            float(self.params.get("PILOT_SPEED_UP")) / 100.0,
            TAKEOFF_ACCEL_M_S2 * dt,
            math.sqrt(2.0 * TAKEOFF_DECEL_M_S2 * remaining),
        )
        self.world.command_velocity(self.index, (0.0, 0.0, -v_up), body=False)

    def landed_state(self) -> int:
        if self.phase == Phase.TAKEOFF and self.t_s - self.takeoff_t0_s < TAKEOFF_ON_GROUND_S:
            return mv.LANDED_ON_GROUND
        return super().landed_state()

    def start_landing(self) -> None:
        if not self.airborne or self.on_ground:
            return
        self.phase = Phase.LANDING
        self.velocity_active = False
        self.world.command_yaw_rate(self.index, 0.0)
        self.landing_step()

    def landing_step(self) -> None:
        """Descend at ``LAND_SPEED`` below ``LAND_ALT_LOW``, faster above it."""
        p = self.params
        high = self.altitude_m > float(p.get("LAND_ALT_LOW")) / 100.0
        speed_cm_s = float(p.get("LAND_SPEED_HIGH")) or float(p.get("WPNAV_SPEED_DN"))
        v_down = (speed_cm_s if high else float(p.get("LAND_SPEED"))) / 100.0
        self.world.command_velocity(self.index, (0.0, 0.0, v_down), body=False)

    # --- velocity control -----------------------------------------------------------------------
    def on_velocity_setpoint(self, sp: mv.VelocitySetpoint) -> None:
        if self.mode != "GUIDED" or not self.armed or self.phase != Phase.AIR:
            self.counters.ignored_setpoints += 1  # a real Copter finishes its takeoff first
            return
        self.last_setpoint_t_s = self.t_s
        if max(abs(v) for v in sp.v_m_s) > ABSURD_SPEED_MPS:
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

    # --- disarming ------------------------------------------------------------------------------
    def disarm_after_land_s(self) -> float:
        return (
            LAND_DISARM_S
            if self.mode in ("LAND", "RTL")
            else float(self.params.get("DISARM_DELAY"))
        )

    def autodisarm_unflown(self) -> bool:
        return True

    def autodisarm_unflown_s(self) -> float:
        return float(self.params.get("DISARM_DELAY"))
