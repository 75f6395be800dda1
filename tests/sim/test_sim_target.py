"""The simulator as a target (issue 23, defect 7): what any sender can grow is bounded, the
parameters keep their documented ranges, and nothing silences a vehicle's heartbeat.

Before: one parser per UDP source address kept forever (60,000 spoofed sources: 62 -> 210 MB),
every source with one valid packet got all telemetry for 30 s, any finite PARAM_SET was taken
(``COM_OF_LOSS_T = 176`` turned the offboard failsafe off) and SET_MESSAGE_INTERVAL(HEARTBEAT,
-1) made a vehicle fall silent. Real sockets where the defect is about sockets."""

from __future__ import annotations

import math
import socket

import pytest
from pymavlink.dialects.v20 import common

from messages import mavlink as mv
from sim.autopilot.link import (
    MAX_PARSERS,
    MAX_UDP_PEERS,
    NEW_PEERS_BURST,
    Codec,
    LinkCounters,
    UdpLink,
)
from sim.autopilot.params import ardupilot_params, px4_params


def heartbeat(sys_id: int = 250) -> bytes:
    tx = common.MAVLink(None, srcSystem=sys_id, srcComponent=190)
    return common.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(tx)


def test_one_parser_per_source_is_bounded() -> None:
    codec = Codec(common, 1)
    frame = heartbeat()
    for k in range(5 * MAX_PARSERS):  # 320 spoofed source addresses
        assert len(codec.parse(("10.0.0.1", 1000 + k), frame, datagram=True)) == 1
    assert codec.parser_count == MAX_PARSERS
    assert codec.counters.parsers_evicted == 4 * MAX_PARSERS
    assert codec.counters.rx_packets == 5 * MAX_PARSERS  # eviction never loses a packet


class FakeClock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def _spoofers(n: int) -> list[socket.socket]:
    out = []
    for _ in range(n):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        s.settimeout(0.05)
        out.append(s)
    return out


def _drain(link: UdpLink) -> None:
    import selectors

    sel = selectors.DefaultSelector()
    link.register(sel)
    for _ in range(50):
        events = sel.select(0.02)
        if not events:
            break
        for key, mask in events:
            key.data(mask)
    sel.unregister(link.sock)
    link._selector = None


def test_telemetry_goes_to_a_bounded_number_of_new_peers_admitted_at_a_limited_rate() -> None:
    clock = FakeClock()
    counters = LinkCounters()
    codec = Codec(common, 1, counters=counters)
    link = UdpLink(codec, ("127.0.0.1", 0), [], lambda m: None, clock=clock)
    spoofers = _spoofers(3 * MAX_UDP_PEERS)
    try:
        frame = heartbeat()
        for s in spoofers:  # all in the same instant: only the burst gets in
            s.sendto(frame, link.address)
        _drain(link)
        assert len(link.peers) == NEW_PEERS_BURST
        clock.t += 60.0  # the first ones expire (30 s); the bucket refills
        for _round in range(5):  # one second at a time: 2 new peers a second
            for s in spoofers:
                s.sendto(frame, link.address)
            _drain(link)
            clock.t += 1.0
        assert len(link.peers) == MAX_UDP_PEERS
        assert counters.peers_refused > 0
        link.send(common.MAVLink_heartbeat_message(2, 12, 0, 0, 3, 3))
        got = 0
        for s in spoofers:
            try:
                s.recv(512)
                got += 1
            except TimeoutError:
                pass
        assert got == MAX_UDP_PEERS  # not 24: the rest get nothing
    finally:
        link.close()
        for s in spoofers:
            s.close()


@pytest.mark.parametrize(
    ("name", "value", "flavour"),
    [
        ("COM_OF_LOSS_T", 176.0, "px4"),  # the offboard failsafe that never fires
        ("MIS_TAKEOFF_ALT", -0.0, "px4"),
        ("MIS_TAKEOFF_ALT", 0.0, "px4"),
        ("MPC_XY_CRUISE", 1e9, "px4"),
        ("GUID_TIMEOUT", -3989.0, "ardupilot"),
        ("RTL_ALT", 1e12, "ardupilot"),
    ],
)
def test_a_param_set_outside_its_range_is_refused_with_param_value_and_text(
    bench_factory, name: str, value: float, flavour: str
) -> None:
    b = bench_factory(flavour, n=1)
    before = b.aps[0].params.get(name)
    b.outbox[0].clear()
    b.deliver(0, b.dialect.MAVLink_param_set_message(1, 1, name.encode(), value, 9))
    assert b.aps[0].params.get(name) == before
    echo = b.sent(0, "PARAM_VALUE")
    assert len(echo) == 1 and echo[0].param_value == pytest.approx(before)
    assert any(name in t and "out of range" in t for t in b.texts(0)), b.texts(0)
    assert b.aps[0].counters.params_refused == 1


def test_in_range_param_sets_still_apply_and_every_default_is_in_range() -> None:
    for table in (px4_params(1), ardupilot_params(1)):
        for _, p in table.items():
            assert p.accepts(p.value) and p.lo <= p.hi
            assert math.isfinite(p.lo) or p.param_type != 9 or p.name == "ARMING_CHECK"
    t = px4_params(1)
    assert t.set_from_wire("COM_OF_LOSS_T", 60.0, 9) is not None
    assert t.set_from_wire("COM_OF_LOSS_T", 60.5, 9) is None
    assert t.set_from_wire("MIS_TAKEOFF_ALT", 0.5, 9) is not None


def test_heartbeat_cannot_be_stopped_or_slowed(bench_factory) -> None:
    b = bench_factory("px4", n=1)
    for interval_us in (-1, 10_000_000):
        assert b.command(0, mv.CMD_SET_MESSAGE_INTERVAL, 0, interval_us) == mv.RESULT_DENIED
    assert b.aps[0].counters.intervals_refused == 2
    assert b.command(0, mv.CMD_SET_MESSAGE_INTERVAL, 0, 500_000) == mv.RESULT_ACCEPTED  # 2 Hz
    assert b.command(0, mv.CMD_SET_MESSAGE_INTERVAL, 0, 0) == mv.RESULT_ACCEPTED
    b.outbox[0].clear()
    b.run(5.0)
    assert len(b.sent(0, "HEARTBEAT")) >= 4  # still about 1 Hz
    assert b.command(0, mv.CMD_SET_MESSAGE_INTERVAL, 32, 1) == mv.RESULT_ACCEPTED  # 1 us
    b.outbox[0].clear()
    b.run(1.0)
    assert len(b.sent(0, "LOCAL_POSITION_NED")) <= 101  # clamped to 100 Hz
