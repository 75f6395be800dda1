"""The secured fleet's Zenoh access control (messages/zenoh_acl.py; docs/flying.md, "Securing
the links") evaluated on the keys it is about: who may *put* what, by the rules' key
expressions (Zenoh's ``*``: one chunk, ``**``: any number). The ground station puts fleet
commands, formation changes and leader drives (issue 25's ``command/formation`` and
``command/leader``) to every vehicle; a vehicle puts only under its own id; the simulator puts
its clock, cameras and truth; nobody else puts anything."""

from __future__ import annotations

import pytest

from messages.command import COMMAND_TOPIC, FORMATION_TOPIC, LEADER_TOPIC
from messages.keys import key, peer_key
from messages.zenoh_acl import fleet_access_control

FLEET, N = "t1", 3
COMMANDS = (COMMAND_TOPIC, FORMATION_TOPIC, LEADER_TOPIC)


def _matches(expr: str, k: str) -> bool:
    """Zenoh key-expression matching of a concrete key (no wildcards in ``k``)."""

    def match(e: list[str], c: list[str]) -> bool:
        if not e:
            return not c
        if e[0] == "**":
            return any(match(e[1:], c[i:]) for i in range(len(c) + 1))
        return bool(c) and (e[0] in ("*", c[0])) and match(e[1:], c[1:])

    return match(expr.split("/"), k.split("/"))


def _may_put(common_name: str, k: str) -> bool:
    acl = fleet_access_control(FLEET, N, "alpha")["access_control"]
    subjects = {s["id"] for s in acl["subjects"] if common_name in s["cert_common_names"]}
    rules = {r["id"]: r for r in acl["rules"]}
    for policy in acl["policies"]:
        if not subjects & set(policy["subjects"]):
            continue
        for rid in policy["rules"]:
            r = rules[rid]
            if ("put" in r["messages"] and "ingress" in r["flows"] and r["permission"] == "allow"
                    and any(_matches(e, k) for e in r["key_exprs"])):  # fmt: skip
                return True
    return acl["default_permission"] == "allow"


def test_the_matcher_is_zenohs():
    assert _matches("bf/t1/*/command", "bf/t1/2/command")
    assert not _matches("bf/t1/*/command", "bf/t1/2/command/formation")
    assert _matches("bf/t1/2/**", "bf/t1/2/command/leader")
    assert not _matches("bf/t1/2/**", "bf/t1/20/status")


@pytest.mark.parametrize("topic", COMMANDS)
def test_the_ground_station_commands_every_vehicle(topic):
    for i in range(N):
        assert _may_put("alpha-gcs", key(FLEET, i, topic)), (i, topic)
    assert not _may_put("alpha-gcs", key(FLEET, 0, "status"))  # it is no vehicle
    assert not _may_put("alpha-gcs", peer_key(FLEET, 0))


@pytest.mark.parametrize("topic", COMMANDS)
def test_a_vehicle_commands_no_other_vehicle(topic):
    """Vehicle 2's certificate (an insider) on vehicle 0's command keys: denied."""
    for j in range(N):
        for i in range(N):
            if i != j:
                assert not _may_put(f"alpha-vehicle-{j}", key(FLEET, i, topic)), (j, i, topic)
    # under its own id everything is its own (the daemon's own keys; its own command topics
    # included: a vehicle's certificate already controls that vehicle's daemon)
    assert _may_put("alpha-vehicle-2", key(FLEET, 2, topic))


@pytest.mark.parametrize("topic", COMMANDS)
def test_the_simulator_and_strangers_command_nobody(topic):
    for name in ("alpha-sim", "beta-gcs", "alpha-vehicle-3", "alpha-gcs-2", ""):
        assert not any(_may_put(name, key(FLEET, i, topic)) for i in range(N)), (name, topic)


def test_vehicles_publish_their_own_payloads_only():
    assert _may_put("alpha-vehicle-1", peer_key(FLEET, 1))
    assert _may_put("alpha-vehicle-1", key(FLEET, 1, "status"))
    assert not _may_put("alpha-vehicle-1", peer_key(FLEET, 0))
    assert _may_put("alpha-sim", f"bf/{FLEET}/sim/clock")
    assert not _may_put("alpha-vehicle-1", f"bf/{FLEET}/sim/clock")
