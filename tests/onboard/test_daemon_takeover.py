"""Issue 23 defect 6: a failsafe is told from a pilot, and the operator's ``start`` rejoins
after a failsafe. Once any exit from OFFBOARD/GUIDED (a forged HEARTBEAT showing LOITER, a 5 s
stall after which PX4 failed over, a restarted simulator) put the daemon in ``pilot`` with the
alarm ``failsafe``: a failsafe could not be told from a real pilot.

Pure loop logic with stand-ins (the autopilot link, the peer link, the camera); the
classification itself is :func:`onboard.daemon.guards.takeover_kind`."""

from __future__ import annotations

import math
import threading
import time
from types import SimpleNamespace

import pytest
from pymavlink.dialects.v20 import common as dialect

from groundstation.demo import DemoPorts, plan_formation, write_demo_files
from messages import mavlink as mv
from messages.agent import Setpoint, VehicleStatus
from messages.command import FleetCommand
from onboard.autopilot.base import (
    ActionResult,
    Flavour,
    LinkConfig,
    LinkCounters,
    LinkEvent,
    StreamState,
)
from onboard.autopilot.states import Saturated, TelemetryState, snapshot
from onboard.daemon.clock import WallClock
from onboard.daemon.config import load_fleet
from onboard.daemon.guards import takeover_kind
from onboard.daemon.loop import AgentDaemon
from onboard.daemon.peers import DropCounter


@pytest.mark.parametrize(
    ("flavour", "mode", "since_stall_s", "since_lost_s", "kind"),
    [
        (Flavour.PX4, "AUTO.LOITER", math.inf, math.inf, "failsafe"),  # PX4's offboard loss
        (Flavour.PX4, "AUTO.LAND", math.inf, math.inf, "failsafe"),
        (Flavour.PX4, "POSCTL", math.inf, math.inf, "pilot"),
        (Flavour.PX4, "POSCTL", 2.0, math.inf, "failsafe"),  # after a stall: PX4's RC failover
        (Flavour.PX4, "POSCTL", math.inf, 1.0, "failsafe"),  # after a lost link
        (Flavour.ARDUPILOT, "LOITER", math.inf, math.inf, "pilot"),
        (Flavour.ARDUPILOT, "BRAKE", math.inf, math.inf, "failsafe"),
        (Flavour.ARDUPILOT, "UNKNOWN(99)", math.inf, math.inf, "failsafe"),
    ],
)
def test_takeover_kind(flavour, mode, since_stall_s, since_lost_s, kind):
    assert takeover_kind(flavour, mode, since_stall_s, since_lost_s) == kind


class _Link:
    """A PX4 in the air that enters OFFBOARD when asked and leaves it when the test says."""

    config = SimpleNamespace(clock=time.monotonic)

    def __init__(self) -> None:
        self.mode = "AUTO.LOITER"
        self.starts = 0
        self.setpoint_ages_s: list[float] = []
        self.frame_to_wire_s: list[float] = []
        self._events: list[LinkEvent] = []
        self._lock = threading.Lock()

    def connect(self, url: str, timeout_s: float) -> None:
        pass

    def request_streams(self) -> ActionResult:
        return ActionResult("request_streams", True, 0, 1, 0.0)

    def wait_ready(self, timeout_s: float) -> ActionResult:
        return ActionResult("wait_ready", True, 0, 1, 0.0)

    def start_velocity_control(self) -> ActionResult:
        with self._lock:
            self.starts += 1
            self.mode = "OFFBOARD"
        return ActionResult("start_velocity_control", True, 0, 1, 0.0)

    def leave(self, mode: str) -> None:
        """The autopilot shows ``mode``: the link stops streaming and says so."""
        with self._lock:
            self.mode = mode
            self._events.append(LinkEvent(time.monotonic(), "stream_stopped",
                                          f"vehicle left OFFBOARD: now {mode}"))  # fmt: skip

    def telemetry(self):
        st = TelemetryState(flavour=Flavour.PX4)
        t = time.monotonic()
        main, sub = mv.PX4_MODES[self.mode]
        custom = mv.px4_custom_mode(main, sub)
        st.apply(dialect.MAVLink_heartbeat_message(2, 12, mv.BASE_MODE_CUSTOM | mv.BASE_MODE_ARMED,
                                                   custom, 4, 3), t)  # fmt: skip
        st.apply(dialect.MAVLink_attitude_message(1000, 0.0, 0.0, 0.2, 0, 0, 0.0), t)
        st.apply(dialect.MAVLink_local_position_ned_message(1000, 0, 0, -5.0, 0, 0, 0), t)
        st.apply(dialect.MAVLink_extended_sys_state_message(0, mv.LANDED_IN_AIR), t)
        return snapshot(st, t, LinkConfig(), 1, StreamState.IDLE,
                        Saturated((0.0, 0.0, 0.0), 0.0, False, False), LinkCounters())  # fmt: skip

    def set_setpoint(self, setpoint: Setpoint, source_t=None) -> Setpoint:
        return setpoint

    def events(self) -> list:
        with self._lock:
            out, self._events = self._events, []
        return out

    def stop_streaming(self, reason: str = "") -> None:
        pass


