"""MAVProxy (the ``mavproxy`` package) connects without a terminal, downloads the parameters,
shows a parameter, reads the mode and (ArduPilot) changes it."""

from __future__ import annotations

import queue
import shutil
import signal
import subprocess
import sys
import threading
import time

import pytest

from sim.launch import start_sim
from sim.server import free_port_base
from tests.e2e.sim_ports import start_sim_on_kernel_ports

pytestmark = pytest.mark.e2e


class MavProxy:
    """MAVProxy driven through its stdin console, its output collected line by line."""

    def __init__(self, master: str, cwd: str) -> None:
        exe = shutil.which("mavproxy.py") or str(
            __import__("pathlib").Path(sys.executable).with_name("mavproxy.py")
        )
        self.proc = subprocess.Popen(
            [sys.executable, exe, f"--master={master}", "--nodtr",
             "--default-modules=param,mode,arm,cmdlong"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
            text=True, cwd=cwd,
        )  # fmt: skip
        self.lines: queue.Queue[str] = queue.Queue()
        self.seen: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.put(line)

    def expect(self, text: str, timeout: float = 20.0) -> str:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=0.2)
            except queue.Empty:
                continue
            self.seen.append(line)
            if text in line:
                return line
        raise AssertionError(f"MAVProxy never printed {text!r}:\n" + "".join(self.seen))

    def send(self, command: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()

    def close(self) -> None:
        # MAVProxy ignores SIGTERM for seconds while its modules unload; it keeps no state we need
        self.proc.kill()
        self.proc.wait()


@pytest.mark.parametrize("flavour", ["ardupilot", "px4"])
def test_mavproxy_params_and_mode(flavour, tmp_path):
    if flavour == "ardupilot":  # its TCP server on a port the kernel chose
        sim, port = start_sim_on_kernel_ports(
            "--vehicles", "1", "--flavour", "ardupilot", "--tcp-base", "0"
        )
        master, n_params, sysid_param, mode, new_mode = (
            f"tcp:127.0.0.1:{port}", 14, "SYSID_THISMAV", "STABILIZE", "GUIDED",
        )  # fmt: skip
    else:  # MAVProxy's udpin port must be known before it binds: a checked free range
        base = free_port_base(1, span=60)
        sim = start_sim(
            "--vehicles", "1", "--port-base", str(base), "--bind-base", "0",
            "--gcs-port", str(base + 10),
        )  # fmt: skip
        master, n_params, sysid_param, mode, new_mode = (
            f"udpin:127.0.0.1:{base + 10}", 12, "MAV_SYS_ID", "LOITER", None,
        )  # fmt: skip
    mp = MavProxy(master, str(tmp_path))
    try:
        mp.expect("online system 1")
        mp.expect(f"Received {n_params} parameters")
        mp.send(f"param show {sysid_param}")
        line = mp.expect(f"{sysid_param} ")
        assert float(line.split()[-1]) == 1.0
        mp.send("status HEARTBEAT")
        assert mode in mp.expect(f"{mode}>")
        if new_mode is not None:  # MAVProxy's own ``mode`` command only works for ArduPilot
            mp.send(f"mode {new_mode}")
            mp.expect(f"Mode {new_mode}")
    finally:
        mp.close()
        sim.send_signal(signal.SIGINT)
        sim.communicate(timeout=10)
    assert sim.returncode == 0
