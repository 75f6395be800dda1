"""A secured simulator over real UDP sockets: unsigned, wrongly signed and replayed commands
change nothing and are counted; pymavlink 2.4.50's two holes stay closed (issue 24)."""

from __future__ import annotations

import hashlib
import socket
import time

from pymavlink.dialects.v20 import common

from messages.mavsign import TIMESTAMP_UNITS_PER_S, sign_outgoing, signing_timestamp
from sim.server import SimConfig, SimServer, free_port_base
from sim.world import grid_layout

KEY = hashlib.sha256(b"vehicle 0 link").digest()
WRONG = hashlib.sha256(b"not the key").digest()
ARM = common.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
DISARM = common.MAVLink_command_long_message(1, 1, 400, 0, 0, 21196, 0, 0, 0, 0, 0)
TEN_YEARS = 10 * 365 * 86400 * TIMESTAMP_UNITS_PER_S


def _server(key: bytes = KEY) -> SimServer:
    base = free_port_base(1, span=60)
    p, yaw = grid_layout(1)
    cfg = SimConfig(p, yaw, flavour="px4", client_base=base, gcs_port=None, signing_key=key)
    return SimServer(cfg).start()


def _wait(pred, timeout: float = 3.0) -> None:
    deadline = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < deadline, "condition not reached"
        time.sleep(0.01)


class Client:
    """A UDP MAVLink sender with its own pymavlink packer (signed with ``key`` if given)."""

    def __init__(self, port: int = 0, key: bytes | None = None, ts: int | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.1)
        self.mav = packer(key, ts)
        self.parser = common.MAVLink(None)

    def frame(self, msg, mav=None) -> bytes:
        mav = mav or self.mav
        buf = bytes(msg.pack(mav))
        mav.seq = (mav.seq + 1) % 256
        return buf

    def send(self, msg, to: tuple[str, int], mav=None) -> bytes:
        buf = self.frame(msg, mav)
        self.sock.sendto(buf, to)
        return buf

    def received(self, seconds: float) -> list:
        out = []
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            try:
                data = self.sock.recv(65535)
            except TimeoutError:
                continue
            out.extend(self.parser.parse_buffer(data) or [])
        return out

    def close(self) -> None:
        self.sock.close()


def packer(key: bytes | None, ts: int | None = None, sysid: int = 245, link_id: int = 0):
    mav = common.MAVLink(None, srcSystem=sysid, srcComponent=190)
    if key is not None:
        sign_outgoing(mav, key, link_id)
        if ts is not None:
            mav.signing.timestamp = ts
    return mav


def _acked(client: Client, msg, to, timeout_s: float = 2.0) -> bool:
    client.send(msg, to)
    return any(m.get_type() == "COMMAND_ACK" and m.result == 0 for m in client.received(timeout_s))


def test_unsigned_wrongly_signed_and_replayed_commands_do_nothing_and_are_counted():
    srv = _server()
    vehicle = ("127.0.0.1", srv.links[0].address[1])
    ap, counters = srv.autopilots[0], srv.autopilots[0].counters
    attacker = Client()
    try:
        attacker.send(ARM, vehicle)  # unsigned
        attacker.send(ARM, vehicle, packer(WRONG))  # signed with another key
        sp = common.MAVLink_set_position_target_local_ned_message(
            0, 1, 1, 8, 1479, 0, 0, 0, 1.0, 0, 0, 0, 0, 0, 0, 0.3
        )
        attacker.send(sp, vehicle)
        attacker.send(common.MAVLink_set_mode_message(1, 1, 6 << 16), vehicle, packer(WRONG))
        _wait(lambda: counters.unsigned_rejected == 2 and counters.bad_signature == 2)
        assert not ap.armed
        legit = Client(key=KEY)
        arm_frame = legit.send(ARM, vehicle)
        _wait(lambda: ap.armed)
        legit.send(DISARM, vehicle)
        _wait(lambda: not ap.armed)
        attacker.sock.sendto(arm_frame, vehicle)  # a captured, correctly signed ARM
        _wait(lambda: counters.replayed == 1)
        time.sleep(0.2)
        assert not ap.armed
        print(f"\ncounters: {counters.as_dict()}")
        legit.close()
    finally:
        attacker.close()
        srv.stop()


def test_forged_far_future_packet_from_the_clients_own_address_does_not_lock_it_out():
    """Hole 1: pymavlink stored the forged timestamp before the HMAC check (0 of 30 commands
    acknowledged in the next 26 s). The forger uses the client's (link id, system, component)
    and the client's own source address (SO_REUSEADDR on the same port stands in for a
    source-spoofing attacker), before and after the client's first packet."""
    srv = _server()
    vehicle = ("127.0.0.1", srv.links[0].address[1])
    counters = srv.autopilots[0].counters
    legit = Client(key=KEY)
    port = legit.sock.getsockname()[1]
    far = signing_timestamp() + TEN_YEARS
    try:
        forged = packer(WRONG, ts=far)  # same link id 0, system 245, component 190
        legit.send(ARM, vehicle, forged)  # before the client's first packet
        _wait(lambda: counters.bad_signature == 1)
        assert _acked(legit, ARM, vehicle)
        spoofer = Client(port=port)  # the client's address
        assert spoofer.sock.getsockname() == legit.sock.getsockname()
        spoofer.send(DISARM, vehicle, forged)
        spoofer.close()
        _wait(lambda: counters.bad_signature == 2)
        acked = sum(_acked(legit, cmd, vehicle, 0.5) for cmd in (DISARM, ARM) * 5)
        print(f"\nacknowledged after the forgeries: {acked}/10, counters {counters.as_dict()}")
        assert acked == 10
    finally:
        legit.close()
        srv.stop()


def test_forged_radio_status_or_heartbeat_gets_no_telemetry():
    """Hole 2: pymavlink passed wrongly signed allow-listed messages, and the sender became a
    peer receiving the signed telemetry stream (263-269 frames in 3 s). An *unsigned*
    RADIO_STATUS is accepted (the allow-list) but does not make a peer either."""
    srv = _server()
    vehicle = ("127.0.0.1", srv.links[0].address[1])
    counters = srv.autopilots[0].counters
    radio = common.MAVLink_radio_status_message(200, 180, 90, 10, 5, 0, 0)
    hb = common.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3)
    forgers = [Client(), Client(), Client()]
    legit = Client(key=KEY)
    try:
        forgers[0].send(radio, vehicle, packer(WRONG))
        forgers[1].send(hb, vehicle, packer(WRONG))
        forgers[2].send(radio, vehicle, packer(None))
        legit.send(hb, vehicle)
        got = [len(f.received(1.5)) for f in forgers]
        print(f"\nframes to the forgers in 1.5 s: {got}; counters {counters.as_dict()}")
        assert got == [0, 0, 0]
        assert counters.bad_signature == 2 and counters.unsigned_allowed == 1
        assert len(legit.received(0.5)) > 10  # the signed sender does get the stream
        assert set(srv.links[0].peers) == {legit.sock.getsockname()}
    finally:
        for c in [*forgers, legit]:
            c.close()
        srv.stop()
