"""The ground station's MAVLink link: one UDP socket, a receive thread, commands out.

Endpoints are written like MAVProxy's:

* ``udp:0.0.0.0:14550`` (or ``udpin:``) — bind this port and hear every vehicle that sends
  to it (PX4 and the simulator send to 14550); replies go to the address each system's packets
  came from, so a command reaches vehicle ``k`` over the very path its telemetry takes;
* ``udpout:127.0.0.1:14580`` — send from an ephemeral port to a vehicle's own socket (a GCS
  HEARTBEAT every second makes the vehicle stream to us). Useful when another program (a
  running ``gcs monitor``) already holds 14550.

A GCS HEARTBEAT goes every second to the ``udpout`` endpoints and to every vehicle heard, and
an ArduPilot, which streams nothing to a port until asked, is asked with SET_MESSAGE_INTERVAL
for what the monitor shows (:data:`~groundstation.gcs.mavlink_state.GCS_STREAMS_HZ`), again
whenever one of those streams stops (``request_streams=False`` turns that off).

Every valid message is folded into a :class:`~groundstation.gcs.mavlink_state.MavlinkState`
under a lock and passed to the ``on_message`` hooks with its raw bytes and receive time (the
recorder is one). Garbage and bad CRCs are counted, never raised.

With ``signing_keys`` (system id -> 32-byte key, the fleet's ``mavlink-vehicle-<id>.key``),
what goes to system ``s`` is signed with ``s``'s key (heartbeats to a ``udpout`` endpoint,
whose system is not known yet, once with each key), and every received message must pass a
:class:`~messages.mavsign.SignatureVerifier` first: a rejected one is counted
(``sig_bad_signature``, ``sig_unsigned``, ``sig_replayed``) and changes no state, and only a
correctly signed one tells us where a system is.
"""

from __future__ import annotations

import select
import socket
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as dialect

from groundstation.gcs.mavlink_state import (
    MAV_AUTOPILOT_INVALID,
    MAV_TYPE_GCS,
    Ack,
    MavlinkState,
    SystemTelemetry,
    streams_to_request,
)
from messages import mavlink as mv
from messages.mavsign import SignatureVerifier, Verdict, keep_timestamp_current, sign_outgoing

GCS_SYSTEM_ID = 255
GCS_COMPONENT_ID = 190
"""MAV_COMP_ID_MISSIONPLANNER, as QGroundControl and MAVProxy use."""
GCS_SIGNING_LINK_ID = 2
"""Link id in the ground station's signatures (the daemons use 1, the autopilots 0)."""
HEARTBEAT_PERIOD_S = 1.0
RECEIVE_BUFFER_BYTES = 4 << 20
"""Asked for (the kernel caps it at ``net.core.rmem_max``): a busy machine can stall the
receive thread long enough for a default-sized buffer to overflow, which shows up as loss."""

MessageHook = Callable[[Any, bytes, float], None]
"""Called with (parsed message, raw frame bytes, wall-clock receive time in s)."""


@dataclass(frozen=True)
class MavlinkEndpoint:
    """``kind`` is ``"udp"`` (bind and listen) or ``"udpout"`` (send to a vehicle)."""

    kind: str
    host: str
    port: int

    def __str__(self) -> str:
        return f"{self.kind}:{self.host}:{self.port}"


def parse_endpoint(text: str) -> MavlinkEndpoint:
    """``udp:HOST:PORT``, ``udpin:HOST:PORT`` or ``udpout:HOST:PORT``; ``ValueError`` otherwise."""
    parts = text.strip().split(":")
    if len(parts) != 3 or parts[0] not in ("udp", "udpin", "udpout"):
        raise ValueError(f"MAVLink endpoint {text!r}: expected udp:HOST:PORT or udpout:HOST:PORT")
    try:
        port = int(parts[2])
    except ValueError:
        raise ValueError(f"MAVLink endpoint {text!r}: port is not an integer") from None
    kind = "udpout" if parts[0] == "udpout" else "udp"
    if not (0 if kind == "udp" else 1) <= port < 65536:  # udp:HOST:0 binds an ephemeral port
        raise ValueError(f"MAVLink endpoint {text!r}: port out of range")
    return MavlinkEndpoint(kind, parts[1] or "0.0.0.0", port)


class _Sink:
    def write(self, _buf: bytes) -> None:  # pragma: no cover - pymavlink wants a file
        pass


