"""Bad input about a process: a Zenoh or MAVLink port in use is one error line and an exit,
never a traceback or a daemon that retries forever (issue 23, defect 12; the in-process cases
are tests/test_bad_input.py). Real processes, ports held by the test (kernel-chosen)."""

from __future__ import annotations

import math
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from sim.server import free_port_base

pytestmark = pytest.mark.e2e

FORMATION = """
[[agent]]
id = 0
position_ned = [0.0, 0.0, -5.0]
[[agent]]
id = 1
position_ned = [4.0, 0.0, -5.0]
[[agent]]
id = 2
position_ned = [2.0, 3.0, -6.0]
"""


def fleet_file(tmp: Path, body: str, zenoh_base: int) -> Path:
    (tmp / "formation.toml").write_text(FORMATION)
    path = tmp / "fleet.toml"
    path.write_text(f'formation = "formation.toml"\n{body}\n[zenoh]\nport_base = {zenoh_base}\n')
    return path


@contextmanager
def held_port(kind: int) -> Iterator[int]:
    s = socket.socket(socket.AF_INET, kind)
    s.bind(("127.0.0.1", 0))
    if kind == socket.SOCK_STREAM:
        s.listen()
    try:
        yield s.getsockname()[1]
    finally:
        s.close()


def _one_line_error(output: str, message: str) -> None:
    assert "Traceback" not in output, output
    errors = [line for line in output.splitlines() if line.startswith("error")]
    assert len(errors) == 1 and message in errors[0], output


def _bearingflock(*args: str, timeout_s: float) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "groundstation.cli", *args],
        capture_output=True, text=True, timeout=timeout_s,
    )  # fmt: skip


def test_agent_zenoh_port_in_use_is_one_line(tmp_path: Path) -> None:
    with held_port(socket.SOCK_STREAM) as port:  # the agent 0 listens on port_base + 1
        fleet = fleet_file(tmp_path, "", zenoh_base=port - 1)
        res = _bearingflock("agent", "--id", "0", "--config", str(fleet), timeout_s=30)
    assert res.returncode == 2, res.stderr
    _one_line_error(res.stderr, "Address already in use")


def test_sim_zenoh_port_in_use_is_one_line() -> None:
    base = free_port_base(1)
    with held_port(socket.SOCK_STREAM) as port:
        res = _bearingflock(
            "sim", "--quiet", "--vehicles", "1", "--port-base", str(base), "--bind-base", "0",
            "--gcs-port", "0", "--zenoh", f"tcp/127.0.0.1:{port}", timeout_s=30,
        )  # fmt: skip
    assert res.returncode == 2, res.stdout + res.stderr
    _one_line_error(res.stderr, "Address already in use")


@pytest.mark.parametrize("backend", ["pymavlink", "mavsdk"])
def test_agent_with_its_mavlink_udpin_port_in_use_exits(tmp_path: Path, backend: str) -> None:
    """It retried the bind every second forever; now the flight thread's permanent error ends
    the daemon (exit 1, one line and no traceback), well within the test's timeout. With
    MAVSDK too: its "cannot open" carried no cause and was retried forever."""
    zenoh = free_port_base(4)
    with held_port(socket.SOCK_DGRAM) as port:
        fleet = fleet_file(tmp_path, f'[mavlink]\nurl = "udpin:127.0.0.1:{port}"', zenoh_base=zenoh)
        t0 = time.monotonic()
        res = _bearingflock(
            "agent", "--id", "0", "--config", str(fleet), "--backend", backend, timeout_s=40
        )
        took = time.monotonic() - t0
    assert res.returncode == 1, res.stderr
    assert "Traceback" not in res.stderr  # a permanent error is no crash: no traceback at all
    assert res.stderr.strip().splitlines()[-1].startswith("error: cannot open 'udpin:")
    assert "Address already in use" in res.stderr.strip().splitlines()[-1]
    assert math.isfinite(took)
