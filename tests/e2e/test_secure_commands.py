"""Issue 25's command topics in a secured fleet (issue 24: ``bearingflock keys init``, mutual
TLS, the fleet's access control; messages/zenoh_acl.py, docs/flying.md "Securing the links"):
one flying team (the simulator with ``--keys`` and three daemons as processes, real UDP MAVLink,
real Zenoh over TLS) and, in turn:

* the ground station (its own certificate, ``--keys``) sends ``gcs formation --leader 0`` and
  ``gcs leader 0 --velocity``: every daemon's status shows the formation, the leader's the drive;
* an insider with vehicle 2's valid certificate puts a FormationChange and a LeaderDrive on
  vehicle 0's ``command/formation`` and ``command/leader``: the access control denies them, so
  daemon 0 neither adopts them nor even counts them (they never reach its decoder), while the
  same insider's change on vehicle 2's own key (its own subtree, allowed) is adopted by daemon 2:
  the insider's session works, the rule is what stops it;
* a rogue with a certificate from another CA (the same common names) runs `gcs formation`: it
  has no peer, sees no status and exits 1; nobody adopts its formation."""

from __future__ import annotations

import json
import time

import pytest

from messages.codec import encode
from messages.command import (
    FORMATION_TOPIC,
    LEADER_TOPIC,
    FormationChange,
    FormationSlot,
    LeaderDrive,
)
from messages.fleetkeys import GCS_NAME, identity_files, init_fleet, vehicle_name
from messages.keys import key
from messages.transport import (
    ZenohSettings,
    loopback_endpoint,
    open_session,
    peer_count,
    with_mutual_tls,
)
from messages.zenoh_acl import fleet_access_control
from tests.e2e.test_gcs_formation import gcs
from tests.e2e.test_gcs_scale_leader import _formation_file, _links
from tests.e2e.test_secure_fleet import N, _flying

pytestmark = pytest.mark.e2e


def _commands_dropped(status) -> dict[str, int]:
    return {k: n for k, n in status.dropped.items() if k.startswith("command_")}


def _session(keys, name: str, fleet: str, zenoh_base: int, acl: bool = True):
    endpoints = [loopback_endpoint(zenoh_base + k) for k in range(N + 1)]
    rules = (fleet_access_control(fleet, N, "alpha"),) if acl else ()
    return open_session(
        with_mutual_tls(ZenohSettings(connect=endpoints), *identity_files(keys, name), *rules)
    )


def _wait_peers(session, timeout_s: float = 10.0) -> int:
    deadline = time.monotonic() + timeout_s
    while peer_count(session) == 0 and time.monotonic() < deadline:
        time.sleep(0.1)
    return peer_count(session)


def test_the_ground_station_commands_a_secured_team_and_an_insider_or_a_rogue_cannot(
    tmp_path, fleet_with, wait_for
):
    keys = tmp_path / "keys"
    init_fleet(keys, "alpha", N)
    init_fleet(tmp_path / "rogue", "alpha", N)  # another CA, the same common names
    with fleet_with(tmp_path, keys=keys) as fleet:
        ev, _procs, ports, _agent_args, name = fleet
        took = wait_for(lambda: _flying(ev), 90.0, "every daemon flying over signed links", ev)
        plan = ev.plan
        ring = _formation_file(tmp_path / "ring.toml", plan.p_ned, plan.yaw_rad, "ring")
        secure = [*_links(ports, name), "--keys", str(keys)]

        # the ground station, with its certificate: accepted
        out = gcs("formation", str(ring), "--leader", "0", "--id", "81", "--yes", "--json",
                  *secure)  # fmt: skip
        assert out.returncode == 0, out.stdout + out.stderr
        assert all(r["ok"] for r in json.loads(out.stdout)["results"])
        assert all(s.formation_id == 81 and s.formation_leader == 0
                   for s in ev.snapshot().values())  # fmt: skip
        out = gcs("leader", "0", "--velocity", "0.1,0,0", "--duration", "2", "--id", "82",
                  "--yes", "--json", *secure)  # fmt: skip
        assert out.returncode == 0 and json.loads(out.stdout)["ok"], out.stdout + out.stderr
        assert ev.snapshot()[0].leader_drive_id == 82
        before = _commands_dropped(ev.snapshot()[0])

        # vehicle 2's certificate on vehicle 0's command keys, and on its own
        insider = _session(keys, vehicle_name(2), name, ports.zenoh)
        try:
            insider_peers = _wait_peers(insider)
            slots = [
                FormationSlot(id=k, position_ned=tuple(float(x) for x in plan.p_ned[k]),
                              yaw_rad=float(plan.yaw_rad[k]))
                for k in range(N)
            ]  # fmt: skip
            forged = FormationChange(sender=0, target=0, formation_id=93, agents=slots,
                                     name="forged", leader=2)  # fmt: skip
            drive = LeaderDrive(sender=0, target=0, drive_id=94, velocity_ned=(1.0, 0.0, 0.0),
                                duration_s=5.0)  # fmt: skip
            own = FormationChange(sender=0, target=2, formation_id=95, agents=slots,
                                  name="own", leader=0)  # fmt: skip
            t_end = time.monotonic() + 3.0
            while time.monotonic() < t_end:  # as the ground station repeats, every 0.1 s
                insider.put(key(name, 0, FORMATION_TOPIC), encode(forged))
                insider.put(key(name, 0, LEADER_TOPIC), encode(drive))
                insider.put(key(name, 2, FORMATION_TOPIC), encode(own))
                time.sleep(0.1)
            took_own = wait_for(lambda: ev.snapshot()[2].formation_id == 95, 5.0,
                                "daemon 2 adopting the insider's change on its own key", ev)  # fmt: skip
        finally:
            insider.close()
        time.sleep(1.0)
        s0 = ev.snapshot()[0]
        after = _commands_dropped(s0)

        # a foreign CA: no peer, no status, nothing adopted
        rogue = _session(tmp_path / "rogue", GCS_NAME, name, ports.zenoh, acl=False)
        try:
            time.sleep(2.0)
            rogue_peers = peer_count(rogue)
            rogue.put(key(name, 0, FORMATION_TOPIC), encode(forged))
        finally:
            rogue.close()
        out_rogue = gcs("formation", str(ring), "--leader", "1", "--id", "96", "--yes",
                        "--timeout", "3", "--json", *_links(ports, name),
                        "--keys", str(tmp_path / "rogue"))  # fmt: skip
        time.sleep(1.0)
        final = ev.snapshot()
    print(
        f"\nflying after {took:.1f} s; ground station: formation 81 and drive 82 acknowledged; "
        f"insider (vehicle 2's certificate, {insider_peers} peers): daemon 0 flies formation "
        f"{s0.formation_id} drive {s0.leader_drive_id} (forged 93/94), command drops "
        f"{before} -> {after}; its own-key change adopted by daemon 2 after {took_own:.1f} s; "
        f"rogue CA: {rogue_peers} peers, gcs formation exit {out_rogue.returncode} "
        f"({out_rogue.stdout.strip()[:160]}); formations {[final[k].formation_id for k in range(N)]}"
    )
    assert insider_peers > 0  # the insider is in the fleet ...
    assert (s0.formation_id, s0.formation_leader, s0.leader_drive_id) == (81, 0, 82)  # ... denied
    assert after == before  # denied by the access control, before the daemon's decoder
    assert rogue_peers == 0
    assert out_rogue.returncode == 1, out_rogue.stdout + out_rogue.stderr
    assert [final[k].formation_id for k in range(N)] == [81, 81, 95]
    assert final[0].leader_drive_id == 82
