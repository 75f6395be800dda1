"""The ground station on real Zenoh sessions (peer mode, loopback): stand-in agents publish the
daemon's payloads; the monitor counts bad samples, fleet commands get their acks, a killed
agent turns red within 5 s, and record -> replay -> record gives the same samples."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from groundstation.gcs import commands
from groundstation.gcs.analysis import load_series, predicted_bearings_body
from groundstation.gcs.monitor import Monitor, MonitorConfig
from groundstation.gcs.plot import plot_all
from groundstation.gcs.record import LIVELINESS_ENCODING, Recorder, Source, iter_records
from groundstation.gcs.replay import replay
from groundstation.gcs.zenoh_listener import ZenohListener
from messages.codec import encode
from messages.command import FleetCommand
from messages.sim import CameraBearings, Truth
from messages.transport import ZenohSettings, loopback_endpoint, open_session
from sim.server import free_port_base
from tests.groundstation.standin import Standin, StandinConfig


@pytest.fixture
def hub():
    """A listening session others connect to, and a factory of connected sessions."""
    endpoint = loopback_endpoint(free_port_base(1))
    sessions = [open_session(ZenohSettings(listen=[endpoint]))]

    def connect():
        s = open_session(ZenohSettings(connect=[endpoint]))
        sessions.append(s)
        return s

    yield endpoint, connect
    for s in reversed(sessions):
        s.close()


def wait(pred, timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.05)
    return False


def put_matched(session, key: str, data: bytes) -> None:
    """Put once a subscriber matches (a fresh session routes nothing before that)."""
    pub = session.declare_publisher(key)
    assert wait(lambda: pub.matching_status.matching), f"no subscriber for {key}"
    pub.put(data)
    pub.undeclare()


def rows(mon: Monitor) -> dict[int, dict]:
    return {r["id"]: r for r in mon.snapshot()["vehicles"]}


def test_monitor_counts_bad_samples_and_commands_get_acks(hub):
    _, connect = hub
    gcs = connect()
    listener = ZenohListener(gcs, "zt").start()
    mon = Monitor(MonitorConfig(fleet="zt"), None, listener)
    agent_session = connect()
    standin = Standin(agent_session, StandinConfig("zt", [0, 1, 2], reject=[2])).start()
    try:
        assert wait(lambda: len(rows(mon)) == 3 and all(r["phase"] for r in rows(mon).values()))
        other = connect()
        put_matched(other, "bf/zt/1/status", b"\xc1 not msgpack")
        put_matched(other, "bf/zt/1/weather", b"sunny")
        put_matched(
            other,
            "bf/zt/7/status",
            encode(FleetCommand(sender=7, target=7, action="hold", request_id=1)),
        )
        assert wait(lambda: sum(mon.snapshot()["zenoh"]["dropped"].values()) == 3)
        snap = mon.snapshot()
        assert snap["zenoh"]["dropped"] == {"malformed": 2, "foreign": 1}
        r = rows(mon)
        assert sorted(r) == [0, 1, 2]  # a bad sample never creates a vehicle
        assert r[1]["neighbours"] == [0, 2] and r[1]["e_index"] > 0 and r[1]["alive"] is True
        assert not any("agent_lost" in x["alarms"] for x in r.values())

        out = commands.run_zenoh(gcs, listener, "zt", "start", [0, 1, 2, 5], timeout_s=1.5)
        assert [out[i].ok for i in (0, 1, 2, 5)] == [True, True, False, False]
        assert "rejected" in out[2].details[0] and "no ack" in out[5].details[0]
        got = [(c.target, c.action) for c in standin.commands]
        assert sorted(got) == [(0, "start"), (1, "start"), (2, "start")]
        assert len({c.request_id for c in standin.commands}) == 1
        assert wait(lambda: rows(mon)[0]["phase"] == "flying")
        # stop waits only for agents it knows; the others are told without waiting
        t0 = time.monotonic()
        out = commands.run_zenoh(gcs, listener, "zt", "stop", [0, 9], timeout_s=3.0, expect=[0])
        assert out[0].ok and not out[9].ok and "never heard" in out[9].details[0]
        assert time.monotonic() - t0 < 2.5
    finally:
        standin.stop()
        listener.close()


def test_killed_agent_turns_red_within_5s(hub):
    endpoint, connect = hub
    listener = ZenohListener(connect(), "zk").start()
    mon = Monitor(MonitorConfig(fleet="zk"), None, listener)
    proc = subprocess.Popen(
        [sys.executable, "-m", "tests.groundstation.standin", "--fleet", "zk", "--ids", "3",
         "--connect", endpoint],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
    )  # fmt: skip
    try:
        assert wait(lambda: 3 in rows(mon) and rows(mon)[3]["alive"], 20.0), "agent never showed"
        assert not rows(mon)[3]["red"] or rows(mon)[3]["alarms"] == ["heartbeat_lost"]
        assert "agent_lost" not in rows(mon)[3]["alarms"]
        proc.send_signal(signal.SIGKILL)
        t_kill = time.monotonic()
        assert wait(lambda: "agent_lost" in rows(mon)[3]["alarms"], 5.0)
        assert rows(mon)[3]["red"]
        assert time.monotonic() - t_kill < 5.0
    finally:
        proc.kill()
        proc.wait(5)
        listener.close()


def publish_truth_and_bearings(session, fleet: str, t: float) -> None:
    """Three vehicles on a circle; truth and camera bearings of vehicle 0 to 1 and 2."""
    ang = 0.3 * t + np.array([0.0, 2.1, 4.2])
    p = np.stack([10 * np.cos(ang), 10 * np.sin(ang), np.full(3, -2.5)], axis=1)
    yaw = ang + np.pi / 2
    for i in range(3):
        session.put(
            f"bf/{fleet}/{i}/truth",
            encode(
                Truth(
                    sender=i,
                    p_ned=tuple(float(x) for x in p[i]),
                    v_ned=(0.0, 0.0, 0.0),
                    yaw_rad=float(yaw[i]),
                    yaw_rate_rad_s=0.3,
                )
            ),
        )
    beta = predicted_bearings_body(p[[0, 0]], yaw[[0, 0]], p[[1, 2]])
    cam = CameraBearings(
        sender=0, targets=[1, 2], beta_body=[tuple(float(x) for x in b) for b in beta]
    )
    session.put(f"bf/{fleet}/0/camera/bearings", encode(cam))


def record_session(connect, fleet: str, path: Path) -> tuple[ZenohListener, Recorder]:
    listener = ZenohListener(connect(), fleet)
    rec = Recorder(path, fleet)
    listener.sample_hooks.append(rec.zenoh_sample)
    listener.alive_hooks.append(rec.alive)
    return listener.start(), rec


def by_topic(path: Path) -> dict[str, list[bytes]]:
    out: dict[str, list[bytes]] = {}
    for r in iter_records(path):
        if r.source == Source.SCENE:  # derived at record time: not what was received
            continue
        out.setdefault(f"{r.encoding}:{r.topic}", []).append(r.data)
    return out


def test_record_replay_record_gives_the_same_samples_and_plots(hub, tmp_path):
    _, connect = hub
    first, second = tmp_path / "a.mcap", tmp_path / "b.mcap"
    listener, rec = record_session(connect, "rr", first)
    pub = connect()
    standin = Standin(pub, StandinConfig("rr", [0, 1, 2], rate_hz=10.0, tau_s=0.5)).start()
    assert wait(lambda: rec.counts.get("liveliness", 0) == 3)
    for k in range(15):
        publish_truth_and_bearings(pub, "rr", 0.1 * k)
        time.sleep(0.1)
    pub.put("bf/rr/1/status", b"\x00broken")
    pub.put(
        "bf/rr/1/command", encode(FleetCommand(sender=0, target=1, action="hold", request_id=3))
    )
    time.sleep(0.3)
    standin.stop()
    assert wait(lambda: rec.counts.get("liveliness", 0) == 6)
    listener.close()
    rec.close()

    recorded = by_topic(first)
    assert len(recorded[f"{LIVELINESS_ENCODING}:bf/rr/2/alive"]) == 2
    assert b"\x00broken" in recorded["msgpack:bf/rr/1/status"]
    assert len(recorded["msgpack:bf/rr/0/truth"]) == 15

    listener2, rec2 = record_session(connect, "rr", second)
    stats = replay(iter_records(first), connect(), speed=4.0)
    assert stats.skipped.pop("scene") > 0  # Foxglove's scene channels: derived, not replayed
    assert stats.skipped == {"command": 1}
    assert wait(lambda: rec2.counts.get("liveliness", 0) == 6)
    time.sleep(0.3)
    listener2.close()
    rec2.close()
    again = by_topic(second)
    del recorded["msgpack:bf/rr/1/command"]  # never replayed: it would command live agents
    assert again == recorded

    series = load_series(first)
    assert series.fleet == "rr" and sorted(series.agents) == [0, 1, 2]
    assert sorted(series.truth) == [0, 1, 2] and len(series.bearings[0].t_s) == 30
    paths = plot_all(series, tmp_path)
    assert [p.name for p in paths] == [
        "scale_error.png", "sfm_convergence.png", "rigidity.png", "bearing_errors.png",
        "trajectories.png",
    ]  # fmt: skip
    assert all(p.stat().st_size > 10_000 for p in paths)
