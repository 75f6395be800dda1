"""The autopilot link flies the simulator over real sockets (PX4 over UDP, ArduPilot over TCP).

The simulator runs in this process (``SimServer.start()``) at twice real time on free ports, so
the tests can compare what the link commanded with the simulated world itself; the link only
sees MAVLink. Simulation time (``world.t_s``) times the failsafes, so wall-clock jitter of this
machine does not matter.
"""

from __future__ import annotations

import math
import socket
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as px4_dialect

from messages import mavlink as mv
from messages.agent import Setpoint
from onboard.autopilot.base import LinkConfig, LinkError, StreamState
from onboard.autopilot.pymavlink_link import PymavlinkLink
from sim.server import SimConfig, SimServer, free_port_base
from sim.world import grid_layout

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(60)]

SPEEDUP = 2.0
U_MPS = 1.0
R_RADPS = 0.3


@pytest.fixture
def make_sim() -> Iterator[Callable[..., tuple[SimServer, int]]]:
    made: list[SimServer] = []

    def make(flavour: str, **kwargs: Any) -> tuple[SimServer, int]:
        base = free_port_base(1, span=60)
        p, yaw = grid_layout(1)
        cfg = SimConfig(
            p, yaw, flavour=flavour, client_base=base, gcs_port=base + 10, tcp_base=base,
            speedup=SPEEDUP, **kwargs,
        )  # fmt: skip
        server = SimServer(cfg).start()
        made.append(server)
        return server, base

    yield make
    for s in made:
        s.stop()


def wait_until(pred: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > deadline:
            raise AssertionError(f"timeout waiting for {what}")
        time.sleep(0.01)


def wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def fly_arc(link: Any, server: SimServer, wall_s: float) -> dict[str, float]:
    """Stream body velocity U + yaw rate R; measure the simulated motion once it is steady."""

    def stream(seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            link.set_setpoint(Setpoint((U_MPS, 0.0, 0.0), R_RADPS))
            time.sleep(0.05)

    stream(0.5)  # let the velocity lag (0.3 s) settle
    w = server.world
    t0, p0, yaw0 = w.t_s, w.p_ned[0].copy(), float(w.yaw_rad[0])
    stream(wall_s)
    t1, p1, yaw1 = w.t_s, w.p_ned[0].copy(), float(w.yaw_rad[0])
    tel = link.telemetry()
    dt = t1 - t0
    return {
        "dt": dt,
        "dpsi": wrap(yaw1 - yaw0),
        "dist": math.hypot(p1[0] - p0[0], p1[1] - p0[1]),
        "chord": 2.0 * (U_MPS / R_RADPS) * math.sin(R_RADPS * dt / 2.0),
        "u_body": tel.v_body[0],
        "v_body": tel.v_body[1],
        "yaw_rate": tel.yaw_rate_rad_s,
    }


def check_arc(m: dict[str, float]) -> None:
    assert m["dt"] == pytest.approx(SPEEDUP * 2.0, rel=0.25)  # the simulator kept its speed-up
    assert m["dpsi"] == pytest.approx(R_RADPS * m["dt"], rel=0.10)
    assert m["dist"] == pytest.approx(m["chord"], rel=0.10)
    # the link's own telemetry: body-frame velocity and yaw rate from LOCAL_POSITION_NED/ATTITUDE
    assert m["u_body"] == pytest.approx(U_MPS, rel=0.10)
    assert abs(m["v_body"]) < 0.15
    assert m["yaw_rate"] == pytest.approx(R_RADPS, rel=0.10)


def test_px4_offboard_flight_failsafe_pilot_takeover_and_bad_input(make_sim):
    server, base = make_sim("px4")
    link = PymavlinkLink()
    try:
        link.connect(f"udpin:127.0.0.1:{base}", timeout_s=5.0)
        assert link.flavour is not None and link.flavour.value == "px4"
        assert link.target_system == 1
        assert link.wait_ready(5.0).ok
        t = link.telemetry()
        assert t.connected and not t.stale and t.mode == "AUTO.LOITER" and not t.armed
        assert t.landed_state == mv.LANDED_ON_GROUND and t.battery_remaining_pct == 100

        assert link.arm().ok
        takeoff = link.takeoff(3.0)  # MIS_TAKEOFF_ALT is set to 3 m first
        assert takeoff.ok, takeoff
        assert -server.world.p_ned[0, 2] == pytest.approx(3.0, abs=0.25)
        assert link.telemetry().mode == "AUTO.LOITER"

        start = link.start_velocity_control()
        assert start.ok, start
        assert link.telemetry().mode == "OFFBOARD"
        assert link.telemetry().stream_state is StreamState.ACTIVE
        check_arc(fly_arc(link, server, 2.0))

        # stop streaming: PX4 fails safe COM_OF_LOSS_T (1 s of simulation time) later
        link.stop_streaming("test")
        t_stop = server.world.t_s
        wait_until(lambda: link.telemetry().mode != "OFFBOARD", 5.0, "offboard failsafe")
        assert server.world.t_s - t_stop == pytest.approx(1.0, abs=0.25)
        assert link.telemetry().mode == "AUTO.LOITER"
        events = link.events()
        assert any(e.kind == "statustext" and "offboard" in e.detail.lower() for e in events)
        assert any(e.kind == "stream_stopped" and e.detail == "test" for e in events)

        # the pilot takes the vehicle out of OFFBOARD from a ground station on the GCS port
        assert link.start_velocity_control().ok
        link.set_setpoint(Setpoint((0.5, 0.0, 0.0), 0.0))
        gcs = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{base + 10}", source_system=255, source_component=190
        )
        try:
            assert gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=5.0) is not None
            gcs.mav.set_mode_send(1, mv.BASE_MODE_CUSTOM, mv.px4_custom_mode(4, 3))
            wait_until(
                lambda: link.telemetry().stream_state is StreamState.IDLE, 5.0, "stream to stop"
            )
        finally:
            gcs.close()
        stops = [e for e in link.events() if e.kind == "stream_stopped"]
        assert len(stops) == 1 and "left OFFBOARD" in stops[0].detail
        sent = link.telemetry().counters.setpoints_sent
        time.sleep(0.3)
        assert link.telemetry().counters.setpoints_sent == sent  # nothing goes out any more
        assert link.telemetry().mode == "AUTO.LOITER"  # and the pilot's choice stands

        # garbage and a corrupted packet on the link's port: counted, dropped, link alive
        packet = px4_dialect.MAVLink_heartbeat_message(2, 12, 0, 0, 3, 3).pack(
            px4_dialect.MAVLink(None, srcSystem=1, srcComponent=1)
        )
        corrupted = bytearray(packet)
        corrupted[-2] ^= 0x55
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.sendto(b"\xfd\x09\x00\x00garbage garbage", ("127.0.0.1", base))
            s.sendto(bytes(corrupted), ("127.0.0.1", base))
        wait_until(lambda: link.telemetry().counters.bad_data >= 2, 2.0, "bad data counted")
        before = link.telemetry().counters.received
        time.sleep(0.3)
        t = link.telemetry()
        assert t.counters.received > before and not t.stale

        land = link.land(wait=True)
        assert land.ok, land
        assert link.disarm().ok  # accepted, or PX4 already disarmed itself after landing
        wait_until(lambda: not link.telemetry().armed, 5.0, "disarmed")
        c = link.telemetry().counters
        assert c.foreign == 0 and c.invalid_values == 0 and c.link_errors == 0
        assert server.counters()["ignored_setpoints"] == 0
    finally:
        link.close()


