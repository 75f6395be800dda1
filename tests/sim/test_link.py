"""The socket side: bad input is counted and never crashes the simulator; signing; TCP."""

from __future__ import annotations

import hashlib
import socket
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega, common

from sim.autopilot.signing import enable_signing, is_signed
from sim.server import SimConfig, SimServer
from sim.world import grid_layout

_HELD: list[socket.socket] = []
"""Client sockets bound for vehicles 1.. that no test reads (closed with the next server)."""


def _client_sockets(n: int, tries: int = 100) -> list[socket.socket]:
    """``n`` UDP sockets on consecutive loopback ports, the first one the kernel's choice: bound
    (held) before the simulator starts, so no other process can take them in between (a range
    checked free and bound later could be taken meanwhile, issue 23 defect 13)."""
    for _ in range(tries):
        first = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        first.bind(("127.0.0.1", 0))
        socks = [first]
        try:
            for k in range(1, n):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                socks.append(s)
                s.bind(("127.0.0.1", first.getsockname()[1] + k))
            return socks
        except OSError:
            for s in socks:
                s.close()
    raise RuntimeError(f"no {n} consecutive free UDP ports")


def _server(flavour: str = "px4", n: int = 2, **kw) -> tuple[SimServer, socket.socket]:
    """A started simulator on ports the kernel chose (its own UDP ports, TCP servers), sending
    to client sockets the test holds; returns it and vehicle 0's client socket."""
    for s in _HELD:
        s.close()
    socks = _client_sockets(n)
    _HELD[:] = socks[1:]
    p, yaw = grid_layout(n)
    base = socks[0].getsockname()[1]
    cfg = SimConfig(
        p, yaw, flavour=flavour, client_base=base, gcs_port=None, bind_base=0, tcp_base=0, **kw
    )
    return SimServer(cfg).start(), socks[0]


def _wait(pred, timeout: float = 3.0) -> None:
    deadline = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < deadline, "condition not reached"
        time.sleep(0.01)


class UdpClient:
    def __init__(self, sock: socket.socket, dialect=common, sysid: int = 245) -> None:
        self.sock = sock  # bound already (:func:`_client_sockets`)
        self.sock.settimeout(0.2)
        self.mav = dialect.MAVLink(None, srcSystem=sysid, srcComponent=190)
        self.parser = dialect.MAVLink(None)
        self.peer: tuple[str, int] | None = None

    def recv_until(self, kind: str, timeout: float = 3.0, pred=lambda m: True):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                data, addr = self.sock.recvfrom(65535)
            except TimeoutError:
                continue
            self.peer = addr
            for m in self.parser.parse_buffer(data) or []:
                if m.get_type() == kind and pred(m):
                    return m
        raise AssertionError(f"no {kind}")

    def raw(self, data: bytes) -> None:
        assert self.peer is not None
        self.sock.sendto(data, self.peer)

    def send(self, msg) -> bytes:
        buf = bytes(msg.pack(self.mav))
        self.mav.seq = (self.mav.seq + 1) % 256
        self.raw(buf)
        return buf

    def close(self) -> None:
        self.sock.close()


def test_garbage_bad_crc_unknown_ids_are_counted_and_survived():
    srv, sock = _server("px4", n=1)
    c = UdpClient(sock)
    try:
        c.recv_until("HEARTBEAT")
        counters = srv.autopilots[0].counters
        c.raw(b"\x00\x01hello world, not mavlink\x02" * 3)
        good = bytearray(
            common.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(c.mav)
        )
        good[-1] ^= 0xFF  # break the CRC
        c.raw(bytes(good))
        # a frame with a message id nobody knows (0xABCDE), valid framing
        c.raw(bytes([0xFD, 1, 0, 0, 7, 245, 190, 0xDE, 0xBC, 0x0A, 0x55, 0x12, 0x34]))
        c.raw(b"\xfd\xff")  # truncated header
        _wait(lambda: counters.bad_crc >= 1 and counters.unknown_ids >= 1)
        assert counters.garbage_bytes >= 3 * 26
        assert not srv.autopilots[0].armed  # the corrupted ARM did nothing
        # still alive and serving
        c.send(common.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))
        ack = c.recv_until("COMMAND_ACK")
        assert ack.command == 400 and ack.result == 0
        assert srv.autopilots[0].armed
        assert srv.counters()["rx_packets"] >= 1
    finally:
        c.close()
        srv.stop()


