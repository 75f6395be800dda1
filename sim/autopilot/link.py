"""MAVLink 2 over plain sockets: framing, counters, and one UDP or TCP link per vehicle.

* :class:`Codec` packs outgoing messages with one pymavlink ``MAVLink`` object (sequence
  numbers, optional signing) and parses incoming bytes with one parser per peer, classifying
  everything that is not a valid message into :class:`LinkCounters` instead of raising.
* :class:`UdpLink` — PX4 style: one socket, sends to fixed destinations (14540+i, 14550)
  and to the addresses valid packets came from (at most :data:`MAX_UDP_PEERS`, admitted at
  most :data:`NEW_PEERS_PER_S` a second).
* :class:`TcpLink` — ArduPilot SITL style: a TCP server; every accepted connection is a peer
  (at most :data:`MAX_TCP_CONNS`).

Every table a sender can grow is bounded (issue 23): parsers (:data:`MAX_PARSERS`, least
recently used evicted), UDP peers, TCP connections; running out of file descriptors in
``accept`` closes the newcomer instead of ending the loop.

Links are non-blocking and are driven by the server's ``selectors`` loop: they register their
sockets with a callback and never block.
"""

from __future__ import annotations

import errno
import os
import selectors
import socket
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, fields
from types import ModuleType
from typing import Any

from messages.mavsign import SignatureVerifier, Verdict, keep_timestamp_current
from sim.autopilot.signing import enable_signing

PEER_TIMEOUT_S = 30.0
"""A learned UDP peer that stays silent this long (wall time) is no longer sent to."""
MAX_TCP_BACKLOG_BYTES = 1 << 20
MAX_PARSERS = 64
"""Per-sender parsers kept per vehicle; the least recently used goes first. A UDP parser holds
nothing between datagrams (a partial frame is dropped), so evicting one loses nothing."""
MAX_UDP_PEERS = 8
"""Learned UDP addresses that receive telemetry, per vehicle, besides the fixed destinations
(a real PX4 link answers one address; 8 covers a GCS, an API client and tools)."""
NEW_PEERS_PER_S = 2.0
"""Rate at which new UDP peers are admitted (token bucket, burst :data:`NEW_PEERS_BURST`)."""
NEW_PEERS_BURST = 4.0
MAX_TCP_CONNS = 16
"""Simultaneous TCP connections per vehicle; a further one is accepted and closed at once."""


@dataclass
class LinkCounters:
    """What arrived and what was wrong with it (never raises, always counts)."""

    rx_bytes: int = 0
    rx_packets: int = 0
    tx_packets: int = 0
    tx_errors: int = 0
    garbage_bytes: int = 0
    bad_crc: int = 0
    malformed: int = 0
    unknown_ids: int = 0
    unsigned_rejected: int = 0
    """With signing on: unsigned messages not on the allow-list (dropped)."""
    bad_signature: int = 0
    """With signing on: signed with another key, or altered (dropped before anything else)."""
    replayed: int = 0
    """With signing on: correct signature, timestamp not ahead of the stream's (dropped)."""
    signed_ok: int = 0
    unsigned_allowed: int = 0
    """With signing on: unsigned RADIO_STATUS, ADSB_VEHICLE, COLLISION (accepted)."""
    foreign_target: int = 0
    nan_setpoints: int = 0
    ignored_setpoints: int = 0
    nan_commands: int = 0
    """Commands refused for a NaN where the real autopilot would crash (ArduCopter aborts on a
    NaN it converts to an integer or compares, e.g. ARM_DISARM's param 2)."""
    params_refused: int = 0
    """PARAM_SETs refused: wrong type, non-finite, or outside the documented range."""
    peers_refused: int = 0
    """UDP senders not made telemetry peers: the peer table was full or new peers came in
    faster than :data:`NEW_PEERS_PER_S`."""
    parsers_evicted: int = 0
    """Per-sender parsers dropped, least recently used first (:data:`MAX_PARSERS`)."""
    tcp_refused: int = 0
    """TCP connections closed at once: :data:`MAX_TCP_CONNS` reached, or out of descriptors."""
    intervals_refused: int = 0
    """SET_MESSAGE_INTERVAL requests that would stop the HEARTBEAT (refused, DENIED)."""

    def as_dict(self) -> dict[str, int]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