class MavlinkListener:
    """Receive thread + state + command sender on one UDP socket (see the module docstring)."""

    def __init__(
        self,
        endpoints: Sequence[MavlinkEndpoint],
        clock: Callable[[], float] = time.monotonic,
        request_streams: bool = True,
        signing_keys: Mapping[int, bytes] | None = None,
    ) -> None:
        binds = [e for e in endpoints if e.kind == "udp"]
        if len(binds) > 1:
            raise ValueError("at most one udp: (listen) endpoint per listener")
        self.clock = clock
        self.state = MavlinkState()
        self.lock = threading.Condition()
        self.hooks: list[MessageHook] = []
        self.outs = [(e.host, e.port) for e in endpoints if e.kind == "udpout"]
        self.addresses: dict[int, tuple[str, int]] = {}
        """Where each system's packets come from: commands to it go there."""
        self.request_streams = request_streams
        self.stream_requests: dict[int, float] = {}
        """When each system was last asked for its streams (module docstring)."""
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER_BYTES)
        try:
            self.sock.bind((binds[0].host, binds[0].port) if binds else ("0.0.0.0", 0))
        except OSError as exc:
            self.sock.close()
            where = f"{binds[0].host}:{binds[0].port}" if binds else "an ephemeral port"
            raise OSError(
                f"cannot listen on {where} ({exc.strerror}); is another ground station using "
                "it? Pass a free --mavlink udp:HOST:PORT, or udpout:HOST:PORT to the vehicles"
            ) from None
        self._tx = dialect.MAVLink(_Sink(), srcSystem=GCS_SYSTEM_ID, srcComponent=GCS_COMPONENT_ID)
        self.signing_keys = dict(signing_keys) if signing_keys else None
        self.verifier = SignatureVerifier(self.signing_keys) if self.signing_keys else None
        self._signed_tx: dict[int, Any] = {}
        for sysid, key in (self.signing_keys or {}).items():
            tx = dialect.MAVLink(_Sink(), srcSystem=GCS_SYSTEM_ID, srcComponent=GCS_COMPONENT_ID)
            sign_outgoing(tx, key, GCS_SIGNING_LINK_ID)
            self._signed_tx[sysid] = tx
        self._parsers: dict[tuple[str, int], Any] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._send_lock = threading.Lock()

    @property
    def port(self) -> int:
        return int(self.sock.getsockname()[1])

    # --- receive ------------------------------------------------------------------------------------
    def start(self) -> MavlinkListener:
        self._thread = threading.Thread(target=self._run, name="gcs-mavlink", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self.sock.close()

    def __enter__(self) -> MavlinkListener:
        return self.start()

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def _run(self) -> None:
        next_beat = 0.0
        while not self._stop.is_set():
            now = self.clock()
            if now >= next_beat:
                self._send_heartbeat()
                if self.request_streams:
                    self._ask_for_streams(now)
                next_beat = now + HEARTBEAT_PERIOD_S
            try:
                ready, _, _ = select.select([self.sock], [], [], 0.1)
            except (OSError, ValueError):
                return
            if not ready:
                continue
            for _ in range(256):
                try:
                    data, addr = self.sock.recvfrom(65535, socket.MSG_DONTWAIT)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:
                    if self._stop.is_set():
                        return
                    continue
                self.feed(data, addr)

    def feed(self, data: bytes, addr: tuple[str, int]) -> list[Any]:
        """Parse one datagram from ``addr`` and fold its messages (also used by tests)."""
        t_mono = self.clock()
        t_wall = time.time()
        parser = self._parsers.get(addr)
        if parser is None:
            parser = self._parsers[addr] = dialect.MAVLink(_Sink())
            parser.robust_parsing = True
        try:
            msgs = parser.parse_buffer(data) or []
        except Exception:  # robust parsing should not raise; never let a packet kill us
            msgs = []
            with self.lock:
                self.state.count("malformed")
        good = []
        with self.lock:
            for m in msgs:
                kind = m.get_type()
                if kind == "BAD_DATA":
                    self.state.count("bad_crc" if "CRC" in str(m.reason) else "garbage")
                elif kind.startswith("UNKNOWN_"):
                    self.state.count("unknown_ids")
                elif (verdict := self._verify(m)) is not None:
                    sys = self.state.fold(m, t_mono)
                    if sys is not None and verdict is Verdict.GOOD:
                        self.addresses[sys.sysid] = addr
                    good.append(m)
            if parser.buf_len() > 0:  # a datagram never continues in the next one
                self.state.count("garbage")
                self._parsers.pop(addr, None)
            if good:
                self.lock.notify_all()
        for m in good:
            raw = bytes(m.get_msgbuf())
            for hook in self.hooks:
                hook(m, raw, t_wall)
        return good

    def _verify(self, m: Any) -> Verdict | None:
        """The verdict on an accepted message (``GOOD`` without signing), ``None`` if rejected
        (counted; call with the lock held)."""
        if self.verifier is None:
            return Verdict.GOOD
        verdict = self.verifier.check_message(m)
        self.state.count(f"sig_{verdict.value}")
        return verdict if verdict.accepted else None

    # --- read ---------------------------------------------------------------------------------------
    def systems(self) -> dict[int, SystemTelemetry]:
        """A shallow copy of the per-system telemetry (read it, do not modify it)."""
        with self.lock:
            return dict(self.state.systems)

    def wait_for(self, predicate: Callable[[MavlinkState], bool], timeout_s: float) -> bool:
        """Block until ``predicate(state)`` (evaluated under the lock) holds or time runs out."""
        with self.lock:  # every update notifies the condition
            return self.lock.wait_for(lambda: predicate(self.state), timeout_s)

    def acks_since(self, t_s: float) -> list[Ack]:
        with self.lock:
            return [a for a in self.state.acks if a.t_s >= t_s]

    # --- send ---------------------------------------------------------------------------------------
    def _send(self, msg: Any, addr: tuple[str, int], sysid: int | None = None) -> bool:
        """Pack (signed with ``sysid``'s key when signing) and send; ``False`` on failure or
        when signing is on and we hold no key for ``sysid``."""
        with self._send_lock:
            tx = self._tx
            if self.signing_keys is not None:
                tx = self._signed_tx.get(sysid) if sysid is not None else None
                if tx is None:
                    with self.lock:
                        self.state.count("sig_no_key")
                    return False
                keep_timestamp_current(tx)
            buf = msg.pack(tx)
            tx.seq = (tx.seq + 1) % 256
        try:
            self.sock.sendto(buf, addr)
        except OSError:
            with self.lock:
                self.state.count("tx_errors")
            return False
        return True

    def _send_heartbeat(self) -> None:
        """To the ``udpout`` endpoints and to every vehicle heard (its address)."""
        hb = dialect.MAVLink_heartbeat_message(MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID, 0, 0, 4, 3)
        with self.lock:
            heard = dict(self.addresses)
        if self.signing_keys is None:
            for addr in dict.fromkeys([*self.outs, *heard.values()]):
                self._send(hb, addr)
            return
        for sysid, addr in heard.items():
            self._send(hb, addr, sysid)
        for addr in self.outs:  # whose it is is not known yet: one copy per key
            for sysid in self._signed_tx:
                if heard.get(sysid) != addr:
                    self._send(hb, addr, sysid)

    def _ask_for_streams(self, now_s: float) -> None:
        """SET_MESSAGE_INTERVAL for every stream an ArduPilot does not send us (yet)."""
        with self.lock:
            due = {
                sysid: streams_to_request(sys, now_s, self.stream_requests.get(sysid))
                for sysid, sys in self.state.systems.items()
            }
        for sysid, streams in due.items():
            if not streams:
                continue
            self.stream_requests[sysid] = now_s
            for name, hz in streams:
                msg_id = getattr(dialect, f"MAVLINK_MSG_ID_{name}")
                self.send_command_long(sysid, mv.CMD_SET_MESSAGE_INTERVAL, (msg_id, 1e6 / hz))

    def send_command_long(
        self, sysid: int, command: int, params: Sequence[float], confirmation: int = 0
    ) -> bool:
        """COMMAND_LONG to system ``sysid`` (component 1) at the address it was heard from;
        ``False`` if the system was never heard or the send failed."""
        addr = self.addresses.get(sysid)
        if addr is None:
            return False
        p = command_params(params)
        msg = dialect.MAVLink_command_long_message(sysid, 1, command, confirmation, *p)
        return self._send(msg, addr, sysid)


def command_params(params: Sequence[float]) -> list[float]:
    """The seven COMMAND_LONG parameters: ``params`` followed by zeros.

    MAVLink's unused parameters are 0; NaN only where a command defines it ("unchanged", e.g.
    NAV_TAKEOFF's yaw), and the caller then passes it explicitly. Padding with NaN killed
    ArduCopter SITL: it compares ARM_DISARM's param 2 with the force-disarm code 21196, and the
    NaN comparison raised the floating-point exception it aborts on (issue 22, bug 2)."""
    if len(params) > 7:
        raise ValueError(f"COMMAND_LONG has 7 parameters, got {len(params)}")
    return [float(x) for x in params] + [0.0] * (7 - len(params))
