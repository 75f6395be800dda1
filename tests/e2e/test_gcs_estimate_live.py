"""``bearingflock gcs estimate`` live (issue 26): the simulator and three daemons as processes,
real Zenoh on loopback, the estimator as a subprocess of the CLI. Its EKF runs on the daemons'
odometry and bearings only; the simulator's truth, heard here by the test alone, checks its
scale after the fact. One daemon is killed mid-run: the estimator drops that vehicle with a
message and carries on with the other two."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from messages.codec import MessageError, decode
from messages.keys import topic_keys
from messages.sim import TRUTH_TOPIC, Truth
from messages.transport import loopback_endpoint

pytestmark = pytest.mark.e2e
N = 3  # conftest.py
DURATION_S = 21.0
KILL_AFTER_S = 12.0
"""Daemon 2 is killed this long after the estimator started listening."""
SCALE_TOLERANCE = 0.05
"""Relative error allowed between the EKF's RMS inter-vehicle distance and the truth's."""


def _lines(stream, out: list[str]) -> None:
    for raw in iter(stream.readline, b""):
        out.append(raw.decode(errors="replace").rstrip())


def test_live_estimate_tracks_the_scale_and_drops_a_killed_vehicle(fleet):
    ev, procs, ports, _agent_args, name = fleet
    truth: list[Truth] = []
    lock = threading.Lock()

    def on_truth(sample) -> None:
        try:
            msg = decode(sample.payload.to_bytes(), Truth)
        except MessageError:
            return
        with lock:
            truth.append(msg)

    sub = ev.session.declare_subscriber(topic_keys(name, TRUTH_TOPIC), on_truth)
    zenoh = [a for k in range(N + 1) for a in ("--zenoh", loopback_endpoint(ports.zenoh + k))]
    proc = subprocess.Popen(
        [
            sys.executable, "-m", "groundstation.cli", "gcs", "estimate", "--fleet", name,
            *zenoh, "--duration", str(DURATION_S), "--json", "--silent-s", "2",
        ],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )  # fmt: skip
    err: list[str] = []
    stdout: list[str] = []
    readers = [
        threading.Thread(target=_lines, args=(stream, lines), daemon=True)
        for stream, lines in ((proc.stderr, err), (proc.stdout, stdout))
    ]
    for r in readers:
        r.start()

    def wait_for_lines(what: str, count: int, deadline: float) -> None:
        while sum(what in line for line in err) < count:
            assert time.monotonic() < deadline, f"no {count} x {what!r} in time: {err}"
            assert proc.poll() is None, err
            time.sleep(0.1)

    try:  # --duration runs from "listening": the CLI's start-up time varies with the load
        wait_for_lines("listening on Zenoh", 1, time.monotonic() + 30.0)
        t_ready = time.monotonic()
        wait_for_lines("joined the filter", N, t_ready + KILL_AFTER_S)
        time.sleep(max(0.0, t_ready + KILL_AFTER_S - time.monotonic()))  # the scale converges
        dict(procs.procs)["agent2"].kill()
        proc.wait(timeout=DURATION_S + 15.0)
    finally:
        if proc.poll() is None:
            proc.kill()
        sub.undeclare()
    for r in readers:
        r.join(timeout=2.0)
    assert proc.returncode == 0, err
    s = json.loads(stdout[-1])
    assert s["updates"] > 50
    # vehicle 2 went silent: dropped with a message, the other two carry on
    drops = [e for e in s["events"] if e["kind"] == "dropped"]
    assert [e["vehicle"] for e in drops] == [2], s["events"]
    assert "vehicle 2 dropped: silent for" in drops[0]["message"]
    assert any("vehicle 2 dropped" in line for line in err), err
    assert sorted(s["vehicles"]) == [0, 1]
    assert s["skipped"].get("bearing_to_unknown_vehicle", 0) > 0  # the camera still sees 2
    # a healthy team: the daemons' own estimates agree with the EKF, no alarm
    assert s["alarms"] == [] and "disagreement" not in s["event_counts"]
    (other,) = (i for i in s["vehicles"] if i != s["reference"])
    assert s["poses"][str(other)]["disagreement_m"] < s["max_disagreement_m"]
    # the scale, against the truth nearest the filter's last frame (never fed to the filter)
    assert math.isfinite(s["scale_m"]) and s["scale_m"] > 0
    with lock:
        latest: dict[int, Truth] = {}
        for tr in sorted(truth, key=lambda tr: abs(tr.stamp_s - s["t_s"]), reverse=True):
            latest[tr.sender] = tr
    assert all(abs(latest[i].stamp_s - s["t_s"]) < 0.5 for i in s["vehicles"])
    p = np.array([latest[i].p_ned for i in s["vehicles"]])
    d_true = float(np.linalg.norm(p[0] - p[1]))
    assert s["scale_m"] == pytest.approx(d_true, rel=SCALE_TOLERANCE), (s["scale_m"], d_true)
