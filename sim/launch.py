"""Start the simulator as a separate process and know when it is ready (tests, scripts).

``bearingflock sim`` prints where every vehicle listens and then a line ending in
``Ctrl-C to stop``; :func:`start_sim` waits for that line, so a client that connects right
after never races the simulator's sockets.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time

READY_LINE = "Ctrl-C to stop"


def start_sim(*args: str, timeout_s: float = 20.0) -> subprocess.Popen[str]:
    """``python -m sim.cli --quiet ARGS`` with its output piped; returns once it is ready.

    Raises ``RuntimeError`` with everything it printed if it exits or is not ready in time.
    """
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim.cli", "--quiet", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    assert proc.stdout is not None
    deadline = time.monotonic() + timeout_s
    lines = []
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        lines.append(line)
        if READY_LINE in line:
            return proc
        if not line and proc.poll() is not None:
            break
    proc.kill()
    raise RuntimeError("simulator did not start:\n" + "".join(lines))


def stop_sim(proc: subprocess.Popen[str], timeout_s: float = 10.0) -> str:
    """Ctrl-C the simulator and return the rest of its output; raises if it fails to exit 0."""
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=timeout_s)
    if proc.returncode != 0:
        raise RuntimeError(f"simulator exited with {proc.returncode}:\n{out}")
    return out
