"""pymavlink flies the ArduPilot flavour in GUIDED over TCP, and the failsafes fire on time.

Simulation time is read from ``time_boot_ms`` of the vehicle's own messages, so the timing
checks hold whatever the wall-clock jitter of this machine.
"""

from __future__ import annotations

import math
import time
from typing import Any

import pytest
from pymavlink import mavutil

from messages import mavlink as mv
from sim.launch import start_sim, stop_sim
from tests.e2e.sim_ports import start_sim_on_kernel_ports

pytestmark = pytest.mark.e2e

SPEEDUP = 2.0


class Link:
    """A pymavlink connection that remembers the latest message of each type."""

    def __init__(self, url: str) -> None:
        self.m = mavutil.mavlink_connection(url, source_system=255, source_component=190)
        self.latest: dict[str, Any] = {}
        self.texts: list[str] = []

    def pump(self, pred=lambda: False, timeout: float = 10.0, on_idle=None) -> None:
        deadline = time.monotonic() + timeout
        while not pred():
            if time.monotonic() > deadline:
                raise AssertionError("timeout waiting for the vehicle")
            msg = self.m.recv_match(blocking=True, timeout=0.05)
            if on_idle is not None:
                on_idle()
            if msg is None:
                continue
            self.latest[msg.get_type()] = msg
            if msg.get_type() == "STATUSTEXT":
                self.texts.append(msg.text)

    def t_sim(self) -> float:
        return self.latest["LOCAL_POSITION_NED"].time_boot_ms / 1000.0

    def command(self, cmd: int, *params: float) -> int:
        p = [*params, *([0.0] * (7 - len(params)))]
        self.latest.pop("COMMAND_ACK", None)
        self.m.mav.command_long_send(1, 1, cmd, 0, *p)
        self.pump(
            lambda: "COMMAND_ACK" in self.latest and self.latest["COMMAND_ACK"].command == cmd, 5.0
        )
        return int(self.latest["COMMAND_ACK"].result)

    def hb(self) -> Any:
        return self.latest["HEARTBEAT"]

    def armed(self) -> bool:
        return bool(self.hb().base_mode & mv.BASE_MODE_ARMED)

    def setpoint(self, v: tuple[float, float, float], yaw_rate: float, frame: int = 8) -> None:
        self.m.mav.set_position_target_local_ned_send(
            0, 1, 1, frame, mv.MASK_VELOCITY_YAW_RATE, 0, 0, 0, *v, 0, 0, 0, 0, yaw_rate
        )


