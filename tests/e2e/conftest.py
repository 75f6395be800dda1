"""Shared fixtures of the end-to-end tests that run the simulator and real daemons."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from groundstation.demo import DemoPorts, Evaluator, Processes, plan_formation, write_demo_files
from messages.fleetkeys import GCS_NAME, identity_files, identity_fleet
from messages.transport import ZenohSettings, loopback_endpoint, with_mutual_tls
from messages.zenoh_acl import fleet_access_control
from sim.server import free_port_base

N = 3


def _wait_for(predicate, timeout_s: float, what: str, ev: Evaluator | None = None) -> float:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        if predicate():
            return time.monotonic() - t0
        time.sleep(0.1)
    state = (
        {k: (s.phase, s.autopilot_mode, s.alarms) for k, s in ev.snapshot().items()} if ev else {}
    )
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}; status {state}")


@contextmanager
def running_fleet(
    tmp_path: Path, extra_fleet_toml: str = "", keys: Path | None = None, loss: float = 0.0
) -> Iterator[tuple]:
    """The simulator and N daemons as processes (the demo's files, ``extra_fleet_toml``
    appended to the fleet file); yields ``(evaluator, processes, ports, agent_args, fleet)``.

    ``keys``: a ``bearingflock keys init`` directory inside ``tmp_path``: the fleet file's
    ``[security] dir``, the simulator's ``--keys``, and the evaluator joins Zenoh over mutual
    TLS as the ground station. ``loss``: the fleet file's ``[zenoh] inject_loss`` (every
    daemon drops that fraction of the peer messages it receives)."""
    base = free_port_base(N + 2, span=60)
    ports = DemoPorts(zenoh=base, mavlink=base + 10 + N, gcs=base + 9)
    plan = plan_formation(N, seed=1)
    name = f"t{base}"
    fleet_path = write_demo_files(tmp_path, plan, ports, name, "formation-active", loss)
    if keys is not None:
        extra_fleet_toml += f'\n[security]\ndir = "{keys.relative_to(tmp_path)}"\n'
    if extra_fleet_toml:
        with fleet_path.open("a") as f:
            f.write(extra_fleet_toml)
    procs = Processes(tmp_path)
    procs.start(
        "sim",
        [
            "-m", "sim.cli", "--vehicles", str(N), "--layout", str(tmp_path / "start.toml"),
            "--zenoh", loopback_endpoint(ports.zenoh), "--fleet", name,
            "--port-base", str(ports.mavlink), "--gcs-port", str(ports.gcs),
            "--bind-base", "0", "--camera-fov", "360", "--quiet",
            *(["--keys", str(keys)] if keys is not None else []),
        ],
    )  # fmt: skip
    agent_args = {
        i: ["-m", "groundstation.cli", "agent", "--id", str(i), "--config", str(fleet_path)]
        for i in range(N)
    }
    for i, args in agent_args.items():
        procs.start(f"agent{i}", args)
    settings = ZenohSettings(connect=[loopback_endpoint(ports.zenoh + k) for k in range(N + 1)])
    if keys is not None:
        acl = fleet_access_control(name, N, identity_fleet(keys))
        settings = with_mutual_tls(settings, *identity_files(keys, GCS_NAME), acl)
    ev = Evaluator(name, plan, settings)
    try:
        yield ev, procs, ports, agent_args, name
    finally:
        ev.close()
        procs.stop()


@pytest.fixture
def fleet(tmp_path: Path):
    with running_fleet(tmp_path) as running:
        yield running


@pytest.fixture
def fleet_with():
    """``fleet_with(tmp_path, extra_fleet_toml)``: :func:`running_fleet` as a context manager."""
    return running_fleet


@pytest.fixture
def wait_for():
    """``wait_for(predicate, timeout_s, what, ev=None)``: poll until true, else fail with the
    fleet's status in the message; returns the time it took."""
    return _wait_for
