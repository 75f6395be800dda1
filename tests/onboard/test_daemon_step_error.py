"""An exception from one tick of the daemon's core loop (issue 23, defect 1: a
``ZeroDivisionError`` deep in an estimator killed the loop, the process stayed alive) is
counted, alarmed (``step_error``) and held; the loop and the status go on.

Pure loop logic: the autopilot link, the peer link and the camera are small stand-ins."""

from __future__ import annotations

import threading
import time
from types import SimpleNamespace

from pymavlink.dialects.v20 import common as dialect

from groundstation.demo import DemoPorts, plan_formation, write_demo_files
from messages import mavlink as mv
from messages.agent import Setpoint
from onboard.autopilot.base import Flavour, LinkConfig, LinkCounters, LinkError, StreamState
from onboard.autopilot.states import Saturated, TelemetryState, snapshot
from onboard.daemon.clock import Clock, WallClock
from onboard.daemon.config import load_fleet
from onboard.daemon.loop import AgentDaemon
from onboard.daemon.peers import DropCounter


def _telemetry():
    st = TelemetryState(flavour=Flavour.PX4)
    t = time.monotonic()
    st.apply(dialect.MAVLink_heartbeat_message(2, 12, mv.BASE_MODE_CUSTOM, 0, 3, 3), t)
    st.apply(dialect.MAVLink_attitude_message(1000, 0.0, 0.0, 0.2, 0, 0, 0.0), t)
    st.apply(dialect.MAVLink_local_position_ned_message(1000, 0, 0, -5.0, 0, 0, 0), t)
    return snapshot(st, t, LinkConfig(), 1, StreamState.IDLE,
                    Saturated((0.0, 0.0, 0.0), 0.0, False, False), LinkCounters())  # fmt: skip


class _Link:
    config = SimpleNamespace(clock=time.monotonic)

    def __init__(self) -> None:
        self.setpoints: list[tuple] = []
        self.setpoint_ages_s: list[float] = []
        self.frame_to_wire_s: list[float] = []

    def connect(self, url: str, timeout_s: float) -> None:
        time.sleep(0.05)
        raise LinkError("no autopilot in this test")

    def telemetry(self):
        return _telemetry()

    def set_setpoint(self, setpoint: Setpoint, source_t=None) -> Setpoint:
        self.setpoints.append((setpoint.v_body, setpoint.yaw_rate_rad_s))
        return setpoint

    def events(self) -> list:
        return []


class _Peers:
    def __init__(self) -> None:
        self.statuses: list = []
        self.failures = 1

    def drain(self, senders=None) -> list:
        if self.failures:
            self.failures -= 1
            raise ZeroDivisionError("float division by zero")  # what predict_bearing raised
        return []

    def commands(self) -> list:
        return []

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


class _NoCamera:
    def poll(self):
        return None

    def age_s(self, now_s: float) -> float:
        return float("inf")


def test_an_exception_in_one_tick_is_counted_alarmed_and_the_loop_goes_on(tmp_path):
    path = write_demo_files(tmp_path, plan_formation(3, seed=1), DemoPorts(zenoh=1, mavlink=2,
                            gcs=3), "t", "formation-active")  # fmt: skip
    link, peers, drops = _Link(), _Peers(), DropCounter()
    daemon = AgentDaemon(load_fleet(path), 0, link, peers, _NoCamera(), WallClock(), drops, "x")
    loop = threading.Thread(target=daemon.run, daemon=True)
    loop.start()
    t0 = time.monotonic()
    while len(peers.statuses) < 3 and time.monotonic() - t0 < 10.0 and loop.is_alive():
        time.sleep(0.05)
    alive = loop.is_alive()
    daemon.stop_event.set()
    loop.join(5.0)
    assert alive, "the core loop died on one exception"
    assert len(peers.statuses) >= 3
    first = peers.statuses[0]
    assert "step_error" in first.alarms and first.dropped["step_exception"] == 1
    assert ((0.0, 0.0, 0.0), 0.0) in link.setpoints  # held
    assert drops.snapshot()["step_exception"] == 1  # once: the next ticks ran normally


class _SettableClock(Clock):
    def __init__(self, t_s: float) -> None:
        self.t_s, self.t0 = t_s, time.monotonic()

    def now(self) -> float:
        return self.t_s + (time.monotonic() - self.t0)

    def set(self, t_s: float) -> None:
        self.t_s, self.t0 = t_s, time.monotonic()


def test_after_the_clock_went_back_no_alarm_is_stuck_in_the_future(tmp_path):
    """A restarted simulator: the step error at t = 500 s must not hold the vehicle until the
    new clock reaches 500 s again."""
    path = write_demo_files(tmp_path, plan_formation(3, seed=1), DemoPorts(zenoh=1, mavlink=2,
                            gcs=3), "t", "formation-active")  # fmt: skip
    link, peers, drops, clock = _Link(), _Peers(), DropCounter(), _SettableClock(500.0)
    daemon = AgentDaemon(load_fleet(path), 0, link, peers, _NoCamera(), clock, drops, "x")
    loop = threading.Thread(target=daemon.run, daemon=True)
    loop.start()
    t0 = time.monotonic()
    while not peers.statuses and time.monotonic() - t0 < 10.0:
        time.sleep(0.02)
    clock.set(1.0)  # restarted: time starts again
    n = len(peers.statuses)
    while len(peers.statuses) < n + 3 and time.monotonic() - t0 < 20.0:
        time.sleep(0.02)
    daemon.stop_event.set()
    loop.join(5.0)
    after = [s for s in peers.statuses[n:] if s.stamp_s < 100.0]
    assert after and all("step_error" not in s.alarms for s in after)
    assert after[-1].dropped.get("core_time_backwards", 0) >= 1