def test_ardupilot_strict_boot_guided_velocity_and_guid_timeout(make_sim):
    # init ("ArduPilot Ready") at 6 s, EKF position at 12 s of simulation time (twice real time):
    # the mode below must be set before init, and on a loaded machine connecting alone took 1 s
    server, base = make_sim("ardupilot", strict=True, warmup_s=6.0, ekf_warmup_s=12.0)
    link = PymavlinkLink(LinkConfig(mode_settle_s=0.5, ack_timeout_s=0.3))
    try:
        link.connect(f"tcp:127.0.0.1:{base}", timeout_s=5.0, request_streams=False)
        assert link.flavour is not None and link.flavour.value == "ardupilot"
        time.sleep(0.3)
        t = link.telemetry()
        assert not t.stale_heartbeat and math.isinf(t.attitude_age_s)  # nothing but heartbeats

        # a mode accepted during boot is reverted when boot ends, and re-applied
        assert link.set_mode("ALT_HOLD").ok
        # the position streams only once the EKF has one: the request says what is missing
        streams = link.request_streams()
        assert not streams.ok and "LOCAL_POSITION_NED not received" in streams.detail, streams
        assert not link.telemetry().stale_attitude
        assert not link.telemetry().ready  # the estimator is still warming up
        # arming is refused until the warm-up ends; the link retries with backoff
        arm = link.arm()
        assert arm.ok, arm
        assert arm.attempts >= 2
        assert "Arm: EKF attitude is bad" in arm.reasons
        ready = link.wait_ready(10.0)
        assert ready.ok and "re-applied ALT_HOLD" in ready.detail, ready
        assert link.telemetry().mode == "ALT_HOLD"
        assert any(e.kind == "mode_reverted" for e in link.events())

        # takeoff (switches to GUIDED); velocity control waits until the climb is over
        takeoff = link.takeoff(3.0, wait=False)
        assert takeoff.ok, takeoff
        start = link.start_velocity_control()
        assert start.ok, start
        assert -server.world.p_ned[0, 2] == pytest.approx(3.0, abs=0.3)
        assert link.telemetry().landed_state == mv.LANDED_IN_AIR
        assert link.telemetry().mode == "GUIDED"
        check_arc(fly_arc(link, server, 2.0))
        assert server.counters()["ignored_setpoints"] == 0  # nothing was sent while climbing

        # GUID_TIMEOUT: 3 s after the last setpoint the velocity goes to zero, still GUIDED
        link.stop_streaming("test")
        t_stop = server.world.t_s
        w = server.world
        wait_until(lambda: math.hypot(*w.v_ned[0, :2]) < 0.5, 10.0, "guided timeout")
        # 3 s timeout + ln(2) * tau_v (0.3 s) to lose half the speed, + one stream period
        assert w.t_s - t_stop == pytest.approx(3.0 + 0.21, abs=0.3)
        assert link.telemetry().mode == "GUIDED"
        hold = link.hold()  # ArduCopter BRAKE: stop and hold without pilot input
        assert hold.ok and link.telemetry().mode == "BRAKE", hold

        land = link.land(wait=True)
        assert land.ok, land
        wait_until(lambda: not link.telemetry().armed, 10.0, "disarm after landing")
        assert link.telemetry().counters.bad_data == 0
    finally:
        link.close()


