"""A secured team end to end (issue 24): ``bearingflock keys init``, ``[security] dir`` in the
fleet file, the simulator with ``--keys``: the three daemons (separate processes, real UDP
MAVLink, real Zenoh over mutual TLS) arm, take off and fly the mission over signed links.
Two rogue Zenoh peers connect to every endpoint of the team, one over plain TCP and one over
TLS with a certificate from another CA, subscribe to everything and publish ``stop`` to every
vehicle: they receive nothing, have no peer, and the team flies on. An insider with vehicle
2's valid certificate publishes under vehicle 0's keys: the access control of every peer
denies it (a ground-station observer receives none of it, but does receive what the insider
publishes under its own vehicle 2). Meanwhile an
attacker on the link sends unsigned and wrongly signed ARM/DISARM, SET_MODE and setpoints to
every vehicle, including packets with the daemons' own (link id, system, component) and a
far-future timestamp (pymavlink's hole 1): nothing changes, the daemons keep flying, and the
simulator counts every packet."""

from __future__ import annotations

import re
import socket
import time

import pytest
from pymavlink.dialects.v20 import common

from messages import mavlink as mv
from messages.codec import encode
from messages.command import COMMAND_TOPIC, FleetCommand
from messages.fleetkeys import GCS_NAME, identity_files, init_fleet, vehicle_name
from messages.keys import fleet_keys, key
from messages.mavsign import TIMESTAMP_UNITS_PER_S, sign_outgoing, signing_timestamp
from messages.transport import (
    ZenohSettings,
    loopback_endpoint,
    open_session,
    peer_count,
    with_mutual_tls,
)
from messages.zenoh_acl import fleet_access_control

pytestmark = pytest.mark.e2e
N = 3
ROUNDS = 10


def _attack_frames(sysid: int) -> list[bytes]:
    """What the attacker sends to vehicle ``sysid``: 4 commands unsigned and 4 signed with a
    wrong key, the latter as the daemon (245/191, link id 1) with a far-future timestamp."""
    msgs = [
        common.MAVLink_command_long_message(sysid, 1, 400, 0, 0, 21196, 0, 0, 0, 0, 0),  # disarm
        common.MAVLink_set_mode_message(sysid, 1, mv.px4_custom_mode(4, 6)),  # AUTO.LAND
        common.MAVLink_command_long_message(sysid, 1, 21, 0, 0, 0, 0, 0, 0, 0, 0),  # NAV_LAND
        common.MAVLink_set_position_target_local_ned_message(
            0, sysid, 1, 8, 1479, 0, 0, 0, 2.0, 0, -1.0, 0, 0, 0, 0, 0.8
        ),
    ]
    out = []
    plain = common.MAVLink(None, srcSystem=245, srcComponent=191)
    forged = common.MAVLink(None, srcSystem=245, srcComponent=191)
    sign_outgoing(forged, bytes(range(32)), 1)
    forged.signing.timestamp = signing_timestamp() + 10 * 365 * 86400 * TIMESTAMP_UNITS_PER_S
    for mav in (plain, forged):
        for m in msgs:
            out.append(bytes(m.pack(mav)))
            mav.seq = (mav.seq + 1) % 256
    return out


def _rogue_sessions(tmp_path, fleet: str, zenoh_base: int) -> tuple[list, list[int]]:
    """A plain-TCP and an other-CA TLS Zenoh peer connected to the simulator's and every
    daemon's endpoint; each subscribes to the whole fleet and publishes ``stop`` to everyone
    (the sessions stay open while the test runs)."""
    init_fleet(tmp_path / "rogue", "alpha", N)
    endpoints = [loopback_endpoint(zenoh_base + k) for k in range(N + 1)]
    plain = ZenohSettings(connect=endpoints)
    forged = with_mutual_tls(plain, *identity_files(tmp_path / "rogue", GCS_NAME))
    got = [0, 0]
    sessions = []
    for idx, settings in enumerate((plain, forged)):
        try:
            session = open_session(settings)
        except Exception:  # refusing the session outright is fine too
            continue

        def count(_sample, idx=idx) -> None:
            got[idx] += 1

        for i in range(N):  # before subscribing: its own puts would come back to it
            session.put(key(fleet, i, COMMAND_TOPIC),
                        encode(FleetCommand(sender=0, seq=1, stamp_s=time.time(), target=i,
                                            action="stop", request_id=7)))  # fmt: skip
        session.declare_subscriber(fleet_keys(fleet), count)
        sessions.append(session)
    return sessions, got