class _Sink:
    """pymavlink wants a file; we pack with it and send ourselves."""

    def write(self, _buf: bytes) -> None:  # pragma: no cover - never called
        pass


class Codec:
    """Pack and parse MAVLink 2 for one vehicle (system ``sys_id``, component 1).

    With a signing key, one :class:`~messages.mavsign.SignatureVerifier` per vehicle (shared
    by all its peers) decides on every parsed message; pymavlink's own check is never used.
    """

    def __init__(
        self,
        dialect: ModuleType,
        sys_id: int,
        comp_id: int = 1,
        signing_key: bytes | None = None,
        counters: LinkCounters | None = None,
    ) -> None:
        self.dialect = dialect
        self.counters = counters if counters is not None else LinkCounters()
        self.signing_key = signing_key
        self._tx = dialect.MAVLink(_Sink(), srcSystem=sys_id, srcComponent=comp_id)
        self.verifier: SignatureVerifier | None = None
        if signing_key is not None:
            enable_signing(self._tx, signing_key)
            self.verifier = SignatureVerifier(signing_key)
        self._parsers: OrderedDict[Any, Any] = OrderedDict()
        self.authenticated = False
        """Whether the last :meth:`parse` returned a correctly signed message (or, without
        signing, any valid one): only such a sender may become a peer."""

    def pack(self, msg: Any) -> bytes:
        """Serialize ``msg`` with this vehicle's identity and next sequence number."""
        if self.verifier is not None:
            keep_timestamp_current(self._tx)
        buf = msg.pack(self._tx)
        self._tx.seq = (self._tx.seq + 1) % 256
        self.counters.tx_packets += 1
        return bytes(buf)

    def _parser(self, peer: Any) -> Any:
        p = self._parsers.get(peer)
        if p is None:
            # no key on the parser: it passes signed frames unchecked, the verifier decides
            p = self.dialect.MAVLink(_Sink(), srcSystem=self._tx.srcSystem, srcComponent=1)
            p.robust_parsing = True
            self._parsers[peer] = p
            while len(self._parsers) > MAX_PARSERS:
                self._parsers.popitem(last=False)
                self.counters.parsers_evicted += 1
        else:
            self._parsers.move_to_end(peer)
        return p

    @property
    def parser_count(self) -> int:
        return len(self._parsers)

    def forget(self, peer: Any) -> None:
        self._parsers.pop(peer, None)

    def parse(self, peer: Any, data: bytes, datagram: bool) -> list[Any]:
        """Valid messages in ``data`` from ``peer``; everything else is counted and dropped.

        For a ``datagram`` (UDP) an incomplete trailing frame cannot be completed by a later
        packet, so it is counted as garbage and the parser is reset.
        """
        c = self.counters
        c.rx_bytes += len(data)
        self.authenticated = False
        p = self._parser(peer)
        try:
            msgs = p.parse_buffer(data) or []
        except Exception:  # pymavlink should not raise in robust mode; never let it crash us
            msgs = []
            c.malformed += 1
            self._reset(p)
        good = []
        for m in msgs:
            kind = m.get_type()
            if kind == "BAD_DATA":
                self._count_bad(m)
            elif kind.startswith("UNKNOWN_"):
                c.unknown_ids += 1
            elif self._verified(m):
                c.rx_packets += 1
                good.append(m)
        if datagram and p.buf_len() > 0:
            c.garbage_bytes += p.buf_len()
            self._reset(p)
        return good

    def _verified(self, m: Any) -> bool:
        if self.verifier is None:
            self.authenticated = True
            return True
        verdict = self.verifier.check_message(m)
        c = self.counters
        if verdict is Verdict.GOOD:
            c.signed_ok += 1
            self.authenticated = True
        elif verdict is Verdict.ALLOWED_UNSIGNED:
            c.unsigned_allowed += 1
        elif verdict is Verdict.UNSIGNED:
            c.unsigned_rejected += 1
        elif verdict is Verdict.BAD_SIGNATURE:
            c.bad_signature += 1
        else:
            c.replayed += 1
        return verdict.accepted

    def _count_bad(self, m: Any) -> None:
        c = self.counters
        reason = str(getattr(m, "reason", ""))
        if reason.startswith("Bad prefix"):
            c.garbage_bytes += len(m.data)
        elif "CRC" in reason:
            c.bad_crc += 1
        else:
            c.malformed += 1

    @staticmethod
    def _reset(p: Any) -> None:
        p.buf = bytearray()
        p.buf_index = 0
        p.expected_length = 8  # HEADER_LEN_V1 + 2: wait for a new header
        p.have_prefix_error = False


