"""The ground-station CLI against the live simulator (4 PX4 vehicles, UDP, Zenoh on loopback):
``monitor --once --json`` sees every vehicle with its mode and arming state, fleet commands arm
and take off all four and report each ACK, ``stop`` lands everything, the live table shows in a
pseudo-terminal (tmux), and a recording of the run turns into plots.

A second, independent view of the vehicles comes from a MAVLink listener that talks to each
vehicle's own port (``udpout``), so it runs next to the CLI, which holds the GCS port.
"""

from __future__ import annotations

import json
import shlex
import shutil
import signal
import subprocess
import sys
import time

import pytest
from pymavlink import mavutil
from typer.testing import CliRunner

from groundstation.gcs.mavlink_listener import MavlinkListener, parse_endpoint
from groundstation.gcs.record import iter_records, tlog_path
from groundstation.gcs_cli import gcs_app
from sim.launch import start_sim
from sim.server import free_port_base

pytestmark = pytest.mark.e2e

N = 4
SPEEDUP = 4.0


@pytest.fixture(scope="module")
def sim():
    base = free_port_base(N)
    gcs_port, zenoh_ep = base + 45, f"tcp/127.0.0.1:{base + 46}"
    proc = start_sim(
        "--vehicles", str(N), "--port-base", str(base), "--gcs-port", str(gcs_port),
        "--speedup", str(SPEEDUP), "--zenoh", zenoh_ep, "--fleet", "eg",
    )  # fmt: skip
    side = MavlinkListener([parse_endpoint(f"udpout:127.0.0.1:{base + 40 + i}") for i in range(N)])
    side.start()
    try:
        yield {"mavlink": f"udp:127.0.0.1:{gcs_port}", "zenoh": zenoh_ep, "side": side}
    finally:
        side.close()
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=10)
        assert proc.returncode == 0, out


def gcs(sim, *args: str, input: str | None = None):
    links = ["--fleet", "eg", "--mavlink", sim["mavlink"]]
    if args[0] not in ("arm", "takeoff", "land"):
        links += ["--zenoh", sim["zenoh"]]
    if args[0] not in ("monitor", "record"):
        links += ["--discover", "1.5"]
    return CliRunner().invoke(gcs_app, [*args, *links], input=input)


def side_view(sim, pred, timeout_s: float = 15.0) -> dict:
    """Wait until ``pred(systems)`` holds in the side listener's view of the vehicles."""
    side: MavlinkListener = sim["side"]
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        systems = side.systems()
        if len(systems) == N and pred(systems):
            return systems
        time.sleep(0.1)
    raise AssertionError(f"vehicles never got there: {side.systems()}")


def acks(result, action: str, text: str) -> None:
    assert result.exit_code == 0, result.output
    lines = [ln for ln in result.output.splitlines() if ln.startswith("vehicle ")]
    assert len(lines) == N, result.output
    assert all("OK" in ln and text in ln for ln in lines), result.output
    assert f"{action}: {N}/{N} vehicles OK" in result.output