def _insider(tmp_path, fleet: str, zenoh_base: int) -> tuple[int, int]:
    """Vehicle 2's certificate publishing 20 samples as vehicle 0 and 20 as itself; how many
    of each a ground-station session (same CA, the fleet's ACL) receives."""
    keys = tmp_path / "keys"
    acl = fleet_access_control(fleet, N, "alpha")
    endpoints = [loopback_endpoint(zenoh_base + k) for k in range(N + 1)]
    observer = open_session(
        with_mutual_tls(ZenohSettings(connect=endpoints), *identity_files(keys, GCS_NAME), acl)
    )
    insider = open_session(
        with_mutual_tls(
            ZenohSettings(connect=endpoints), *identity_files(keys, vehicle_name(2)), acl
        )
    )
    got = {"as_0": 0, "as_2": 0}
    try:
        observer.declare_subscriber(
            key(fleet, 0, "peer/insider"), lambda _s: got.__setitem__("as_0", got["as_0"] + 1)
        )
        observer.declare_subscriber(
            key(fleet, 2, "peer/insider"), lambda _s: got.__setitem__("as_2", got["as_2"] + 1)
        )
        deadline = time.monotonic() + 10.0
        while (peer_count(insider) == 0 or peer_count(observer) == 0) and (
            time.monotonic() < deadline
        ):
            time.sleep(0.1)
        time.sleep(1.0)  # the subscriptions reach the insider
        for _ in range(20):
            insider.put(key(fleet, 0, "peer/insider"), b"forged as vehicle 0")
            insider.put(key(fleet, 2, "peer/insider"), b"vehicle 2 as itself")
            time.sleep(0.02)
        time.sleep(1.0)
    finally:
        insider.close()
        observer.close()
    return got["as_0"], got["as_2"]


def _flying(ev) -> bool:
    st = ev.snapshot()
    return len(st) == N and all(
        s.phase == "flying" and s.autopilot_mode == "OFFBOARD" and s.armed and s.in_air
        for s in st.values()
    )


def _vehicle_ports(tmp_path) -> list[int]:
    """The UDP ports the simulator bound for its vehicles, from its start-up lines
    (``vehicle I sysid S: udp 127.0.0.1:PORT -> ...``; the fleet fixture lets the kernel
    choose them, ``--bind-base 0``)."""
    text = (tmp_path / "sim.log").read_text()
    return [int(p) for p in re.findall(r"^vehicle \d+ sysid \d+: udp [\d.]+:(\d+)", text, re.M)]


def test_secured_team_flies_and_ignores_unsigned_and_forged_mavlink(tmp_path, fleet_with, wait_for):
    init_fleet(tmp_path / "keys", "alpha", N)
    with fleet_with(tmp_path, keys=tmp_path / "keys") as fleet:
        ev, _procs, ports, _agent_args, name = fleet
        took = wait_for(lambda: _flying(ev), 90.0, "every daemon flying over signed links", ev)
        rogues, rogue_got = _rogue_sessions(tmp_path, name, ports.zenoh)
        bind = _vehicle_ports(tmp_path)  # the simulator's vehicle sockets (kernel-chosen)
        assert len(bind) == N
        sent = 0
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for _ in range(ROUNDS):
                for i in range(N):
                    for frame in _attack_frames(i + 1):
                        s.sendto(frame, ("127.0.0.1", bind[i]))
                        sent += 1
                time.sleep(0.1)
            t_end = time.monotonic() + 5.0
            while time.monotonic() < t_end:  # the whole time: still flying the mission
                assert _flying(ev), {
                    k: (v.phase, v.autopilot_mode) for k, v in ev.snapshot().items()
                }
                try:  # and the attacker is no peer: nothing comes back
                    s.settimeout(0.1)
                    data = s.recv(65535)
                    raise AssertionError(f"the attacker got {len(data)} bytes")
                except TimeoutError:
                    pass
        as_0, as_2 = _insider(tmp_path, name, ports.zenoh)
        rogue_peers = [peer_count(r) for r in rogues]
        for r in rogues:
            r.close()
        assert ev.session is not None and peer_count(ev.session) >= N  # the evaluator's TLS works
        statuses = ev.snapshot()
        link_bad = {k: {r: n for r, n in v.dropped.items() if r.startswith("mavlink_")}
                    for k, v in statuses.items()}  # fmt: skip
    log = (tmp_path / "sim.log").read_text()
    counts = {k: int(v) for k, v in re.findall(r"(\w+)=(\d+)", log.splitlines()[-1])}
    print(
        f"\nflying after {took:.1f} s; attack packets sent {sent}; simulator counters "
        f"unsigned_rejected={counts.get('unsigned_rejected', 0)} "
        f"bad_signature={counts.get('bad_signature', 0)} signed_ok={counts.get('signed_ok', 0)}; "
        f"daemon link counters {link_bad}; rogue Zenoh peers (tcp, other CA): "
        f"{rogue_peers} peers, {rogue_got} samples received; insider with vehicle 2's "
        f"certificate: {as_0}/20 received as vehicle 0, {as_2}/20 as itself"
    )
    assert as_0 == 0 and as_2 == 20
    assert rogue_peers == [0, 0] and rogue_got == [0, 0]
    assert counts.get("unsigned_rejected", 0) == sent // 2
    assert counts.get("bad_signature", 0) == sent // 2
    assert counts.get("replayed", 0) == 0
    # every message the vehicles acted on was correctly signed (the daemons' own)
    assert counts["signed_ok"] == counts["rx_packets"] > 0
    assert link_bad == {i: {} for i in range(N)}  # nothing forged reached the daemons either
    for i in range(N):  # each daemon's link counted what it verified
        ok = re.findall(r"mavlink signing: (\d+) signed_ok, 0 bad_signature",
                        (tmp_path / f"agent{i}.log").read_text())  # fmt: skip
        assert ok and int(ok[-1]) > 100, i