Handler = Callable[[Any], None]
"""Called with each valid message a link receives."""


class UdpLink:
    """One UDP socket: sends to fixed destinations and to every peer heard from."""

    def __init__(
        self,
        codec: Codec,
        bind: tuple[str, int],
        destinations: list[tuple[str, int]],
        on_message: Handler,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.codec = codec
        self.on_message = on_message
        self._clock = clock
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 0)
        self.sock.bind(bind)
        self.sock.setblocking(False)
        self.fixed = list(dict.fromkeys(tuple(d) for d in destinations))  # no duplicates
        self.peers: dict[tuple[str, int], float] = {}
        self._tokens = NEW_PEERS_BURST
        self._tokens_t = clock()
        self._selector: selectors.BaseSelector | None = None

    @property
    def address(self) -> tuple[str, int]:
        return self.sock.getsockname()

    def describe(self) -> str:
        host, port = self.address
        outs = ", ".join(f"{h}:{p}" for h, p in self.fixed)
        return f"udp {host}:{port} -> {outs}"

    def register(self, sel: selectors.BaseSelector) -> None:
        self._selector = sel
        sel.register(self.sock, selectors.EVENT_READ, self._on_readable)

    def _on_readable(self, _mask: int) -> None:
        for _ in range(256):  # bounded: never starve the clock
            try:
                data, addr = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # e.g. ICMP port unreachable reported on a later recv
                continue
            msgs = self.codec.parse(addr, data, datagram=True)
            if self.codec.authenticated:  # never an unsigned or forged sender
                self._heard(addr)
            for m in msgs:
                self.on_message(m)

    def _heard(self, addr: tuple[str, int]) -> None:
        """A valid packet from ``addr``: refresh it, or admit it as a telemetry peer if there is
        room and the admission rate allows (else count it in ``peers_refused``)."""
        now = self._clock()
        if addr in self.peers:
            self.peers[addr] = now
            return
        if addr in self.fixed:
            return
        self._expire(now)
        self._tokens = min(NEW_PEERS_BURST, self._tokens + (now - self._tokens_t) * NEW_PEERS_PER_S)
        self._tokens_t = now
        if len(self.peers) >= MAX_UDP_PEERS or self._tokens < 1.0:
            self.codec.counters.peers_refused += 1
            return
        self._tokens -= 1.0
        self.peers[addr] = now

    def _expire(self, now: float) -> None:
        for addr, heard in list(self.peers.items()):
            if now - heard > PEER_TIMEOUT_S:
                del self.peers[addr]
                self.codec.forget(addr)

    def send(self, msg: Any) -> None:
        buf = self.codec.pack(msg)
        self._expire(self._clock())
        dests = self.fixed + [a for a in self.peers if a not in self.fixed]
        for d in dests:
            try:
                self.sock.sendto(buf, d)
            except OSError:
                self.codec.counters.tx_errors += 1

    def close(self) -> None:
        if self._selector is not None:
            try:
                self._selector.unregister(self.sock)
            except (KeyError, ValueError):
                pass
        self.sock.close()