class _Peers:
    def __init__(self) -> None:
        self.statuses: list[VehicleStatus] = []
        self.acks: list[tuple[str, bool, str]] = []
        self.queued: list[FleetCommand] = []

    def drain(self, senders=None) -> list:
        return []

    def commands(self) -> list:
        out, self.queued = self.queued, []
        return out

    def formation(self) -> None:
        return None

    def leader_drive(self) -> None:
        return None

    def alive_peers(self) -> set:
        return set()

    def publish(self, payloads) -> int:
        return 0

    def publish_status(self, status) -> None:
        self.statuses.append(status)

    def ack(self, cmd, ok: bool, detail: str, stamp_s: float) -> None:
        self.acks.append((cmd.action, ok, detail))


class _NoCamera:
    def poll(self):
        return None

    def age_s(self, now_s: float) -> float:
        return 0.0


def _until(predicate, timeout_s: float = 5.0) -> bool:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        if predicate():
            return True
        time.sleep(0.02)
    return False


@pytest.fixture
def flying(tmp_path):
    path = write_demo_files(tmp_path, plan_formation(3, seed=1), DemoPorts(zenoh=1, mavlink=2,
                            gcs=3), "t", "formation-active")  # fmt: skip
    link, peers = _Link(), _Peers()
    daemon = AgentDaemon(load_fleet(path), 0, link, peers, _NoCamera(), WallClock(),
                         DropCounter(), "x")  # fmt: skip
    loop = threading.Thread(target=daemon.run, daemon=True)
    loop.start()
    assert _until(lambda: daemon.state.get() == "flying"), daemon.state.get()
    yield daemon, link, peers
    daemon.stop_event.set()
    loop.join(5.0)


def _alarms(daemon: AgentDaemon, peers: _Peers, phase: str) -> list[str]:
    assert _until(lambda: daemon.state.get() == phase), daemon.state.get()
    n = len(peers.statuses)
    assert _until(lambda: len(peers.statuses) > n + 1)
    return peers.statuses[-1].alarms


def _start(peers: _Peers) -> tuple[str, bool, str]:
    n = len(peers.acks)
    peers.queued.append(FleetCommand(sender=0, seq=1, stamp_s=0.0, target=0, action="start",
                                     request_id=7))  # fmt: skip
    assert _until(lambda: len(peers.acks) > n)
    return peers.acks[-1]


def test_a_failsafe_is_no_pilot_and_start_rejoins(flying):
    daemon, link, peers = flying
    link.leave("AUTO.LOITER")  # PX4's offboard-loss failsafe, or a forged HEARTBEAT
    alarms = _alarms(daemon, peers, "failsafe")
    assert "failsafe" in alarms and "pilot_takeover" not in alarms
    action, ok, detail = _start(peers)
    assert (action, ok) == ("start", True), detail
    assert daemon.state.get() == "flying" and link.starts == 2


def test_a_pilot_keeps_the_vehicle_until_they_hand_it_back(flying):
    daemon, link, peers = flying
    link.leave("POSCTL")  # the pilot's position-control switch
    alarms = _alarms(daemon, peers, "pilot")
    assert "pilot_takeover" in alarms and "failsafe" not in alarms
    action, ok, detail = _start(peers)
    assert (
        action == "start" and not ok and "POSCTL" in detail and link.starts == 1
    )  # refused: the pilot flies it
    link.mode = "AUTO.LOITER"  # the pilot hands back: a hold mode
    _, ok, detail = _start(peers)
    assert ok, detail
    assert daemon.state.get() == "flying" and link.starts == 2
