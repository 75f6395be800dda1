"""A TCP connection flood never stops the simulator's loop (issue 23, defect 5): at 1,025
connections (the usual 1024-descriptor limit) accept failed with EMFILE, the loop thread died and
the process ran on with its clock frozen. A real simulator process with a low descriptor limit
(10 descriptors left: accept fails with EMFILE) and with a normal one (the per-vehicle connection cap); its TCP port is
kernel-chosen (``--tcp-base 0``)."""

from __future__ import annotations

import resource
import socket
import subprocess
import sys
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega

from sim.launch import READY_LINE

pytestmark = pytest.mark.e2e


def _heartbeats(conn: socket.socket, seconds: float) -> int:
    mav = ardupilotmega.MAVLink(None)
    mav.robust_parsing = True
    n = 0
    conn.settimeout(0.2)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        try:
            data = conn.recv(65536)
        except TimeoutError:
            continue
        if not data:
            break
        n += sum(m.get_type() == "HEARTBEAT" for m in mav.parse_buffer(data) or [])
    return n


@pytest.mark.parametrize("nofile", [20, 256], ids=["out-of-descriptors", "connection-cap"])
def test_a_connection_flood_never_stops_the_loop(nofile: int) -> None:
    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_NOFILE, (nofile, nofile))

    proc = subprocess.Popen(
        [sys.executable, "-m", "sim.cli", "--quiet", "--flavour", "ardupilot", "--vehicles", "1",
         "--tcp-base", "0", "--gcs-port", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, preexec_fn=limit,
    )  # fmt: skip
    flood: list[socket.socket] = []
    try:
        assert proc.stdout is not None
        port = None
        for line in proc.stdout:
            if "tcp 127.0.0.1:" in line:
                port = int(line.rsplit(":", 1)[1])
            if READY_LINE in line:
                break
        assert port is not None, "no endpoint line"
        first = socket.create_connection(("127.0.0.1", port))
        flood.append(first)
        assert _heartbeats(first, 1.2) >= 1
        for _ in range(40):
            try:
                flood.append(socket.create_connection(("127.0.0.1", port), timeout=0.3))
            except OSError:
                pass
        time.sleep(0.2)
        assert proc.poll() is None
        assert _heartbeats(first, 2.2) >= 2, "the loop stopped: no more heartbeats"
    finally:
        for s in flood:
            s.close()
        proc.send_signal(2)
        out, _ = proc.communicate(timeout=10)
    assert proc.returncode == 0, out
    assert "tcp_refused=" in out  # what it shed is counted
