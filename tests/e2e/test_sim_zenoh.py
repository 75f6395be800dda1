"""The simulator publishes camera bearings, truth and its clock over Zenoh (peer mode, loopback,
no multicast scouting), and in lockstep advances only when a SimStep is published."""

from __future__ import annotations

import json
import signal
import threading
import time

import pytest
import zenoh

from messages.codec import decode, encode
from messages.sim import CameraBearings, SimClock, SimStep, Truth, clock_key, step_key
from sim.launch import start_sim
from sim.server import free_port_base

pytestmark = pytest.mark.e2e


def session(connect: str):
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([connect]))
    conf.insert_json5("listen/endpoints", "[]")
    return zenoh.open(conf)


def test_zenoh_bearings_truth_clock_and_lockstep():
    base = free_port_base(3)
    endpoint = f"tcp/127.0.0.1:{base + 45}"
    proc = start_sim(
        "--vehicles", "3", "--port-base", str(base), "--gcs-port", "0", "--spacing", "4",
        "--zenoh", endpoint, "--lockstep", "--fleet", "zt", "--camera-fov", "360",
    )  # fmt: skip
    received: dict[str, list[bytes]] = {}
    lock = threading.Lock()

    def on_sample(sample) -> None:
        with lock:
            received.setdefault(str(sample.key_expr), []).append(sample.payload.to_bytes())

    s = session(endpoint)
    try:
        sub = s.declare_subscriber("bf/zt/**", on_sample)
        pub = s.declare_publisher(step_key("zt"))
        time.sleep(1.0)  # let the peers connect
        with lock:
            assert clock_key("zt") not in received  # lockstep: nothing moves without a step
        target = 0.0
        deadline = time.monotonic() + 15.0
        while time.monotonic() < deadline:
            target += 0.1
            pub.put(encode(SimStep(sender=99, until_s=target)))
            time.sleep(0.05)
            with lock:
                clocks = [decode(b, SimClock) for b in received.get(clock_key("zt"), [])]
            if (
                clocks
                and clocks[-1].t_s >= 0.5
                and len(received.get("bf/zt/0/camera/bearings", [])) > 3
            ):
                break
        assert clocks and clocks[-1].lockstep
        assert max(c.t_s for c in clocks) <= target + 1e-6  # never ahead of the steps
        with lock:
            bearings = decode(received["bf/zt/0/camera/bearings"][-1], CameraBearings)
            truth = decode(received["bf/zt/1/truth"][-1], Truth)
        assert bearings.sender == 0 and sorted(bearings.targets) == [1, 2]
        assert truth.p_ned == pytest.approx((0.0, 4.0, 0.0))
        sub.undeclare()
    finally:
        s.close()
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=10)
    assert proc.returncode == 0, out