def test_a_link_whose_first_connect_failed_connects_later():
    """Bug 1 of issue 22: a daemon started before its autopilot retries ``connect`` on the same
    link object; ``close()`` after the failed attempt left the stop flag set, so every later
    attempt ended at once (threads exited, nothing was heard) and the daemon never connected."""
    base = free_port_base(1, span=60)
    link = PymavlinkLink()
    url = f"udpin:127.0.0.1:{base}"
    server = None
    try:
        with pytest.raises(LinkError, match="no autopilot heartbeat"):
            link.connect(url, timeout_s=0.5)  # nothing there yet
        p, yaw = grid_layout(1)
        cfg = SimConfig(p, yaw, client_base=base, gcs_port=None, speedup=SPEEDUP)
        server = SimServer(cfg).start()
        link.connect(url, timeout_s=5.0)
        assert link.target_system == 1
        wait_until(lambda: not link.telemetry().stale, 5.0, "fresh telemetry")
        assert link.telemetry().counters.received > 0
        assert link.arm().ok  # commands go out and their ACKs come back
    finally:
        link.close()
        if server is not None:
            server.stop()


@pytest.mark.parametrize("backend", ["pymavlink", "mavsdk"])
def test_a_link_talks_only_to_its_own_system_id(make_sim, backend):
    """On a shared network a daemon must not adopt another vehicle's autopilot: with system 1
    on the link, a link for system 2 fails and names what it heard and what to set."""
    from onboard.autopilot.mavsdk_link import MavsdkLink

    cls = PymavlinkLink if backend == "pymavlink" else MavsdkLink
    _, base = make_sim("px4")  # one vehicle, system 1
    url = f"udpin:127.0.0.1:{base}"
    wrong = cls(LinkConfig(system_id=2))
    with pytest.raises(LinkError, match=r"system 2 .* only of system 1: set .*MAV_SYS_ID"):
        wrong.connect(url, timeout_s=1.5)
    right = cls(LinkConfig(system_id=1))
    try:
        right.connect(url, timeout_s=5.0)
        assert right.target_system == 1
    finally:
        right.close()


def test_mavsdk_backend_flies_px4(make_sim):
    from onboard.autopilot.mavsdk_link import MavsdkLink

    server, base = make_sim("px4")
    link = MavsdkLink()
    try:
        link.connect(f"udpin:127.0.0.1:{base}", timeout_s=5.0)
        assert link.flavour is not None and link.flavour.value == "px4"
        assert link.target_system == 1
        assert link.request_streams().ok
        assert link.wait_ready(5.0).ok
        t = link.telemetry()
        assert t.connected and not t.stale and t.mode == "AUTO.LOITER" and not t.armed
        assert t.landed_state == mv.LANDED_ON_GROUND

        assert link.arm().ok
        assert link.takeoff(2.5).ok
        assert -server.world.p_ned[0, 2] == pytest.approx(2.5, abs=0.25)

        start = link.start_velocity_control()
        assert start.ok, start
        assert link.telemetry().mode == "OFFBOARD"
        m = fly_arc(link, server, 1.0)
        assert m["dpsi"] == pytest.approx(R_RADPS * m["dt"], rel=0.10)
        assert m["dist"] == pytest.approx(m["chord"], rel=0.10)
        assert m["u_body"] == pytest.approx(U_MPS, rel=0.10)

        # stopping the stream does not command a mode: PX4's own failsafe ends OFFBOARD
        link.stop_streaming("test")
        t_stop = server.world.t_s
        wait_until(lambda: link.telemetry().mode != "OFFBOARD", 5.0, "offboard failsafe")
        assert server.world.t_s - t_stop == pytest.approx(1.0, abs=0.3)

        assert link.land(wait=True).ok
        wait_until(lambda: not link.telemetry().armed, 10.0, "disarm after landing")
    finally:
        link.close()


