"""``bearingflock gcs`` usage errors and the offline paths: a clear one-line error and exit
status 2 for bad usage or a busy port, an empty snapshot without links, plots of a recording."""

from __future__ import annotations

import json
import socket

from typer.testing import CliRunner

from groundstation.gcs.record import Recorder
from groundstation.gcs_cli import gcs_app
from messages.codec import encode
from tests.groundstation.standin import StandinConfig, scripted_status


def run(*args: str, input: str | None = None):
    return CliRunner().invoke(gcs_app, list(args), input=input)


def test_usage_errors_exit_2_with_a_message():
    cases = [
        (["monitor", "--json", "--zenoh", "none", "--mavlink", "none"], "--json needs --once"),
        (["monitor", "--fleet", "a/b", "--once"], "fleet name"),
        (["arm", "--zenoh", "none"], "--ids 1,3 or --all"),
        (["arm", "--ids", "1", "--all"], "either --ids or --all"),
        (["hold", "--ids", "x"], "bad id list"),
        (["arm", "--all", "--mavlink", "tcp:1.2.3.4:5"], "expected udp:HOST:PORT"),
        (["plot", "/nonexistent.mcap", "--out", "/tmp/x"], "no such file"),
    ]
    for args, message in cases:
        res = run(*args)
        assert res.exit_code == 2, (args, res.output)
        assert message in res.output, (args, res.output)


def test_busy_port_is_a_clear_error():
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    try:
        port = s.getsockname()[1]
        res = run("monitor", "--once", "--zenoh", "none", "--mavlink", f"udp:127.0.0.1:{port}")
        assert res.exit_code == 2 and "is another ground station using it" in res.output
    finally:
        s.close()


def test_once_json_without_vehicles_and_plot_of_a_recording(tmp_path):
    res = run("monitor", "--once", "--json", "--wait", "0", "--zenoh", "none",
              "--mavlink", "udp:127.0.0.1:0")  # fmt: skip
    assert res.exit_code == 0, res.output
    snap = json.loads(res.output)
    assert snap["vehicles"] == [] and snap["fleet_status"]["up"] == 0 and snap["zenoh"] is None

    path = tmp_path / "r.mcap"
    rec = Recorder(path, "alpha")
    cfg = StandinConfig("alpha", [0, 1])
    for k in range(20):
        for i in (0, 1):
            data = encode(scripted_status(cfg, i, 0.1 * k, k, "flying"))
            rec.zenoh_sample(f"bf/alpha/{i}/status", data, 1000.0 + 0.1 * k)
    rec.close()
    res = run("plot", str(path), "--out", str(tmp_path / "p"))
    assert res.exit_code == 0, res.output
    assert len(res.output.split()) == 5
    assert all((tmp_path / "p" / name).stat().st_size > 5000 for name in (
        "scale_error.png", "sfm_convergence.png", "rigidity.png", "bearing_errors.png",
        "trajectories.png"))  # fmt: skip
    empty = tmp_path / "empty.mcap"
    Recorder(empty, "alpha").close()
    res = run("plot", str(empty), "--out", str(tmp_path / "q"))
    assert res.exit_code == 1 and "no vehicle data" in res.output


def test_a_file_that_is_not_mcap_is_a_usage_error(tmp_path):
    not_mcap = tmp_path / "flight.mcap"
    not_mcap.write_bytes(b"\xff\xd8\xff\xe0 a JPEG, not a recording")
    for args in (
        ["plot", str(not_mcap), "--out", str(tmp_path / "plots")],
        ["replay", str(not_mcap)],
    ):
        res = run(*args)
        assert res.exit_code == 2, (args, res.output)
        assert "not an MCAP recording" in res.output, (args, res.output)


def test_a_command_that_hears_nobody_says_where_it_listened():
    res = run("start", "--all", "--yes", "--fleet", "nobody", "--discover", "0.2",
              "--zenoh", "tcp/127.0.0.1:1")  # fmt: skip
    assert res.exit_code == 1, res.output
    assert "no vehicles heard" in res.output and "fleet 'nobody'" in res.output, res.output
