"""The MAVSDK backend's "cannot open" error carries its cause, so the daemon's connect loop
(:func:`messages.fatal.is_permanent`) ends on a port another process holds instead of
retrying forever, as with the pymavlink backend (issue 23, defect 12 leftover). Real MAVSDK,
real sockets on ports the kernel chose."""

from __future__ import annotations

import errno
import socket

import pytest

from messages.fatal import is_permanent
from onboard.autopilot.base import LinkConfig, LinkError
from onboard.autopilot.mavsdk_link import MavsdkLink

pytest.importorskip("mavsdk")


def test_udpin_port_in_use_is_a_permanent_cannot_open() -> None:
    held = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    held.bind(("127.0.0.1", 0))
    port = held.getsockname()[1]
    link = MavsdkLink(LinkConfig())
    try:
        with pytest.raises(LinkError) as err:
            link.connect(f"udpin:127.0.0.1:{port}", timeout_s=2.0)
    finally:
        held.close()
        link.close()
    assert "cannot open" in str(err.value) and "in use" in str(err.value), err.value
    assert isinstance(err.value.__cause__, OSError)
    assert err.value.__cause__.errno == errno.EADDRINUSE
    assert is_permanent(err.value)


def test_the_cause_of_each_result() -> None:
    from onboard.autopilot.mavsdk_link import open_failure_cause

    assert is_permanent(open_failure_cause("udpin://x", "CONNECTION_URL_INVALID"))
    # a listening URL whose port binds again now: a transient failure, retried
    assert not is_permanent(open_failure_cause("udpin://127.0.0.1:0", "BIND_ERROR"))
    # an autopilot not (yet) listening on the TCP port: retried
    assert not is_permanent(
        open_failure_cause("tcpout://127.0.0.1:5760", "SOCKET_CONNECTION_ERROR")
    )