def test_commands_for_other_systems_are_ignored_on_the_wire():
    srv, sock = _server("px4", n=2)
    c0 = UdpClient(sock)
    try:
        c0.recv_until("HEARTBEAT")
        c0.send(common.MAVLink_command_long_message(2, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))
        _wait(lambda: srv.autopilots[0].counters.foreign_target == 1)
        assert not srv.autopilots[0].armed and not srv.autopilots[1].armed
    finally:
        c0.close()
        srv.stop()


def test_replies_go_to_the_sender_address_too():
    srv, sock = _server("px4", n=1)
    listener = UdpClient(sock)
    other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    other.bind(("127.0.0.1", 0))
    other.settimeout(0.2)
    try:
        listener.recv_until("HEARTBEAT")
        mav = common.MAVLink(None, srcSystem=250, srcComponent=1)
        other.sendto(
            bytes(common.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(mav)), listener.peer
        )
        parser = common.MAVLink(None)
        deadline = time.monotonic() + 3.0
        got = False
        while time.monotonic() < deadline and not got:
            try:
                data = other.recv(65535)
            except TimeoutError:
                continue
            got = any(m.get_type() == "HEARTBEAT" for m in parser.parse_buffer(data) or [])
        assert got
    finally:
        other.close()
        listener.close()
        srv.stop()


def test_signing_rejects_unsigned_and_wrongly_signed_commands():
    key = hashlib.sha256(b"correct horse").digest()
    srv, sock = _server("px4", n=1, signing_key=key)
    c = UdpClient(sock)
    try:
        hb = c.recv_until("HEARTBEAT")
        assert is_signed(hb.get_msgbuf())  # the vehicle signs what it sends
        counters = srv.autopilots[0].counters
        arm = common.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
        c.send(arm)  # unsigned
        _wait(lambda: counters.unsigned_rejected == 1)
        wrong = common.MAVLink(None, srcSystem=245, srcComponent=190)
        enable_signing(wrong, hashlib.sha256(b"wrong").digest())
        c.raw(bytes(arm.pack(wrong)))
        _wait(lambda: counters.bad_signature == 1)
        assert not srv.autopilots[0].armed
        enable_signing(c.mav, key)
        c.send(arm)
        ack = c.recv_until("COMMAND_ACK")
        assert ack.result == 0 and srv.autopilots[0].armed
        c.mav = common.MAVLink(None, srcSystem=245, srcComponent=190)  # unsigned again
        c.send(common.MAVLink_radio_status_message(200, 180, 90, 10, 5, 0, 0))  # allow-listed
        c.send(common.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3))  # not (PX4's list)
        _wait(lambda: counters.unsigned_allowed == 1 and counters.unsigned_rejected == 2)
    finally:
        c.close()
        srv.stop()


def test_tcp_link_serves_several_clients():
    srv, _sock = _server("ardupilot", n=2, transport="tcp")
    try:
        clients = [socket.create_connection(srv.links[1].address) for _ in range(2)]
        for s in clients:
            s.settimeout(3.0)
            parser = ardupilotmega.MAVLink(None)
            seen = set()
            deadline = time.monotonic() + 3.0
            while "HEARTBEAT" not in seen and time.monotonic() < deadline:
                for m in parser.parse_buffer(s.recv(65535)) or []:
                    seen.add(m.get_type())
                    if m.get_type() == "HEARTBEAT":
                        assert m.get_srcSystem() == 2
            assert "HEARTBEAT" in seen
        clients[0].close()  # a client leaving does not disturb the other
        mav = ardupilotmega.MAVLink(None, srcSystem=255, srcComponent=190)
        clients[1].sendall(
            bytes(
                ardupilotmega.MAVLink_command_long_message(2, 1, 176, 0, 1, 4, 0, 0, 0, 0, 0).pack(
                    mav
                )
            )
        )
        _wait(lambda: srv.autopilots[1].mode == "GUIDED")
        clients[1].close()
    finally:
        srv.stop()


def test_port_in_use_is_a_clear_error():
    srv, sock = _server("px4", n=1)
    try:
        p, yaw = grid_layout(1)
        taken = srv.links[0].address[1]  # the first simulator's own port
        with pytest.raises(OSError):
            SimServer(
                SimConfig(p, yaw, client_base=sock.getsockname()[1], gcs_port=None, bind_base=taken)
            )
    finally:
        srv.stop()