class TcpLink:
    """A TCP server; each accepted connection is a peer that receives everything we send."""

    def __init__(self, codec: Codec, bind: tuple[str, int], on_message: Handler) -> None:
        self.codec = codec
        self.on_message = on_message
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(bind)
        self.sock.listen(8)
        self.sock.setblocking(False)
        self.conns: dict[socket.socket, bytearray] = {}
        self._reserve: int | None = _open_reserve()
        self._selector: selectors.BaseSelector | None = None

    @property
    def address(self) -> tuple[str, int]:
        return self.sock.getsockname()

    def describe(self) -> str:
        host, port = self.address
        return f"tcp {host}:{port}"

    def register(self, sel: selectors.BaseSelector) -> None:
        self._selector = sel
        sel.register(self.sock, selectors.EVENT_READ, self._on_accept)

    def _on_accept(self, _mask: int) -> None:
        try:
            conn, _addr = self.sock.accept()
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:  # EMFILE/ENFILE/ENOBUFS, ECONNABORTED: never end the loop
            self.codec.counters.tcp_refused += 1
            if exc.errno in (errno.EMFILE, errno.ENFILE):
                self._shed_one()
            return
        if len(self.conns) >= MAX_TCP_CONNS:
            self.codec.counters.tcp_refused += 1
            conn.close()
            return
        conn.setblocking(False)
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.conns[conn] = bytearray()
        assert self._selector is not None
        self._selector.register(conn, selectors.EVENT_READ, lambda mask: self._on_conn(conn, mask))

    def _on_conn(self, conn: socket.socket, mask: int) -> None:
        if mask & selectors.EVENT_WRITE:
            self._flush(conn)
        if not mask & selectors.EVENT_READ or conn not in self.conns:
            return
        try:
            data = conn.recv(65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            data = b""
        if not data:
            self._drop(conn)
            return
        for m in self.codec.parse(conn, data, datagram=False):
            self.on_message(m)

    def send(self, msg: Any) -> None:
        buf = self.codec.pack(msg)
        for conn, pending in list(self.conns.items()):
            if pending:
                if len(pending) + len(buf) > MAX_TCP_BACKLOG_BYTES:
                    self.codec.counters.tx_errors += 1
                else:
                    pending.extend(buf)
                continue
            try:
                n = conn.send(buf)
            except (BlockingIOError, InterruptedError):
                n = 0
            except OSError:
                self._drop(conn)
                continue
            if n < len(buf):
                pending.extend(buf[n:])
                self._want_write(conn, True)

    def _flush(self, conn: socket.socket) -> None:
        pending = self.conns.get(conn)
        if pending is None:
            return
        try:
            n = conn.send(pending)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            self._drop(conn)
            return
        del pending[:n]
        if not pending:
            self._want_write(conn, False)

    def _want_write(self, conn: socket.socket, on: bool) -> None:
        if self._selector is None:
            return
        events = selectors.EVENT_READ | (selectors.EVENT_WRITE if on else 0)
        key = self._selector.get_key(conn)
        self._selector.modify(conn, events, key.data)

    def _drop(self, conn: socket.socket) -> None:
        self.conns.pop(conn, None)
        self.codec.forget(conn)
        if self._selector is not None:
            try:
                self._selector.unregister(conn)
            except (KeyError, ValueError):
                pass
        conn.close()

    def _shed_one(self) -> None:
        """Out of descriptors: free the reserved one, accept the waiting connection and close
        it (else the listening socket stays readable and the loop spins), then re-reserve."""
        if self._reserve is not None:
            os.close(self._reserve)
            self._reserve = None
        try:
            conn, _ = self.sock.accept()
            conn.close()
        except OSError:
            pass
        self._reserve = _open_reserve()

    def close(self) -> None:
        if self._reserve is not None:
            os.close(self._reserve)
            self._reserve = None
        for conn in list(self.conns):
            self._drop(conn)
        if self._selector is not None:
            try:
                self._selector.unregister(self.sock)
            except (KeyError, ValueError):
                pass
        self.sock.close()


def _open_reserve() -> int | None:
    """One spare descriptor, given back to let ``accept`` shed a connection at EMFILE."""
    try:
        return os.open(os.devnull, os.O_RDONLY)
    except OSError:
        return None
