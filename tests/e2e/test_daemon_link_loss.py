"""A daemon whose TCP autopilot goes away (issue 22, bug 4): the link's threads survive the
loss, and SIGTERM still stops the daemon promptly and releases its Zenoh port.

Before the fix, pymavlink's reconnect left its socket ``None`` and raised AttributeError: the
sender thread died, ``link.close()`` raised, the peers' close was skipped, and the daemon hung
with its Zenoh port held."""

from __future__ import annotations

import signal
import socket
import subprocess
import time
from pathlib import Path

import pytest

from groundstation.demo import DemoPorts, Processes, plan_formation, write_demo_files
from messages.transport import loopback_endpoint
from sim.launch import start_sim
from sim.server import free_port_base

pytestmark = pytest.mark.e2e

N = 3


def _tcp_fleet(tmp_path: Path, base: int, name: str) -> tuple[Path, DemoPorts]:
    ports = DemoPorts(zenoh=base, mavlink=base + 20, gcs=base + 9)
    path = write_demo_files(tmp_path, plan_formation(N, seed=0), ports, name, "formation-active")
    path.write_text(path.read_text().replace("auto_start = true", "auto_start = false"))
    return path, ports


def _port_free(port: int) -> bool:
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        s.bind(("127.0.0.1", port))
        return True
    except OSError:
        return False
    finally:
        s.close()


def test_daemon_survives_its_tcp_autopilot_going_away_and_stops_on_sigterm(tmp_path):
    base = free_port_base(N, span=60)
    name = f"t{base}"
    fleet_path, ports = _tcp_fleet(tmp_path, base, name)
    sim = start_sim(
        "--vehicles", str(N), "--flavour", "ardupilot", "--layout", str(tmp_path / "start.toml"),
        "--tcp-base", str(ports.mavlink), "--zenoh", loopback_endpoint(ports.zenoh),
        "--fleet", name, "--speedup", "2",
    )  # fmt: skip
    procs = Processes(tmp_path)
    try:
        agent = procs.start(
            "agent0",
            ["-m", "groundstation.cli", "agent", "--id", "0", "--config", str(fleet_path),
             "--mavlink", f"tcp:127.0.0.1:{ports.mavlink}"],
        )  # fmt: skip
        log = tmp_path / "agent0.log"
        deadline = time.monotonic() + 30.0
        while "-> ready" not in log.read_text():
            assert time.monotonic() < deadline, log.read_text()
            assert agent.poll() is None, log.read_text()
            time.sleep(0.2)
        sim.kill()  # the autopilot is gone: TCP resets, pymavlink starts reconnecting
        sim.wait(5)
        time.sleep(4.0)
        assert agent.poll() is None, log.read_text()
        t0 = time.monotonic()
        agent.send_signal(signal.SIGTERM)
        try:
            agent.wait(15.0)
        except subprocess.TimeoutExpired:
            pytest.fail("the daemon hung on SIGTERM:\n" + log.read_text())
        assert time.monotonic() - t0 < 15.0
        assert _port_free(ports.zenoh + 1), "the daemon's Zenoh port is still held"
        text = log.read_text()
        assert "Traceback" not in text, text
    finally:
        if sim.poll() is None:
            sim.kill()
            sim.wait()
        procs.stop()
