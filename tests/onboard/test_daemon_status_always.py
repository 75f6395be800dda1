"""Issue 23 defect 9: the status always goes out, with the reason. A daemon whose autopilot link
was lost, or whose core holds NaN estimates, once published nothing (its loop skipped
everything when not connected; the codec refuses a NaN status), so the ground station saw a
frozen row or ``agent_lost``, never the cause.

Pure loop logic: the autopilot link, the peer link and the camera are small stand-ins; the
status goes through the real codec, as :meth:`onboard.daemon.peers.PeerLink.publish_status`
sends it."""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from types import SimpleNamespace

import msgspec
from pymavlink.dialects.v20 import common as dialect

from groundstation.demo import DemoPorts, plan_formation, write_demo_files
from messages import mavlink as mv
from messages.agent import Setpoint, VehicleStatus
from messages.codec import MessageError, decode, encode
from onboard.autopilot.base import Flavour, LinkConfig, LinkCounters, LinkError, StreamState
from onboard.autopilot.states import Saturated, TelemetryState, snapshot
from onboard.daemon.clock import WallClock
from onboard.daemon.config import load_fleet
from onboard.daemon.loop import AgentDaemon, publishable_agent_status
from onboard.daemon.peers import DropCounter


def _telemetry(system_id: int | None):
    st = TelemetryState(flavour=Flavour.PX4)
    t = time.monotonic()
    if system_id is not None:
        st.apply(dialect.MAVLink_heartbeat_message(2, 12, mv.BASE_MODE_CUSTOM, 0, 3, 3), t)
        st.apply(dialect.MAVLink_attitude_message(1000, 0.0, 0.0, 0.2, 0, 0, 0.0), t)
        st.apply(dialect.MAVLink_local_position_ned_message(1000, 0, 0, -5.0, 0, 0, 0), t)
    return snapshot(st, t, LinkConfig(), system_id, StreamState.IDLE,
                    Saturated((0.0, 0.0, 0.0), 0.0, False, False), LinkCounters())  # fmt: skip


class _Link:
    config = SimpleNamespace(clock=time.monotonic)

    def __init__(self, connected: bool, implausible: int = 0) -> None:
        self.connected = connected
        self.implausible = implausible
        self.setpoint_ages_s: list[float] = []
        self.frame_to_wire_s: list[float] = []

    def connect(self, url: str, timeout_s: float) -> None:
        time.sleep(0.05)
        raise LinkError("no autopilot in this test")

    def telemetry(self):
        tel = _telemetry(1 if self.connected else None)
        if self.implausible:  # the autopilot keeps sending impossible values (all dropped)
            return dataclasses.replace(tel, implausible_age_s=0.05, implausible=self.implausible)
        return tel

    def set_setpoint(self, setpoint: Setpoint, source_t=None) -> Setpoint:
        return setpoint

    def events(self) -> list:
        return []


class _Peers:
    """Publishes like :class:`onboard.daemon.peers.PeerLink`: through the codec, or dropped."""

    def __init__(self) -> None:
        self.statuses: list[VehicleStatus] = []
        self.refused = 0

    def drain(self, senders=None) -> list:
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
        try:
            data = encode(status)
        except MessageError:
            self.refused += 1
            return
        self.statuses.append(decode(data, VehicleStatus))


class _NoCamera:
    def poll(self):
        return None

    def age_s(self, now_s: float) -> float:
        return float("inf")


def _run(tmp_path, link, prepare=lambda daemon: None, n: int = 3) -> tuple[_Peers, AgentDaemon]:
    path = write_demo_files(tmp_path, plan_formation(3, seed=1), DemoPorts(zenoh=1, mavlink=2,
                            gcs=3), "t", "formation-active")  # fmt: skip
    peers = _Peers()
    daemon = AgentDaemon(load_fleet(path), 0, link, peers, _NoCamera(), WallClock(),
                         DropCounter(), "x")  # fmt: skip
    prepare(daemon)
    loop = threading.Thread(target=daemon.run, daemon=True)
    loop.start()
    t0 = time.monotonic()
    while len(peers.statuses) < n and time.monotonic() - t0 < 10.0 and loop.is_alive():
        time.sleep(0.02)
    daemon.stop_event.set()
    loop.join(5.0)
    return peers, daemon


def test_a_daemon_without_its_autopilot_publishes_status_saying_so(tmp_path):
    def no_grace(daemon: AgentDaemon) -> None:
        daemon.first_connect_grace_s = 0.0

    peers, _ = _run(tmp_path, _Link(connected=False), no_grace)
    assert len(peers.statuses) >= 3, "no status while the autopilot link is down"
    last = peers.statuses[-1]
    assert "autopilot_lost" in last.alarms
    assert last.phase == "connecting" and last.stamp_s > 0.0


def test_a_booting_autopilot_is_connecting_not_lost(tmp_path):
    """Within the first-connection grace the status goes out without the alarm: the phase
    says the daemon is connecting (every demo vehicle raised it while its autopilot booted)."""
    peers, _ = _run(tmp_path, _Link(connected=False))
    assert len(peers.statuses) >= 3
    assert all("autopilot_lost" not in s.alarms for s in peers.statuses)
    assert peers.statuses[-1].phase == "connecting"


def test_a_daemon_with_nan_estimates_publishes_status_saying_so(tmp_path):
    def poison(daemon: AgentDaemon) -> None:
        real = daemon.core.status

        def nan_status():
            s = real()
            return msgspec.structs.replace(s, p_hat_ned=(math.nan, 0.0, 1.0), e_index=math.inf)

        daemon.core.status = nan_status  # what a poisoned estimator leaves behind

    peers, _ = _run(tmp_path, _Link(connected=True), poison)
    assert len(peers.statuses) >= 3 and peers.refused == 0, "a NaN status was not published"
    last = peers.statuses[-1]
    assert "estimate_nonfinite" in last.alarms
    assert last.agent.p_hat_ned == (0.0, 0.0, 1.0)  # the finite part is kept
    assert not last.agent.scale_converged


def test_implausible_autopilot_telemetry_reaches_the_status_as_alarm_and_count(tmp_path):
    """Issue 23 defect 8 in the loop: the dropped telemetry holds the vehicle with an alarm."""
    peers, _ = _run(tmp_path, _Link(connected=True, implausible=4))
    last = peers.statuses[-1]
    assert "telemetry_implausible" in last.alarms
    assert last.dropped["mavlink_implausible"] == 4


def test_publishable_status_keeps_a_healthy_status_as_it_is(tmp_path):
    from onboard.core.agent import AgentCore
    from onboard.daemon.loop import agent_config

    path = write_demo_files(tmp_path, plan_formation(3, seed=1), DemoPorts(zenoh=1, mavlink=2,
                            gcs=3), "t", "formation-active")  # fmt: skip
    status = AgentCore(agent_config(load_fleet(path), 0)).status()
    same, healthy = publishable_agent_status(status)
    assert healthy and same is status
    bad = msgspec.structs.replace(status, chi_hat_inv_m={1: 0.2, 2: math.nan}, lambda_bar=1e300)
    fixed, healthy = publishable_agent_status(bad)
    assert not healthy and fixed.chi_hat_inv_m == {1: 0.2} and fixed.lambda_bar == 0.0
    encode(VehicleStatus(sender=0, seq=1, stamp_s=1.0, agent=fixed, autopilot_mode="x",
                         armed=False, in_air=False, altitude_m=0.0, speed_m_s=0.0,
                         battery_pct=None, heartbeat_age_s=0.0, phase="ready"))  # fmt: skip
