"""The simulator never stays half alive (issue 23, defect 5): its loop died on EMFILE in TCP
accept (1,025 connections at the usual 1024-descriptor limit) and the process ran on with its
clock frozen. Now accept sheds what it cannot hold (tests/e2e/test_sim_flood.py, a real
process), and a loop that dies for any reason is reported and ends the process."""

from __future__ import annotations

import pytest

from sim.server import SimConfig, SimServer
from sim.world import grid_layout


def test_a_loop_that_dies_is_reported_and_never_looks_alive() -> None:
    p, yaw = grid_layout(1, 5.0)
    server = SimServer(SimConfig(p, yaw, client_base=9, gcs_port=None, bind_base=0,
                                 lockstep=True))  # fmt: skip

    def boom(t_s: float, _world: object) -> None:
        if t_s > 0.05:
            raise OSError(24, "Too many open files")

    server.hooks.append(boom)
    server.start()
    try:
        with pytest.raises(RuntimeError, match=r"simulator loop died at t=0\.06s: OSError"):
            server.advance_to(1.0, timeout_s=10.0)
        assert not server.alive()
        assert isinstance(server.failure, OSError)
    finally:
        server.stop()
    assert server.failure is not None  # a stop does not hide why it ended
