"""The simulator stops on SIGINT and SIGTERM even when started as a background job.

A non-interactive shell starts background commands with SIGINT ignored; Python then never
raises KeyboardInterrupt, and a simulator that relied on it ran on after `kill -INT` (the test
fixtures' way of stopping it), holding its ports and a CPU."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest

from sim.launch import READY_LINE
from sim.server import free_port_base


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_sim_stops_on_signal_with_sigint_ignored_at_start(sig: signal.Signals) -> None:
    base = free_port_base(1)
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim.cli", "--quiet", "--vehicles", "1", "--port-base", str(base),
         "--gcs-port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline and READY_LINE not in proc.stdout.readline():
            assert proc.poll() is None, "simulator exited before it was ready"
        proc.send_signal(sig)
        out, _ = proc.communicate(timeout=10.0)
        assert proc.returncode == 0, out
        assert "stopped at t=" in out
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
