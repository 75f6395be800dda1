"""The pymavlink link's logic without sockets: a scripted vehicle answers what the link sends.

Everything crosses a real MAVLink 2 pack/parse round trip (so messages carry source system and
component like on the wire); the vehicle calls :meth:`PymavlinkLink.feed` as the receive thread
would. Socket behaviour is covered by ``tests/e2e/test_autopilot_link.py``.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as dialect

from messages import mavlink as mv
from messages.agent import Setpoint
from onboard.autopilot.base import LinkConfig, StreamState, serial_device
from onboard.autopilot.mavsdk_link import map_result, mavsdk_url
from onboard.autopilot.pymavlink_link import PymavlinkLink

FAST = LinkConfig(
    ack_timeout_s=0.05, backoff_initial_s=0.01, backoff_max_s=0.02, mode_settle_s=0.05,
    retry_timeout_s=2.0,
)  # fmt: skip


def _parser() -> Any:
    p = dialect.MAVLink(None)
    p.robust_parsing = True
    return p


class FakeVehicle:
    """Stands in for the connection: parses what the link writes, answers like an autopilot."""

    def __init__(self, link: PymavlinkLink, sys_id: int = 1, autopilot: int = 12) -> None:
        self.link = link
        self.sys_id = sys_id
        self.autopilot = autopilot
        self.custom_mode = mv.px4_custom_mode(4, 3)
        self.armed = False
        self.arm_refusals = 0
        self.sent: list[Any] = []
        self.params: dict[str, float] = {}
        self._rx = _parser()
        self._out = _parser()
        self.mav = dialect.MAVLink(self, srcSystem=245, srcComponent=191)
        link._conn = self

    # the link writes here (pymavlink calls file.write)
    def write(self, buf: bytes) -> None:
        for m in self._rx.parse_buffer(buf) or []:
            self.sent.append(m)
            self.react(m)

    def close(self) -> None:
        pass

    def emit(self, msg: Any, sys_id: int | None = None, comp: int = 1) -> None:
        enc = dialect.MAVLink(
            None, srcSystem=self.sys_id if sys_id is None else sys_id, srcComponent=comp
        )
        for m in self._out.parse_buffer(msg.pack(enc)):
            self.link.feed(m)

    def heartbeat(self) -> None:
        base = mv.BASE_MODE_CUSTOM | (mv.BASE_MODE_ARMED if self.armed else 0)
        self.emit(
            dialect.MAVLink_heartbeat_message(2, self.autopilot, base, self.custom_mode, 3, 3)
        )

    def ack(self, command: int, result: int) -> None:
        self.emit(dialect.MAVLink_command_ack_message(command, result, 0, 0, 245, 191))

    def react(self, m: Any) -> None:
        kind = m.get_type()
        if kind == "COMMAND_LONG" and m.command == mv.CMD_COMPONENT_ARM_DISARM:
            if m.param1 == 1.0 and self.arm_refusals > 0:
                self.arm_refusals -= 1
                self.ack(m.command, mv.RESULT_DENIED)
                self.emit(dialect.MAVLink_statustext_message(2, b"Arming denied: ekf2 not ready"))
                return
            self.armed = m.param1 == 1.0
            self.ack(m.command, mv.RESULT_ACCEPTED)
            self.heartbeat()
        elif kind == "COMMAND_LONG" and m.command == mv.CMD_DO_SET_MODE:
            self.custom_mode = mv.px4_custom_mode(int(m.param2), int(m.param3))
            self.ack(m.command, mv.RESULT_ACCEPTED)
            self.heartbeat()
        elif kind == "COMMAND_LONG":
            self.ack(m.command, mv.RESULT_ACCEPTED)
        elif kind == "PARAM_SET":
            name = m.param_id.rstrip("\x00") if isinstance(m.param_id, str) else m.param_id.decode()
            self.params[name] = m.param_value
            self.emit(dialect.MAVLink_param_value_message(name.encode(), m.param_value, 9, 1, 0))

    def commands(self, command: int) -> list[Any]:
        return [m for m in self.sent if m.get_type() == "COMMAND_LONG" and m.command == command]


@pytest.fixture
def link():
    lk = PymavlinkLink(FAST)
    yield lk
    lk.close()


def test_adopts_the_first_autopilot_and_counts_the_rest(link):
    v = FakeVehicle(link)
    v.emit(dialect.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3), sys_id=255)  # a GCS
    v.emit(dialect.MAVLink_attitude_message(0, 0, 0, 0, 0, 0, 0))  # before any heartbeat
    assert link.target_system is None
    v.heartbeat()
    assert link.target_system == 1 and link.flavour is not None and link.flavour.value == "px4"
    v.emit(dialect.MAVLink_attitude_message(0, 0, 0, 1.0, 0, 0, 0), sys_id=2)  # another vehicle
    v.emit(dialect.MAVLink_attitude_message(0, 0, 0, 1.0, 0, 0, 0), comp=154)  # a gimbal
    v.emit(dialect.MAVLink_attitude_message(0, 0, 0, math.nan, 0, 0, 0))  # broken numbers
    v.emit(dialect.MAVLink_attitude_message(0, 0, 0, 0.25, 0, 0, 0))
    t = link.telemetry()
    assert t.counters.foreign == 2
    assert t.counters.invalid_values == 1
    assert t.counters.received == 2  # heartbeat + the good attitude
    assert t.yaw_rad == pytest.approx(0.25)
    assert t.mode == "AUTO.LOITER" and not t.armed
    assert [e.kind for e in link.events()] == ["connected"]


def test_configured_system_id_ignores_other_autopilots():
    lk = PymavlinkLink(LinkConfig(system_id=2))
    v = FakeVehicle(lk, sys_id=1)
    v.heartbeat()
    assert lk.target_system is None
    v.sys_id = 2
    v.heartbeat()
    assert lk.target_system == 2


def test_garbage_and_bad_crc_are_counted_and_dropped(link):
    v = FakeVehicle(link)
    v.heartbeat()
    good = dialect.MAVLink_attitude_message(0, 0, 0, 0.5, 0, 0, 0).pack(
        dialect.MAVLink(None, srcSystem=1, srcComponent=1)
    )
    bad_crc = bytearray(good)
    bad_crc[-1] ^= 0xFF
    parser = _parser()
    for m in parser.parse_buffer(b"\x00\x13garbage!" + bytes(bad_crc) + good) or []:
        link.feed(m)
    t = link.telemetry()
    assert t.counters.bad_data >= 2
    assert t.yaw_rad == pytest.approx(0.5)  # the good packet after the garbage still counts


def test_pilot_mode_change_or_disarm_stops_the_stream(link):
    v = FakeVehicle(link)
    v.custom_mode, v.armed = mv.px4_custom_mode(6), True
    v.heartbeat()
    link._stream = StreamState.ACTIVE  # as after start_velocity_control
    v.heartbeat()
    assert link.telemetry().stream_state is StreamState.ACTIVE
    v.custom_mode = mv.px4_custom_mode(3)  # the pilot flips to POSCTL
    v.heartbeat()
    assert link.telemetry().stream_state is StreamState.IDLE
    stops = [e for e in link.events() if e.kind == "stream_stopped"]
    assert len(stops) == 1 and "left OFFBOARD: now POSCTL" in stops[0].detail
    v.custom_mode = mv.px4_custom_mode(6)
    v.heartbeat()
    link._stream = StreamState.ACTIVE
    v.armed = False
    v.heartbeat()
    assert link.telemetry().stream_state is StreamState.IDLE
    assert any(e.detail == "vehicle disarmed" for e in link.events() if e.kind == "stream_stopped")


def test_sender_streams_saturated_body_velocity_and_zero_when_stale(link):
    v = FakeVehicle(link)
    v.heartbeat()
    now = link._clock()
    link._tick(now)
    assert not [m for m in v.sent if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]
    assert [m.type for m in v.sent if m.get_type() == "HEARTBEAT"] == [18]
    link._stream = StreamState.ACTIVE
    sat = link.set_setpoint(Setpoint((3.0, 4.0, 0.0), 5.0))
    assert isinstance(sat, Setpoint)
    assert sat.v_body == pytest.approx((1.2, 1.6, 0.0)) and sat.yaw_rate_rad_s == pytest.approx(0.8)
    link._tick(link._clock())
    sp = [m for m in v.sent if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"][-1]
    assert sp.coordinate_frame == mv.FRAME_BODY_NED and sp.type_mask == mv.MASK_VELOCITY_YAW_RATE
    assert (sp.vx, sp.vy, sp.vz, sp.yaw_rate) == pytest.approx((1.2, 1.6, 0.0, 0.8))
    assert (sp.target_system, sp.target_component) == (1, 1)
    link.set_setpoint(Setpoint((math.nan, 0.0, 0.0), 0.1))
    link._tick(link._clock())
    sp = [m for m in v.sent if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"][-1]
    assert (sp.vx, sp.vy, sp.vz, sp.yaw_rate) == (0.0, 0.0, 0.0, 0.0)
    link.set_setpoint(Setpoint((1.0, 0.0, 0.0), 0.0))
    link._tick(link._clock() + FAST.setpoint_timeout_s + 0.1)  # the agent went quiet
    sp = [m for m in v.sent if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"][-1]
    assert sp.vx == 0.0
    c = link.telemetry().counters
    assert (c.setpoints_sent, c.nan_setpoints, c.saturated_setpoints, c.stale_setpoints) == (
        3,
        1,
        1,
        1,
    )
    assert [e.kind for e in link.events()].count("setpoint_stale") == 1


def test_arm_retries_refusals_and_reports_the_reasons(link):
    v = FakeVehicle(link)
    v.heartbeat()
    v.arm_refusals = 2
    res = link.arm()
    assert res.ok and res.result == mv.RESULT_ACCEPTED
    assert res.attempts == 3
    assert res.reasons == ("Arming denied: ekf2 not ready",) * 2
    assert link.telemetry().armed


def test_arm_gives_up_after_the_retry_timeout(link):
    v = FakeVehicle(link)
    v.heartbeat()
    v.arm_refusals = 10**6
    res = link.arm(timeout_s=0.1)
    assert not res.ok and res.result == mv.RESULT_DENIED and res.result_name == "DENIED"
    assert "gave up retrying" in res.detail
    assert res.attempts >= 2


def test_unanswered_command_times_out_after_its_resends(link):
    v = FakeVehicle(link)
    v.heartbeat()
    v.react = lambda _m: None  # the vehicle stops answering
    res = link.land(timeout_s=0.0)
    assert res.timed_out and res.result_name == "TIMEOUT"
    assert len(v.commands(mv.CMD_NAV_LAND)) == FAST.command_sends
    assert [m.confirmation for m in v.commands(mv.CMD_NAV_LAND)] == [0, 1, 2]


def test_px4_takeoff_sets_the_altitude_parameter_first(link):
    v = FakeVehicle(link)
    v.heartbeat()
    assert not link.takeoff(4.0, wait=False).ok  # not armed
    assert link.arm().ok
    res = link.takeoff(4.0, wait=False)
    assert res.ok
    assert v.params == {"MIS_TAKEOFF_ALT": pytest.approx(4.0)}
    kinds = [m.get_type() for m in v.sent if m.get_type() in ("PARAM_SET", "COMMAND_LONG")]
    assert kinds[-2:] == ["PARAM_SET", "COMMAND_LONG"]
    assert math.isnan(v.commands(mv.CMD_NAV_TAKEOFF)[0].param7)
    assert not link.takeoff(math.nan).ok


def test_mode_accepted_during_boot_is_reapplied_after_the_revert(link):
    v = FakeVehicle(link, autopilot=3)
    v.custom_mode = mv.COPTER_MODES["STABILIZE"]
    present = mv.SENSOR_PREARM_CHECK

    def sys_status(ready: bool) -> None:
        health = present if ready else 0
        v.emit(
            dialect.MAVLink_sys_status_message(
                present, present, health, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0
            )
        )
        v.emit(dialect.MAVLink_local_position_ned_message(0, 0, 0, 0, 0, 0, 0))
        v.emit(dialect.MAVLink_extended_sys_state_message(0, mv.LANDED_ON_GROUND))

    def react(m: Any) -> None:  # ArduPilot: DO_SET_MODE param2 is the mode number
        if m.get_type() == "COMMAND_LONG" and m.command == mv.CMD_DO_SET_MODE:
            v.custom_mode = int(m.param2)
            v.ack(m.command, mv.RESULT_ACCEPTED)
            v.heartbeat()

    v.react = react
    v.heartbeat()
    sys_status(ready=False)
    assert link.set_mode("ALT_HOLD").ok
    v.custom_mode = mv.COPTER_MODES["STABILIZE"]  # boot ends: the autopilot reverts the mode
    v.heartbeat()
    sys_status(ready=True)
    assert "mode_reverted" in [e.kind for e in link.events()]
    res = link.wait_ready(timeout_s=1.0)
    assert res.ok and "re-applied ALT_HOLD" in res.detail
    assert link.telemetry().mode == "ALT_HOLD"
    assert link.set_mode("NOT_A_MODE").detail.startswith("unknown ArduCopter mode")


def test_mavsdk_helpers():
    assert mavsdk_url("udpin:127.0.0.1:14541") == "udpin://127.0.0.1:14541"
    assert mavsdk_url("tcp:127.0.0.1:5770") == "tcpout://127.0.0.1:5770"
    assert mavsdk_url("udpin://0.0.0.0:14540") == "udpin://0.0.0.0:14540"
    assert mavsdk_url("/dev/ttyACM0:57600") == "serial:///dev/ttyACM0:57600"
    assert mavsdk_url("serial:/dev/ttyAMA0:921600") == "serial:///dev/ttyAMA0:921600"
    assert mavsdk_url("/dev/ttyUSB0") == "serial:///dev/ttyUSB0:115200"
    with pytest.raises(ValueError):
        mavsdk_url("carrier-pigeon")
    assert map_result("SUCCESS") == (mv.RESULT_ACCEPTED, False)
    assert map_result("TIMEOUT") == (None, True)
    assert map_result("COMMAND_DENIED") == (mv.RESULT_DENIED, True)
    assert map_result("SOMETHING_NEW") == (mv.RESULT_FAILED, False)


def test_serial_urls():
    assert serial_device("udpin:127.0.0.1:14540") is None
    assert serial_device("tcp:127.0.0.1:5760") is None
    assert serial_device("/dev/ttyACM0") == ("/dev/ttyACM0", 115200)
    assert serial_device("/dev/ttyACM0:921600") == ("/dev/ttyACM0", 921600)
    assert serial_device("serial:/dev/ttyAMA0:57600") == ("/dev/ttyAMA0", 57600)
    assert serial_device("serial:///dev/ttyAMA0:57600") == ("/dev/ttyAMA0", 57600)
    assert serial_device("COM3:57600") == ("COM3", 57600)
    for bad in ("/dev/ttyACM0:fast", "serial:/dev/ttyACM0:-1", "/dev/ttyACM0:0"):
        with pytest.raises(ValueError, match="baud"):
            serial_device(bad)


def test_errors_of_a_broken_connection_are_counted_not_raised(link):
    """Issue 22, bug 4: a TCP autopilot that went away left pymavlink's socket ``None``; its
    AttributeError killed the sender thread and made ``close()`` raise."""
    v = FakeVehicle(link)
    v.heartbeat()

    class Broken:
        def __getattr__(self, name: str) -> Any:
            raise AttributeError("'NoneType' object has no attribute 'send'")

    v.mav = Broken()
    link._stream = StreamState.ACTIVE
    link._tick(link._clock())  # heartbeat and setpoint: both fail, neither raises
    assert link.telemetry().counters.link_errors == 2

    def close() -> None:
        raise AttributeError("'NoneType' object has no attribute 'close'")

    v.close = close  # type: ignore[method-assign]
    link.close()
    assert link.telemetry().counters.link_errors == 3


def test_a_setpoint_on_a_new_frame_goes_out_at_once_not_at_the_next_stream_slot():
    """Issue 27's latency: the sender waits for no stream period when the daemon sets a
    setpoint based on a new camera frame; the same frame's later setpoints wait for the
    stream. ``frame_to_wire_s`` holds one age per frame, ``setpoint_ages_s`` one per send."""
    lk = PymavlinkLink(replace(FAST, rate_hz=2.0))  # a 0.5 s stream period
    try:
        v = FakeVehicle(lk)
        v.heartbeat()
        lk._stream = StreamState.ACTIVE
        lk._start_thread(lk._send_loop, "test-sender")

        def setpoints() -> int:
            return sum(m.get_type() == "SET_POSITION_TARGET_LOCAL_NED" for m in list(v.sent))

        time.sleep(0.1)  # the stream's first slot has passed
        before = setpoints()
        frame_t = lk._clock()
        lk.set_setpoint(Setpoint((0.5, 0.0, 0.0), 0.0), source_t=frame_t)
        t0 = time.monotonic()
        while setpoints() == before and time.monotonic() - t0 < 1.0:
            time.sleep(0.002)
        assert time.monotonic() - t0 < 0.1, "the frame's setpoint waited for the stream slot"
        lk.set_setpoint(Setpoint((0.6, 0.0, 0.0), 0.0), source_t=frame_t)  # same frame
        time.sleep(0.2)
        assert setpoints() == before + 1  # no prompt send for a frame already on the wire
        assert len(lk.frame_to_wire_s) == 1 and 0.0 <= lk.frame_to_wire_s[0] < 0.1
        assert list(lk.setpoint_ages_s) == list(lk.frame_to_wire_s)
    finally:
        lk.close()
