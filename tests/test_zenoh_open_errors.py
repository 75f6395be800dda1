"""A Zenoh session that cannot open is one error line and a nonzero exit (issue 23, defect 12's
leftovers): ``sim --autopilot ardupilot-sitl`` and the demo's own session used to let
:class:`messages.transport.TransportError` escape as a traceback (and SITL started first, so a
port in use left ArduCopter processes starting for nothing). Real sockets: the port is held by a
listening socket the kernel chose."""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from typer.testing import CliRunner

from groundstation.cli import app
from groundstation.demo import Evaluator, plan_formation
from messages.transport import ZenohSettings, loopback_endpoint

SITL = Path(os.environ.get("BEARINGFLOCK_SITL", "/work/shared/sitl/arducopter"))


@contextmanager
def held_tcp_port() -> Iterator[int]:
    """A loopback TCP port the kernel chose, held by a listening socket."""
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    s.bind(("127.0.0.1", 0))
    s.listen()
    try:
        yield s.getsockname()[1]
    finally:
        s.close()


def _one_line_error(output: str, message: str) -> None:
    assert "Traceback" not in output, output
    errors = [line for line in output.splitlines() if line.startswith("error")]
    assert len(errors) == 1 and message in errors[0], output


@pytest.mark.skipif(not os.access(SITL, os.X_OK), reason="no ArduCopter SITL binary")
def test_sitl_sim_with_its_zenoh_port_in_use_is_one_error_line() -> None:
    t0 = time.monotonic()
    with held_tcp_port() as port:
        res = CliRunner().invoke(
            app,
            ["sim", "--autopilot", "ardupilot-sitl", "--sitl", str(SITL), "--vehicles", "2",
             "--zenoh", loopback_endpoint(port), "--quiet"],
        )  # fmt: skip
    assert res.exit_code == 2, (res.output, res.exception)
    assert not isinstance(res.exception, Exception) or isinstance(res.exception, SystemExit)
    _one_line_error(res.output, "zenoh")
    assert "SITL instance" not in res.output  # no ArduCopter process was started
    assert time.monotonic() - t0 < 10.0


def test_demo_evaluator_session_that_cannot_open_is_a_runtime_error_line() -> None:
    """The demo CLI prints a RuntimeError as one ``error:`` line with exit 1."""
    with held_tcp_port() as port:
        settings = ZenohSettings(listen=[loopback_endpoint(port)])
        with pytest.raises(RuntimeError) as err:
            Evaluator("demo0", plan_formation(3), settings)
    text = str(err.value)
    assert "\n" not in text and "zenoh" in text and str(port) in text, text
