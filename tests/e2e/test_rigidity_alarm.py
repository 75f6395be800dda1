"""The ground station's rigidity alarm works by construction (issue 21): the simulator and three
daemons as processes, real Zenoh on loopback, and the monitor's own listener and fleet line
(:func:`groundstation.gcs.monitor.snapshot`) reading their statuses. Agents 1 and 2 are killed:
agent 0 alone is no rigid framework (its rigidity guard raises ``rigidity_lost`` after the 2 s
loss time) and the fleet line turns "NOT rigid". Once the two words differed (the daemon raised
``rigidity_lost``, the monitor looked for ``rigidity_low``) and the column never turned."""

from __future__ import annotations

import time

import pytest
from rich.console import Console

from groundstation.gcs.monitor import Monitor, MonitorConfig, render
from groundstation.gcs.zenoh_listener import ZenohListener

pytestmark = pytest.mark.e2e


def _poll(predicate, timeout_s: float, what: str, show) -> None:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        if predicate():
            return
        time.sleep(0.1)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}: {show()}")


def test_fleet_line_turns_not_rigid_when_a_daemon_reports_lost_rigidity(fleet):
    ev, procs, _ports, _agent_args, name = fleet
    listener = ZenohListener(ev.session, name).start()
    monitor = Monitor(MonitorConfig(fleet=name), zenoh=listener)
    try:

        def rows() -> dict:
            return {r["id"]: r for r in monitor.snapshot()["vehicles"]}

        def line() -> dict:
            return monitor.snapshot()["fleet_status"]

        def three_agents_with_neighbours() -> bool:
            r = rows()
            return (
                line()["agents"] == 3
                and 0 in r
                and r[0].get("phase") in ("ready", "flying")
                and {1, 2} <= set(r[0].get("neighbours") or ())
            )

        _poll(three_agents_with_neighbours, 20.0, "three agents, agent 0 hearing 1 and 2", rows)
        assert line()["rigid"] is not False  # the whole team: rigid (or not estimated)
        assert not any("rigidity_lost" in r["alarms"] for r in rows().values())

        for victim in ("agent1", "agent2"):
            dict(procs.procs)[victim].kill()
        _poll(lambda: line()["rigid"] is False, 10.0, "the fleet line to turn not rigid", rows)
        alarms = rows()[0]["alarms"]
        assert {"rigidity_lost", "peer_lost:1", "peer_lost:2"} <= set(alarms), alarms
        console = Console(record=True, width=200)
        console.print(render(monitor.snapshot()))
        assert "NOT rigid" in console.export_text()
    finally:
        listener.close()
