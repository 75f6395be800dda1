"""The ground station against the simulator and real daemons (not stand-ins): the snapshot
reports every vehicle with its mode, arming and estimator fields; a killed agent turns its row
red within 5 s; `stop` lands everyone."""

from __future__ import annotations

import json
import shlex
import shutil
import subprocess
import sys
import time

import pytest

pytestmark = pytest.mark.e2e
N = 3  # vehicles in the `fleet` fixture (conftest.py)


def gcs(*args: str, timeout_s: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "groundstation.cli", "gcs", *args],
        capture_output=True, text=True, timeout=timeout_s,
    )  # fmt: skip


def test_monitor_and_stop_with_real_agents(fleet, wait_for, tmp_path):
    ev, procs, ports, _, name = fleet
    links = ["--fleet", name]
    for k in range(N + 1):  # the simulator's and every agent's Zenoh endpoint
        links += ["--zenoh", f"tcp/127.0.0.1:{ports.zenoh + k}"]
    mav = ["--mavlink", f"udp:127.0.0.1:{ports.gcs}"]
    wait_for(
        lambda: len(ev.snapshot()) == N and all(s.phase == "flying" for s in ev.snapshot().values()),
        60.0, "every daemon flying", ev,
    )  # fmt: skip

    def snapshot() -> dict[int, dict]:
        out = gcs("monitor", "--once", "--json", "--wait", "2.0", *links, *mav)
        assert out.returncode == 0, out.stderr
        return {v["id"]: v for v in json.loads(out.stdout)["vehicles"]}

    rows = snapshot()
    assert sorted(rows) == list(range(N))
    for v in rows.values():
        assert v["mode"] == "OFFBOARD" and v["armed"] is True
        assert v["phase"] == "flying" and v["heartbeat_age_s"] < 2.0
        assert "e_index" in v and "chi_hat_inv_m" in v and v["alive"] is True
        assert not v["red"], v["alarms"]

    # a recording of the flying daemons (status, peer traffic, truth, MAVLink) turns into plots
    log = tmp_path / "agents.mcap"
    out = gcs("record", str(log), "--duration", "4.0", *links, *mav)
    assert out.returncode == 0, out.stdout + out.stderr
    out = gcs("plot", str(log), "--out", str(tmp_path / "plots"), "--fleet", name)
    assert out.returncode == 0, out.stdout + out.stderr
    pngs = sorted((tmp_path / "plots").glob("*.png"))
    assert len(pngs) >= 4 and all(p.stat().st_size > 10_000 for p in pngs), pngs

    # the live monitor in a pseudo-terminal: kill agent 1 and time its row turning to agent_lost
    tmux = shutil.which("tmux")
    assert tmux is not None, "tmux is needed (the README's test command installs it)"
    sock = f"gcs-agents-{time.monotonic_ns()}"
    cmd = [sys.executable, "-m", "groundstation.cli", "gcs", "monitor", *links, *mav]
    subprocess.run(
        [tmux, "-L", sock, "new-session", "-d", "-s", "mon", "-x", "220", "-y", "40",
         "COLUMNS=220 LINES=40 " + shlex.join(cmd)],
        check=True,
    )  # fmt: skip

    def screen() -> str:
        return subprocess.run(
            [tmux, "-L", sock, "capture-pane", "-p", "-t", "mon"],
            capture_output=True, text=True, check=True,
        ).stdout  # fmt: skip

    def row(agent_id: int) -> str:
        """The table line of one vehicle (cells split on the box-drawing borders)."""
        for line in screen().splitlines():
            cells = line.replace("│", " ").replace("┃", " ").split()
            if cells[:1] == [str(agent_id)]:
                return line
        return ""

    try:
        try:
            wait_for(lambda: all("flying" in row(k) for k in range(N)), 30.0, "the live table")
        except AssertionError as exc:
            raise AssertionError(f"{exc}\n{screen()}") from None
        dict(procs.procs)["agent1"].kill()
        took = wait_for(lambda: "agent_lost" in row(1), 10.0, "row 1 to show agent_lost")
        assert took <= 5.0, f"row 1 turned red after {took:.1f} s"
        assert "flying" in row(0) and "agent_lost" not in row(0)
    finally:
        subprocess.run([tmux, "-L", sock, "kill-server"], check=False)

    out = gcs("stop", "--all", "--yes", *links, *mav)
    assert out.returncode == 0, out.stdout + out.stderr
    wait_for(lambda: all(not s.in_air for k, s in ev.snapshot().items() if k != 1), 40.0,
             "the live agents' vehicles to land", ev)  # fmt: skip
    wait_for(lambda: not snapshot()[1]["in_air"], 40.0, "vehicle 1 (dead agent) to land")
