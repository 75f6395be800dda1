"""Bad configuration and command-line input: one clean line and a nonzero exit, never a
traceback, a process that never exits, or an option silently ignored (issue 23, defect 12).

Every case ran before this test: 10 gave tracebacks, 3 never exited (here: did not exit within
the test's timeout), 6 were accepted or ignored. CLI cases run in-process through typer's runner
where no process is needed; the ones about a process (a port in use, a retry loop) run the real
command in a subprocess, on free ports: tests/e2e/test_bad_input_processes.py."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest
from typer.testing import CliRunner

from groundstation.cli import app
from groundstation.gcs.record import Recorder
from messages.codec import encode
from tests.groundstation.standin import StandinConfig, scripted_status

FORMATION = """
[[agent]]
id = 0
position_ned = [0.0, 0.0, -5.0]
[[agent]]
id = 1
position_ned = [4.0, 0.0, -5.0]
[[agent]]
id = 2
position_ned = [2.0, 3.0, -6.0]
"""


def fleet_file(tmp: Path, body: str, zenoh_base: int | None = None) -> Path:
    (tmp / "formation.toml").write_text(FORMATION)
    path = tmp / "fleet.toml"
    zenoh = f"[zenoh]\nport_base = {zenoh_base}\n" if zenoh_base is not None else ""
    text = f'formation = "formation.toml"\n{body}\n'
    if zenoh and "[zenoh]" not in body:
        text += zenoh
    path.write_text(text)
    return path


def recording(tmp: Path, vehicles: bool = True) -> Path:
    path = tmp / "r.mcap"
    rec = Recorder(path, "alpha")
    cfg = StandinConfig("alpha", [0, 1])
    for k in range(10 if vehicles else 0):
        for i in (0, 1):
            data = encode(scripted_status(cfg, i, 0.1 * k, k, "flying"))
            rec.zenoh_sample(f"bf/alpha/{i}/status", data, 1000.0 + 0.1 * k)
    rec.close()
    return path


@contextmanager
def held_tcp_port() -> Iterator[int]:
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    s.bind(("127.0.0.1", 0))
    s.listen()
    try:
        yield s.getsockname()[1]
    finally:
        s.close()


@contextmanager
def held_udp_port() -> Iterator[int]:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    try:
        yield s.getsockname()[1]
    finally:
        s.close()


@dataclass
class Case:
    """``args(tmp)`` -> the ``bearingflock`` arguments; ``message``: in the error line."""

    name: str
    args: Callable[[Path], list[str]]
    message: str
    code: int = 2


def _agent(body: str) -> Callable[[Path], list[str]]:
    return lambda tmp: ["agent", "--id", "0", "--config", str(fleet_file(tmp, body))]


def _plot_to_proc(tmp: Path) -> list[str]:
    return ["gcs", "plot", str(recording(tmp)), "--out", "/proc/plots"]


def _truncated(tmp: Path) -> list[str]:
    path = recording(tmp)
    data = path.read_bytes()
    path.write_bytes(data[:200])  # cut inside the first chunk
    return ["gcs", "replay", str(path), "--zenoh", "tcp/127.0.0.1:1"]


IN_PROCESS = [
    Case("fleet name a/b c", _agent('fleet = "a/b c"'), "fleet name"),
    Case("zenoh port_base -5", _agent("[zenoh]\nport_base = -5"), "zenoh.port_base"),
    Case("zenoh connect bogus", _agent('[zenoh]\nconnect = ["bogus"]'), "zenoh endpoint"),
    Case("zenoh connect port", _agent('[zenoh]\nconnect = ["tcp/10.0.0.1:99999"]'), "0..65535"),
    Case("zenoh config_file missing", _agent('[zenoh]\nconfig_file = "no.json5"'), "no.json5"),
    Case("mavlink port_base 70000", _agent("[mavlink]\nport_base = 70000"), "1..65535"),
    Case("mavlink url bogus:::", _agent('[mavlink]\nurl = "bogus:::"'), "mavlink.url"),
    Case("limits.max_alt_m inf", _agent("[limits]\nmax_alt_m = inf"), "limits.max_alt_m"),
    Case("sim --port-base 70000", lambda t: ["sim", "--port-base", "70000"], "1..65535"),
    Case(
        "sim --tcp-base 65530 (ArduPilot, 3 vehicles)",
        lambda t: ["sim", "--flavour", "ardupilot", "--tcp-base", "65530"],
        "1..65535",
    ),
    Case("sim --strict --warmup -5", lambda t: ["sim", "--strict", "--warmup", "-5"], "warmup_s"),
    Case("sim --warmup nan", lambda t: ["sim", "--warmup", "nan"], "warmup_s"),
    Case("demo --out /proc/demo", lambda t: ["demo", "--out", "/proc/demo"], "cannot write"),
    Case("gcs plot --out /proc/plots", _plot_to_proc, "cannot write the plots"),
    Case(
        "gcs record --duration nan",
        lambda t: ["gcs", "record", str(t / "x.mcap"), "--duration", "nan"],
        "--duration",
    ),
    Case(
        "gcs record --duration -1",
        lambda t: ["gcs", "record", str(t / "x.mcap"), "--duration", "-1"],
        "--duration",
    ),
    Case(
        "gcs monitor --zenoh none --zenoh-listen",
        lambda t: [
            "gcs",
            "monitor",
            "--once",
            "--zenoh",
            "none",
            "--zenoh-listen",
            "tcp/127.0.0.1:0",
            "--mavlink",
            "none",
        ],
        "--zenoh-listen",
    ),
    Case("gcs replay truncated", _truncated, "nothing to read", code=1),
    Case(
        "gcs leader --velocity 1,2",
        lambda t: ["gcs", "leader", "0", "--velocity", "1,2", "--yes"],
        "three finite numbers",
    ),
    Case(
        "gcs leader --velocity 1e3,0,0",
        lambda t: ["gcs", "leader", "0", "--velocity", "1e3,0,0", "--yes"],
        "not a leader drive",
    ),
    Case("gcs leader without a drive", lambda t: ["gcs", "leader", "0", "--yes"], "exactly one"),
    Case(
        "gcs leader --waypoints missing",
        lambda t: ["gcs", "leader", "0", "--waypoints", str(t / "no.toml"), "--yes"],
        "no.toml",
    ),
    Case(
        "gcs formation --ramp -1",
        lambda t: ["gcs", "formation", str(t / "f.toml"), "--ramp", "-1", "--yes"],
        "--ramp",
    ),
]


def _one_line_error(output: str, message: str) -> None:
    assert "Traceback" not in output, output
    errors = [line for line in output.splitlines() if line.startswith("error")]
    assert len(errors) == 1 and message in errors[0], output


@pytest.mark.parametrize("case", IN_PROCESS, ids=lambda c: c.name)
def test_bad_input_is_one_error_line_and_a_nonzero_exit(case: Case, tmp_path: Path) -> None:
    t0 = time.monotonic()
    res = CliRunner().invoke(app, case.args(tmp_path))
    assert res.exit_code == case.code, (res.output, res.exception)
    assert not isinstance(res.exception, Exception) or isinstance(res.exception, SystemExit)
    _one_line_error(res.output, case.message)
    assert time.monotonic() - t0 < 10.0


def test_headless_demo_writes_its_summary_into_out(tmp_path: Path) -> None:
    """``demo --headless --out DIR`` used to write nothing into DIR."""
    out = tmp_path / "demo"
    res = CliRunner().invoke(
        app, ["demo", "--headless", "--vehicles", "4", "--duration", "2", "--out", str(out)]
    )
    assert res.exit_code in (0, 1), res.output  # the verdict of a 2 s mission may be FAIL
    summary = out / "summary.json"
    assert summary.is_file() and '"headless": true' in summary.read_text()
