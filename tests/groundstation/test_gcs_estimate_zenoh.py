"""The live shell of ``bearingflock gcs estimate`` (:mod:`groundstation.gcs.ekf_live`) on real
Zenoh sessions (peer mode, loopback): synthetic odometry, frames and daemon statuses published
on the daemons' keys reach the loop; bad samples are counted; the table says what it sees."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import numpy as np
from rich.console import Console

from groundstation.gcs.ekf_live import LiveEstimator, render
from groundstation.gcs.ekf_loop import EkfLoop
from messages.agent import AgentStatus, VehicleStatus
from messages.codec import encode
from messages.envelope import pack
from messages.keys import STATUS_TOPIC, key, peer_key
from messages.peer import BearingShare, MotionShare
from messages.transport import ZenohSettings, loopback_endpoint, open_session
from sim.server import free_port_base
from tests.groundstation.test_gcs_estimate_loop import _feed


class _Publisher:
    """Stands where :func:`_feed` expects a loop: puts each sample on its daemon key instead."""

    def __init__(self, session, fleet: str) -> None:
        self.session, self.fleet = session, fleet

    def add_motion(self, m: MotionShare) -> None:
        self.session.put(peer_key(self.fleet, m.sender), pack(m.sender, m.seq, [m]).data)

    def add_frame(self, f: BearingShare) -> None:
        self.session.put(peer_key(self.fleet, f.sender), pack(f.sender, f.seq, [f]).data)

    def add_daemon_estimate(self, sender: int, stamp_s: float, p, yaw: float) -> None:
        agent = AgentStatus(
            sender=sender, stamp_s=stamp_s, mode="localize", p_hat_ned=tuple(float(x) for x in p),
            yaw_hat_rad=yaw, chi_hat_inv_m={}, e_index=0.0, lambda_bar=0.0, neighbours=[],
        )  # fmt: skip
        status = VehicleStatus(
            sender=sender, stamp_s=stamp_s, agent=agent, autopilot_mode="OFFBOARD", armed=True,
            in_air=True, altitude_m=2.0, speed_m_s=1.0, battery_pct=None, heartbeat_age_s=0.1,
            phase="flying",
        )  # fmt: skip
        self.session.put(key(self.fleet, sender, STATUS_TOPIC), encode(status))


def test_live_estimator_feeds_the_loop_from_zenoh_and_counts_bad_samples():
    endpoint = loopback_endpoint(free_port_base(1))
    sub_session = open_session(ZenohSettings(listen=[endpoint]))
    pub_session = open_session(ZenohSettings(connect=[endpoint]))
    messages: list[str] = []
    est = LiveEstimator(sub_session, "alpha", EkfLoop(), on_event=messages.append).start()
    try:
        # malformed probes until one arrives: the subscriptions have reached the publisher
        # (no fixed sleep: under load that took longer than any guess)
        deadline = time.monotonic() + 10.0
        while est.received == 0 and time.monotonic() < deadline:
            pub_session.put("bf/alpha/1/peer", b"\xc1 not msgpack")
            est.pump(0.1)
        pub_session.put(peer_key("beta", 1), b"other fleet: not subscribed")
        # paced as a team publishes (each key has its own subscription, so a burst can arrive
        # frames first: the loop admits a vehicle only on a frame after its odometry)
        publisher = _Publisher(pub_session, "alpha")
        for k in range(10):
            _feed(publisher, 0.1 * k, 0.1 * (k + 1))
            time.sleep(0.02)
        good = 20 * 3 + 5 * 3 * 2
        deadline = time.monotonic() + 10.0
        while (
            est.received < est.loop.counts["undecodable_malformed"] + good
            and time.monotonic() < deadline
        ):
            est.pump(0.1)
        time.sleep(0.3)  # anything else (the other fleet's sample) would arrive by now
        est.pump(0.1)
    finally:
        est.close()
        pub_session.close()
        sub_session.close()
    loop = est.loop
    probes = loop.counts["undecodable_malformed"]
    assert probes >= 1  # every malformed probe that arrived was counted, none crashed the loop
    assert est.received == probes + good  # the other fleet's sample never arrives
    # each key has its own subscription: which vehicle is heard first (the reference) is the
    # network's choice, that all three join is not
    assert sorted(loop.ids) == [1, 2, 3] and loop.updates > 0
    assert sorted(m.split(" ", 1)[1] for m in messages) == [
        f"vehicle {i} joined the filter" for i in (1, 2, 3)
    ]
    s = loop.summary()
    member = str(loop.ids[1])  # a vehicle other than the reference (the first heard)
    assert set(s["poses"][member]) >= {"p_ref_m", "daemon_p_ref_m", "disagreement_m"}
    assert np.isfinite(s["scale_m"])
    console = Console(record=True, width=160)
    console.print(render(s, "alpha"))
    text = console.export_text()
    assert "EKF and daemons agree" in text and "reference" in text and "updates" in text


def test_the_table_names_a_disagreeing_vehicle():
    loop = EkfLoop()
    _feed(loop, 0.0, 0.4)
    s = loop.summary()
    s["alarms"] = [3]
    s["poses"]["3"]["alarm"] = True
    console = Console(record=True, width=160)
    console.print(render(s, "alpha"))
    text = console.export_text()
    assert "DISAGREE" in text and "more than 1.50 m on vehicle 3" in text


def test_ctrl_c_stops_the_live_estimator_cleanly_with_its_summary():
    endpoint = loopback_endpoint(free_port_base(1))
    hub = open_session(ZenohSettings(listen=[endpoint]))
    cmd = ["gcs", "estimate", "--zenoh", endpoint, "--json"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "groundstation.cli", *cmd],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    try:
        assert b"listening on Zenoh" in proc.stderr.readline()
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=10.0)
    finally:
        if proc.poll() is None:
            proc.kill()
        hub.close()
    assert proc.returncode == 1 and b"Traceback" not in err  # 1: the filter never updated
    s = json.loads(out.decode().strip().splitlines()[-1])
    assert s["updates"] == 0 and s["vehicles"] == [] and s["samples"] == 0


def test_monitor_with_ekf_shows_the_filters_columns_from_zenoh():
    """``gcs monitor --ekf --once --json`` on a real Zenoh session: the team's samples (paced as
    the loop test feeds them, repeated until the monitor prints) give every vehicle row the EKF
    columns and the snapshot the EKF's scale."""
    endpoint = loopback_endpoint(free_port_base(1))
    hub = open_session(ZenohSettings(listen=[endpoint]))
    cmd = ["gcs", "monitor", "--ekf", "--once", "--json", "--wait", "4", "--mavlink", "none"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "groundstation.cli", *cmd, "--zenoh", endpoint],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    try:
        publisher, k = _Publisher(hub, "alpha"), 0
        deadline = time.monotonic() + 14.0
        while proc.poll() is None and time.monotonic() < deadline:
            _feed(publisher, 0.1 * k, 0.1 * (k + 1))
            k += 1
            time.sleep(0.1)
        out, err = proc.communicate(timeout=5.0)
    finally:
        if proc.poll() is None:
            proc.kill()
        hub.close()
    assert proc.returncode == 0, err.decode()[-500:]
    snap = json.loads(out)
    assert snap["ekf"]["updates"] > 0 and snap["ekf"]["scale_m"] > 0.0
    rows = {r["id"]: r for r in snap["vehicles"]}
    assert sorted(rows) == [1, 2, 3]
    member = next(i for i in rows if i != snap["ekf"]["reference"])
    assert rows[member]["ekf_sigma_p_m"] > 0.0 and rows[member]["ekf_disagreement_m"] is not None
