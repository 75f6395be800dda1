"""The simulator stops on SIGINT and SIGTERM even when started as a background job.

A non-interactive shell starts background commands with SIGINT ignored; Python then never
raises KeyboardInterrupt, and a simulator that relied on it ran on after `kill -INT` (the test
fixtures' way of stopping it), holding its ports and a CPU.

No fixed or pre-checked ports (issue 23, defect 13: this test failed once while other processes
held ports): the vehicle binds a port the kernel picks (``--bind-base 0``) and sends to the
discard port, where nobody listens. No timing luck either: the signal goes out only once the
ready line was read (a simulator that exits first, or prints no ready line, fails the test with
its output), and every wait is bounded by a generous timeout, not a race."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from sim.launch import READY_LINE


def _read_until_ready(proc: subprocess.Popen[str]) -> str:
    """Everything printed up to and including the ready line; fails if the process ends first."""
    assert proc.stdout is not None
    seen = []
    for line in proc.stdout:  # blocks per line; pytest's timeout bounds a silent hang
        seen.append(line)
        if READY_LINE in line:
            return "".join(seen)
    proc.wait(timeout=10.0)
    pytest.fail(f"simulator exited ({proc.returncode}) before it was ready:\n{''.join(seen)}")


@pytest.mark.timeout(60)
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_sim_stops_on_signal_with_sigint_ignored_at_start(sig: signal.Signals) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim.cli", "--quiet", "--vehicles", "1", "--bind-base", "0",
         "--port-base", "9", "--gcs-port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )  # fmt: skip
    try:
        head = _read_until_ready(proc)
        assert "udp 127.0.0.1:" in head and ":0 " not in head  # a real, kernel-chosen port
        proc.send_signal(sig)
        out, _ = proc.communicate(timeout=20.0)
        assert proc.returncode == 0, out
        assert "stopped at t=" in out
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
