"""Start the simulator on ports the kernel chose (issue 23, defect 13): a port range checked
free and bound later (``sim.server.free_port_base``) can be taken in between by another
process; a port the kernel hands out while binding cannot."""

from __future__ import annotations

import subprocess
import sys
import time

from sim.launch import READY_LINE


def start_sim_on_kernel_ports(*args: str, timeout_s: float = 20.0) -> tuple[subprocess.Popen, int]:
    """``python -m sim.cli --quiet ARGS`` (with ``--tcp-base 0``: its TCP server on a port the
    kernel chose, no free range checked and bound later, issue 23); returns the process once
    it is ready and vehicle 0's port from its endpoint line."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim.cli", "--quiet", *args],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    assert proc.stdout is not None
    deadline = time.monotonic() + timeout_s
    lines: list[str] = []
    port = None
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        lines.append(line)
        if port is None and "tcp 127.0.0.1:" in line:
            port = int(line.rsplit(":", 1)[1])
        if READY_LINE in line and port is not None:
            return proc, port
        if not line and proc.poll() is not None:
            break
    proc.kill()
    raise RuntimeError("simulator did not start:\n" + "".join(lines))