def test_mavsdk_backend_flies_ardupilot_in_guided(make_sim):
    from onboard.autopilot.mavsdk_link import MavsdkLink

    server, base = make_sim("ardupilot", transport="udp")
    link = MavsdkLink()
    try:
        link.connect(f"udpin:127.0.0.1:{base}", timeout_s=5.0)
        assert link.flavour is not None and link.flavour.value == "ardupilot"
        assert link.request_streams().ok
        assert link.wait_ready(5.0).ok
        assert link.arm().ok
        assert link.takeoff(2.5).ok
        assert -server.world.p_ned[0, 2] == pytest.approx(2.5, abs=0.25)

        start = link.start_velocity_control()
        assert start.ok, start
        assert link.telemetry().mode == "GUIDED"
        m = fly_arc(link, server, 1.0)
        assert m["dpsi"] == pytest.approx(R_RADPS * m["dt"], rel=0.10)
        assert m["dist"] == pytest.approx(m["chord"], rel=0.10)
        assert m["u_body"] == pytest.approx(U_MPS, rel=0.10)

        assert link.land(wait=True).ok
        wait_until(lambda: not link.telemetry().armed, 10.0, "disarm after landing")
    finally:
        link.close()


def test_mavsdk_backend_asks_an_ardupilot_for_its_streams(make_sim):
    """Issue 22, bug 5: ArduPilot streams nothing until asked and MAVSDK does not ask, so the
    MAVSDK backend never got attitude or position and ``wait_ready`` never passed."""
    from onboard.autopilot.mavsdk_link import MavsdkLink

    server, base = make_sim("ardupilot", transport="udp", strict=True, warmup_s=1.0)
    link = MavsdkLink(LinkConfig(system_id=7))
    try:
        with pytest.raises(LinkError, match="only of system 1"):  # bug 1: then retry afresh
            link.connect(f"udpin:127.0.0.1:{base}", timeout_s=1.0)
        link.config = LinkConfig(system_id=1)
        link.connect(f"udpin:127.0.0.1:{base}", timeout_s=5.0)
        assert link._thread is not None and link._thread.is_alive()
        ready = link.wait_ready(10.0)
        assert ready.ok, ready
        wait_until(lambda: not link.telemetry().stale, 5.0, "fresh attitude and velocity")
        assert link.telemetry().landed_state == mv.LANDED_ON_GROUND
        asked = server.autopilots[0].intervals_s
        assert {"ATTITUDE", "LOCAL_POSITION_NED", "SYS_STATUS", "EXTENDED_SYS_STATE"} <= set(asked)
        assert link.request_streams().ok
    finally:
        link.close()


def test_pymavlink_link_over_a_serial_device_at_921600_baud():
    """A companion computer's UART: the link opens a real tty (a pseudo-terminal here) at the
    baud rate in its URL and hears the autopilot's heartbeats through pyserial."""
    import os
    import threading

    from pymavlink.dialects.v20 import common

    controller_fd, device_fd = os.openpty()
    device = os.ttyname(device_fd)
    autopilot = common.MAVLink(None, srcSystem=1, srcComponent=1)
    stop = threading.Event()

    def heartbeats() -> None:
        while not stop.is_set():
            msg = autopilot.heartbeat_encode(
                mv.MAV_TYPE_QUADROTOR, mv.MAV_AUTOPILOT_PX4, 0, 0, mv.MAV_STATE_STANDBY
            )
            os.write(controller_fd, msg.pack(autopilot))
            stop.wait(0.1)

    writer = threading.Thread(target=heartbeats, daemon=True)
    writer.start()
    link = PymavlinkLink()
    try:
        link.connect(f"serial:{device}:921600", timeout_s=5.0)
        assert link.flavour is not None and link.flavour.value == "px4"
        assert link.target_system == 1
    finally:
        link.close()
        stop.set()
        writer.join(1.0)
        os.close(controller_fd)
        os.close(device_fd)
