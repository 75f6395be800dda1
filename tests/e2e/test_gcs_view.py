"""``gcs view`` serves the team live to Foxglove (issue 29): a real ``bearingflock gcs view``
process hears a team on real Zenoh, and a WebSocket client speaking the Foxglove WebSocket
protocol (subprotocol ``foxglove.sdk.v1``, the one foxglove-sdk's server accepts: serverInfo,
advertise, subscribe, binary message data)
receives the 3D scene, valid against the schemas the server advertised, and the alarms."""

from __future__ import annotations

import json
import math
import re
import struct
import subprocess
import sys
import threading
import time

import jsonschema
import msgspec
import numpy as np
import pytest
from websockets.sync.client import connect

from groundstation.gcs.foxglove_scene import EDGE_ONE_ALPHA, weight_color
from messages.codec import encode
from messages.sim import CameraBearings, Truth
from messages.transport import ZenohSettings, loopback_endpoint, open_session
from onboard.geometry import bearings_body
from sim.server import free_port_base
from tests.groundstation.standin import StandinConfig, scripted_status

pytestmark = pytest.mark.e2e
FLEET = "fv"
SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01  # binary opcode: u32 subscription id, u64 log time, payload
R_M = 7.5
"""Radius of the team's circle: neighbours 13 m apart, inside the default camera's 15 m range
but past the 12 m where its weight starts to fall (onboard/rigidity/weights.py)."""


def publish_team(session, stop: threading.Event) -> None:
    """Three vehicles on a circle, 10 samples a second: truth, status (vehicle 2 with an alarm) and the
    camera bearings of each to the next."""
    cfg = StandinConfig(FLEET, [0, 1, 2])
    k = 0
    while not stop.wait(0.1):
        t = 0.1 * k
        ang = 2 * np.pi * np.arange(3) / 3  # a still team: distances do not depend on timing
        p = np.stack([R_M * np.cos(ang), R_M * np.sin(ang), np.full(3, -2.5)], axis=1)
        yaw = ang + np.pi  # cameras toward the centre: each sees the others
        for i in range(3):
            truth = Truth(sender=i, p_ned=tuple(float(x) for x in p[i]), v_ned=(0.0, 0.0, 0.0),
                          yaw_rad=float(yaw[i]), yaw_rate_rad_s=0.0)  # fmt: skip
            session.put(f"bf/{FLEET}/{i}/truth", encode(truth))
            status = scripted_status(cfg, i, t, k, "flying")
            if i == 2:
                status = msgspec.structs.replace(status, alarms=["ticks_late"])
            session.put(f"bf/{FLEET}/{i}/status", encode(status))
            j = (i + 1) % 3
            beta, _d = bearings_body(p, yaw, [(i, j)])
            cam = CameraBearings(sender=i, targets=[j], beta_body=[tuple(map(float, beta[0]))])
            session.put(f"bf/{FLEET}/{i}/camera/bearings", encode(cam))
        k += 1


def test_gcs_view_serves_the_scene_to_a_foxglove_client(tmp_path):
    endpoint = loopback_endpoint(free_port_base(1))
    team = open_session(ZenohSettings(listen=[endpoint]))
    stop = threading.Event()
    publisher = threading.Thread(target=publish_team, args=(team, stop), daemon=True)
    publisher.start()
    proc = subprocess.Popen(
        [sys.executable, "-m", "groundstation.cli", "gcs", "view", "--fleet", FLEET,
         "--zenoh", endpoint, "--port", "0", "--duration", "30"],
        stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    t0 = time.monotonic()
    try:
        line = proc.stderr.readline()
        found = re.search(r"ws://127\.0\.0\.1:(\d+)", line)
        assert found, line + proc.stderr.read() if proc.poll() is not None else line
        with connect(
            f"ws://127.0.0.1:{found.group(1)}", subprotocols=[SUBPROTOCOL], close_timeout=0.5
        ) as ws:
            assert ws.subprotocol == SUBPROTOCOL
            info = json.loads(ws.recv(timeout=5))
            assert info["op"] == "serverInfo" and info["name"] == f"bearingflock {FLEET}"
            channels, statuses, scene, subscribed = {}, [], None, {}
            deadline = time.monotonic() + 10.0
            while scene is None and time.monotonic() < deadline:
                msg = ws.recv(timeout=5)
                if isinstance(msg, bytes):
                    assert msg[0] == MESSAGE_DATA
                    sub, _t_ns = struct.unpack_from("<IQ", msg, 1)
                    ch = subscribed[sub]
                    body = json.loads(msg[13:])
                    jsonschema.validate(body, json.loads(ch["schema"]))
                    if ch["topic"] == "scene/team":
                        ids = {e["id"] for e in body["entities"]}
                        if {"truth 0", "estimate 2", "frustum 1"} <= ids:
                            scene = body
                    continue
                op = json.loads(msg)
                if op["op"] == "advertise":
                    new = [c for c in op["channels"] if c["topic"].startswith(("scene/", "bf/"))]
                    for c in new:
                        channels[c["topic"]] = c
                        subscribed[c["id"]] = c
                    ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                        {"id": c["id"], "channelId": c["id"]} for c in new]}))  # fmt: skip
                elif op["op"] == "status":
                    statuses.append(op)
        assert scene is not None, sorted(channels)
        print(f"scene served {time.monotonic() - t0:.1f} s after the start of gcs view")
        assert channels["scene/team"]["schemaName"] == "foxglove.SceneUpdate"
        assert channels["scene/transforms"]["schemaName"] == "foxglove.FrameTransforms"
        assert channels[f"bf/{FLEET}/0/status"]["schemaName"] == "bearingflock.VehicleStatus"
        assert all(c["encoding"] == "json" for c in channels.values())
        ents = {e["id"]: e for e in scene["entities"]}
        label = ents["estimate 2"]["texts"][0]["text"]
        assert label == "estimate 2: ticks_late", label
        edges = ents["edges"]["lines"][0]
        assert len(edges["points"]) == 6  # 0 -> 1, 1 -> 2, 2 -> 0, one-way
        t = (2 * R_M * math.sin(math.pi / 3) - 12.0) / 3.0  # in the range weight's roll-off
        w = 1 - 3 * t**2 + 2 * t**3  # 30 deg off the camera axis: full fov weight
        assert 0.5 < w < 0.9
        for c in edges["colors"]:
            assert c == pytest.approx(weight_color(w, EDGE_ONE_ALPHA), abs=1e-6), (c, w)
        assert any("vehicle 2: ticks_late" in s["message"] for s in statuses), statuses
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        stop.set()
        publisher.join(5)
        team.close()
    assert proc.returncode in (0, -15), proc.stderr.read()