def test_monitor_json_then_fleet_commands_arm_takeoff_stop(sim, tmp_path):
    res = gcs(sim, "monitor", "--once", "--json", "--wait", "2.0")
    assert res.exit_code == 0, res.output
    snap = json.loads(res.output)
    vehicles = snap["vehicles"]
    assert [v["id"] for v in vehicles] == list(range(N))
    for v in vehicles:
        assert (v["mode"], v["armed"], v["flavour"]) == ("AUTO.LOITER", False, "px4")
        assert v["heartbeat_age_s"] < 4.0 and v["alarms"] == [] and v["altitude_m"] == 0.0
        assert 0.0 <= v["loss_pct"] < 50.0
    assert snap["zenoh"]["sim_time_s"] > 0  # the simulator's clock arrives over Zenoh

    res = gcs(sim, "arm", "--all", input="n\n")  # not confirmed: nothing is sent
    assert res.exit_code == 1 and "not confirmed" in res.output
    time.sleep(0.5)
    assert not any(s.armed for s in sim["side"].systems().values())

    acks(gcs(sim, "arm", "--all", "--yes"), "arm", "mavlink arm: ACCEPTED")
    side_view(sim, lambda sy: all(s.armed for s in sy.values()))
    acks(gcs(sim, "takeoff", "--ids", "0-3", "--yes"), "takeoff", "mavlink takeoff: ACCEPTED")
    side_view(sim, lambda sy: all((s.altitude_m or 0) > 1.0 for s in sy.values()))

    res = gcs(sim, "stop", "--yes")  # no agents run: LAND over MAVLink reaches every vehicle
    acks(res, "stop", "mavlink land: ACCEPTED")
    assert "agent: never heard" in res.output
    side_view(sim, lambda sy: all(s.mode == "AUTO.LAND" for s in sy.values()), 5.0)
    side_view(sim, lambda sy: all(not s.armed and s.altitude_m < 0.1 for s in sy.values()))

    # a selection naming a vehicle that does not exist fails for that one only
    res = gcs(sim, "land", "--ids", "2,9", "--yes", "--timeout", "1")
    assert res.exit_code == 1
    assert "vehicle 2: OK" in res.output and "vehicle 9: FAIL  mavlink: not heard" in res.output


def test_live_table_in_tmux_and_a_recording_plots(sim, tmp_path, recording_schemas):
    tmux = shutil.which("tmux")
    assert tmux is not None, "tmux is needed (apt-get install tmux)"
    sock = f"gcs-test-{time.monotonic_ns()}"
    code = "from groundstation.gcs_cli import gcs_app; gcs_app(prog_name='bearingflock gcs')"
    cmd = [
        sys.executable, "-c", code, "monitor", "--fleet", "eg", "--mavlink", sim["mavlink"],
        "--zenoh", sim["zenoh"],
    ]  # fmt: skip
    subprocess.run(
        [tmux, "-L", sock, "new-session", "-d", "-s", "mon", "-x", "160", "-y", "30",
         shlex.join(cmd)],
        check=True,
    )  # fmt: skip
    try:
        screen = ""
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline:
            screen = subprocess.run(
                [tmux, "-L", sock, "capture-pane", "-p", "-t", "mon"],
                capture_output=True, text=True, check=True,
            ).stdout  # fmt: skip
            if sum("AUTO." in ln for ln in screen.splitlines()) == N:
                break
            time.sleep(0.5)
        rows = [ln.split() for ln in screen.splitlines() if "AUTO." in ln]
        assert "bearingflock fleet 'eg'" in screen, screen
        assert sorted(r[0] for r in rows) == [str(i) for i in range(N)], screen
        assert "vehicles up 4/4" in screen, screen
    finally:
        subprocess.run([tmux, "-L", sock, "kill-server"], check=False)

    out = tmp_path / "run.mcap"
    res = gcs(sim, "record", str(out), "--duration", "2.0")
    assert res.exit_code == 0, res.output
    topics = {r.topic for r in iter_records(out)}
    assert {f"mavlink/{i + 1}/HEARTBEAT" for i in range(N)} <= topics
    names, problems = recording_schemas(out)
    assert problems == [] and names["scene/team"] == "foxglove.SceneUpdate"
    tlog = mavutil.mavlink_connection(str(tlog_path(out)))
    sysids = set()
    while (msg := tlog.recv_match(type="HEARTBEAT")) is not None:
        sysids.add(msg.get_srcSystem())
    assert sysids == {i + 1 for i in range(N)}
    assert {f"bf/eg/{i}/truth" for i in range(N)} <= topics and "bf/eg/sim/clock" in topics
    res = CliRunner().invoke(gcs_app, ["plot", str(out), "--out", str(tmp_path / "plots")])
    assert res.exit_code == 0, res.output
    pngs = sorted(p.name for p in (tmp_path / "plots").glob("*.png"))
    assert len(pngs) == 5 and "trajectories.png" in pngs
