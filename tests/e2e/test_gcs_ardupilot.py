"""The ground station against ArduPilot-flavour autopilots, which behave like ArduCopter: they
stream nothing to a port until asked (the monitor asks, and shows altitude, speed, battery and
the in-air state; issue 22, bug 3), and they refuse (where the real one crashes) a NaN in
ARM_DISARM's param 2, which ``gcs arm`` once sent (bug 2)."""

from __future__ import annotations

import json
import signal

import pytest
from typer.testing import CliRunner

from groundstation.gcs_cli import gcs_app
from sim.launch import start_sim
from sim.server import free_port_base

pytestmark = pytest.mark.e2e

N = 2


@pytest.fixture
def ardupilot_sim():
    base = free_port_base(N)
    gcs_port = base + 45
    proc = start_sim(
        "--vehicles", str(N), "--flavour", "ardupilot", "--transport", "udp", "--strict",
        "--warmup", "1", "--ekf-warmup", "1", "--port-base", str(base),
        "--gcs-port", str(gcs_port), "--speedup", "2",
    )  # fmt: skip
    try:
        yield f"udp:127.0.0.1:{gcs_port}"
    finally:
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=10)
        assert proc.returncode == 0, out
        assert "nan_commands" not in out, out  # the simulator refused no NaN parameter


def test_monitor_asks_an_ardupilot_for_its_streams_and_arm_sends_no_nan(ardupilot_sim):
    mavlink = ardupilot_sim
    res = CliRunner().invoke(
        gcs_app,
        ["monitor", "--once", "--json", "--wait", "3.0", "--mavlink", mavlink, "--zenoh", "none"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    vehicles = json.loads(res.output)["vehicles"]
    assert [v["id"] for v in vehicles] == list(range(N))
    for v in vehicles:
        assert (v["flavour"], v["mode"], v["armed"]) == ("ardupilot", "STABILIZE", False)
        assert v["altitude_m"] == pytest.approx(0.0, abs=0.05)
        assert v["speed_m_s"] == pytest.approx(0.0, abs=0.05)
        assert v["battery_pct"] == 100.0
        assert v["in_air"] is False

    res = CliRunner().invoke(
        gcs_app, ["arm", "--all", "--yes", "--mavlink", mavlink, "--zenoh", "none"]
    )
    assert res.exit_code == 0, res.output
    assert res.output.count("mavlink arm: ACCEPTED") == N, res.output