def test_pymavlink_flies_ardupilot_guided():
    proc, port = start_sim_on_kernel_ports(
        "--vehicles", "1", "--flavour", "ardupilot", "--tcp-base", "0", "--speedup", str(SPEEDUP)
    )
    try:
        link = Link(f"tcp:127.0.0.1:{port}")
        link.pump(lambda: "HEARTBEAT" in link.latest)
        # like ArduCopter, nothing streams until asked; the position only after the EKF warm-up
        for msg_id in (30, 32, 33):  # ATTITUDE, LOCAL_POSITION_NED, GLOBAL_POSITION_INT
            assert link.command(mv.CMD_SET_MESSAGE_INTERVAL, msg_id, 50_000) == 0
        link.pump(lambda: {"LOCAL_POSITION_NED", "ATTITUDE"} <= link.latest.keys())
        assert link.hb().autopilot == mv.MAV_AUTOPILOT_ARDUPILOTMEGA
        assert link.command(mv.CMD_DO_SET_MODE, 1, mv.COPTER_MODES["GUIDED"]) == mv.RESULT_ACCEPTED
        assert link.command(mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_ACCEPTED
        link.pump(lambda: link.armed())
        assert link.command(mv.CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 3.0) == mv.RESULT_ACCEPTED
        link.pump(lambda: link.latest["GLOBAL_POSITION_INT"].relative_alt > 2900, 10.0)
        assert link.hb().custom_mode == mv.COPTER_MODES["GUIDED"]

        # body velocity + yaw rate for 3 s of wall time
        u, r = 1.0, 0.3
        t0 = link.t_sim()
        p0 = link.latest["LOCAL_POSITION_NED"]
        yaw0 = link.latest["ATTITUDE"].yaw
        wall_end = time.monotonic() + 3.0
        last_sent = [0.0]

        def stream() -> None:
            now = time.monotonic()
            if now - last_sent[0] >= 0.1:
                link.setpoint((u, 0.0, 0.0), r)
                last_sent[0] = now

        link.pump(lambda: time.monotonic() > wall_end, 10.0, on_idle=stream)
        t1 = link.t_sim()
        p1 = link.latest["LOCAL_POSITION_NED"]
        yaw1 = link.latest["ATTITUDE"].yaw
        dt = t1 - t0
        assert dt == pytest.approx(3.0 * SPEEDUP, rel=0.10)
        dpsi = (yaw1 - yaw0 + math.pi) % (2 * math.pi) - math.pi
        assert dpsi == pytest.approx(r * dt, rel=0.10)
        chord = 2.0 * (u / r) * math.sin(r * dt / 2.0)
        assert math.hypot(p1.x - p0.x, p1.y - p0.y) == pytest.approx(chord, rel=0.10)

        # GUIDED timeout: 3 s after the last setpoint the velocity goes to zero
        t_last = t1
        link.pump(
            lambda: (
                math.hypot(
                    link.latest["LOCAL_POSITION_NED"].vx, link.latest["LOCAL_POSITION_NED"].vy
                )
                < 0.5
            ),
            10.0,
        )
        # 3 s timeout + ln(2) * tau_v (0.3 s) to lose half the speed
        assert link.t_sim() - t_last == pytest.approx(3.0 + 0.21, abs=0.2)
        assert link.hb().custom_mode == mv.COPTER_MODES["GUIDED"]

        assert link.command(mv.CMD_NAV_LAND) == mv.RESULT_ACCEPTED
        link.pump(lambda: link.hb().custom_mode == mv.COPTER_MODES["LAND"])
        link.pump(lambda: not link.armed(), 15.0)
        link.m.close()
    finally:
        stop_sim(proc)


def test_px4_offboard_loss_failsafe_on_time():
    # the client's port first, the kernel's choice and bound; the vehicle's own port as well
    link = Link("udpin:127.0.0.1:0")
    base = link.m.port.getsockname()[1]
    proc = start_sim(
        "--vehicles", "1", "--port-base", str(base), "--bind-base", "0", "--gcs-port", "0",
        "--speedup", str(SPEEDUP),
    )  # fmt: skip
    try:
        link.pump(lambda: {"HEARTBEAT", "LOCAL_POSITION_NED"} <= link.latest.keys())
        assert link.hb().autopilot == mv.MAV_AUTOPILOT_PX4
        assert link.command(mv.CMD_COMPONENT_ARM_DISARM, 1) == mv.RESULT_ACCEPTED
        nan = math.nan
        assert (
            link.command(mv.CMD_NAV_TAKEOFF, nan, nan, nan, nan, nan, nan, nan)
            == mv.RESULT_ACCEPTED
        )
        loiter = mv.px4_custom_mode(4, 3)
        link.pump(
            lambda: link.hb().custom_mode == loiter and link.latest["LOCAL_POSITION_NED"].z < -2.3,
            10.0,
        )
        offboard = mv.px4_custom_mode(6)
        assert link.command(mv.CMD_DO_SET_MODE, 1, 6, 0) == mv.RESULT_TEMPORARILY_REJECTED
        last_sent = [0.0]

        def stream() -> None:
            now = time.monotonic()
            if now - last_sent[0] >= 0.1:
                link.setpoint((0.5, 0.0, 0.0), 0.0)
                last_sent[0] = now

        stream()  # a setpoint makes OFFBOARD available
        assert link.command(mv.CMD_DO_SET_MODE, 1, 6, 0) == mv.RESULT_ACCEPTED
        end = time.monotonic() + 1.0
        link.pump(lambda: time.monotonic() > end, 5.0, on_idle=stream)
        assert link.hb().custom_mode == offboard
        t_last = link.t_sim()  # setpoints stop now
        link.pump(lambda: link.hb().custom_mode == loiter, 5.0)
        link.latest.pop("LOCAL_POSITION_NED")
        link.pump(lambda: "LOCAL_POSITION_NED" in link.latest, 2.0)
        # COM_OF_LOSS_T = 1 s of simulation time (+ up to one 20 Hz stream period each side)
        assert link.t_sim() - t_last == pytest.approx(1.0, abs=0.12)
        assert any("offboard" in str(t).lower() for t in link.texts)
        link.m.close()
    finally:
        stop_sim(proc)
