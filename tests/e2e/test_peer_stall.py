"""Peers notice a stalled vehicle (issue 23, defect 6): the simulator and three daemons as
processes, real Zenoh on loopback. Agent 1's daemon is stopped (SIGSTOP) for 3 s while its
liveliness token persists (its Zenoh session announces a 30 s lease, as a slow radio link or a
router may keep a token): agent 0 and agent 2 must raise ``peer_lost:1`` from the silence of
its payloads, and drop it once it resumes (SIGCONT). Before, only the token counted: a stalled
vehicle stayed in everyone's graph, its last data used as if fresh."""

from __future__ import annotations

import json
import os
import signal
import time

import pytest

pytestmark = pytest.mark.e2e

STOP_S = 3.0
VICTIM = 1


def _victim_files(tmp_path, ports, n: int) -> list[str]:
    """Agent 1's own fleet file: the same fleet, its Zenoh session from a config file with a
    30 s lease (the others keep its token that long after it went quiet)."""
    zport = lambda i: ports.zenoh + 1 + i  # noqa: E731 (the fleet's rule: port_base + 1 + id)
    connect = [ports.zenoh, *(zport(j) for j in range(n) if j != VICTIM)]
    conf = {
        "mode": "peer",
        "listen": {"endpoints": [f"tcp/127.0.0.1:{zport(VICTIM)}"]},
        "connect": {"endpoints": [f"tcp/127.0.0.1:{p}" for p in connect]},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"tx": {"lease": 30000, "keep_alive": 4}}},
    }
    (tmp_path / "victim_zenoh.json5").write_text(json.dumps(conf))
    text = (tmp_path / "fleet.toml").read_text()
    assert text.count("[zenoh]\n") == 1
    victim = tmp_path / "fleet_victim.toml"
    victim.write_text(text.replace("[zenoh]\n", '[zenoh]\nconfig_file = "victim_zenoh.json5"\n'))
    return ["-m", "groundstation.cli", "agent", "--id", str(VICTIM), "--config", str(victim)]


def test_a_stalled_vehicle_is_lost_to_its_peers_and_rejoins(fleet, wait_for, tmp_path):
    ev, procs, ports, agent_args, _name = fleet
    old = dict(procs.procs)[f"agent{VICTIM}"]
    old.terminate()
    old.wait(10)
    victim = procs.start("agent1-victim", _victim_files(tmp_path, ports, len(agent_args)))
    others = [j for j in agent_args if j != VICTIM]
    lost = f"peer_lost:{VICTIM}"

    def alarms(j: int) -> list[str]:
        st = ev.snapshot().get(j)
        return list(st.alarms) if st is not None else ["<no status>"]

    def team_up() -> bool:
        snap = ev.snapshot()
        return (
            all(
                j in snap
                and snap[j].phase in ("ready", "flying")
                and VICTIM in snap[j].agent.neighbours
                and lost not in snap[j].alarms
                for j in others
            )
            and VICTIM in snap
            and snap[VICTIM].phase in ("ready", "flying")
        )

    wait_for(team_up, 25.0, "the team up, agents 0 and 2 hearing agent 1", ev)
    os.kill(victim.pid, signal.SIGSTOP)
    t_stop = time.monotonic()
    try:
        noticed = {}
        while time.monotonic() - t_stop < STOP_S and len(noticed) < len(others):
            for j in others:
                if j not in noticed and lost in alarms(j):
                    noticed[j] = time.monotonic() - t_stop
            time.sleep(0.05)
        print(f"peer_lost:{VICTIM} raised after {noticed} s of stall; alarms "
              f"{ {j: alarms(j) for j in others} }")  # fmt: skip
        assert set(noticed) == set(others), {j: alarms(j) for j in others}
        time.sleep(max(0.0, STOP_S - (time.monotonic() - t_stop)))
    finally:
        os.kill(victim.pid, signal.SIGCONT)
    t_cont = time.monotonic()
    took = wait_for(
        lambda: all(lost not in alarms(j) for j in others), 8.0, "agent 1 to rejoin", ev
    )
    print(f"rejoined {took:.2f} s after SIGCONT; alarms { {j: alarms(j) for j in others} }")
    assert victim.poll() is None  # the stalled daemon lives on
    # and the resumed daemon does not think its peers were the silent ones
    wait_for(
        lambda: not any(a.startswith("peer_lost") for a in alarms(VICTIM)),
        max(1.0, 8.0 - (time.monotonic() - t_cont)), "agent 1 without peer_lost alarms", ev,
    )  # fmt: skip
