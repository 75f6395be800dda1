"""The peer link: one Zenoh session per daemon, and everything the daemon says and hears on it.

Keys (``messages.keys``): peer payloads on ``bf/<fleet>/<id>/peer``, one envelope per publish
tick that holds the newest payload of each kind (:mod:`messages.envelope`), a liveliness token
``bf/<fleet>/<id>/alive``, the status for the ground station on ``bf/<fleet>/<id>/status``,
commands on ``bf/<fleet>/<id>/command`` (answered on ``.../command/ack``), formation changes on
``.../command/formation`` and leader drives on ``.../command/leader``. Zenoh calls back on
its own threads; the link queues what arrives and the agent loop drains it.

Bad input never reaches the agent core: every sample is decoded and validated
(``messages.codec``; an envelope's payloads each on their own, :func:`messages.envelope.unpack`),
its sender (and every payload's in an envelope) must be a fleet member and match the key it came
on, and a failure is counted by reason and logged once per reason (docs/design.md).
"""

from __future__ import annotations

import logging
import random
import threading
from collections import Counter, deque
from collections.abc import Callable, Iterable
from typing import Any, TypeVar

from messages.codec import MessageError, Payload, decode, encode
from messages.command import (
    ACK_TOPIC,
    COMMAND_TOPIC,
    FORMATION_TOPIC,
    LEADER_TOPIC,
    CommandAck,
    FleetCommand,
    FormationChange,
    LeaderDrive,
)
from messages.envelope import pack, unpack
from messages.keys import STATUS_TOPIC, alive_key, key, parse_key, peer_key
from messages.transport import ZenohSettings, open_session
from messages.vocabulary import DropReason, DropScope, drop_key

log = logging.getLogger(__name__)

T = TypeVar("T")


class DropCounter:
    """Thread-safe counters of dropped input by reason; each reason is logged once."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._counts: Counter[str] = Counter()

    def drop(self, reason: DropReason, detail: str = "", scope: DropScope | None = None) -> None:
        """Count one drop under its wire key (:func:`messages.vocabulary.drop_key`)."""
        key = drop_key(reason, scope)
        with self._lock:
            first = self._counts[key] == 0
            self._counts[key] += 1
        if first:
            log.warning("dropping input (%s): %s (logged once per reason)", key, detail)

    def snapshot(self) -> dict[str, int]:
        with self._lock:
            return dict(self._counts)

    @property
    def total(self) -> int:
        with self._lock:
            return sum(self._counts.values())


class PeerLink:
    """Zenoh I/O of one agent (module docstring). ``known`` are the fleet's agent ids;
    ``listen_to`` the agents whose peer payloads it subscribes to (its graph neighbours; default
    every other agent), so nobody decodes traffic it would drop anyway; ``listen_kinds`` adds
    single kinds of payload from further agents (``(agent, kind)``, e.g. the rigidity layer's
    ``rigidity_eigen`` from agents outside the formation graph): their envelopes are
    subscribed to and only those kinds kept. ``inject_loss`` drops that fraction of the
    received envelopes at random (fault injection, counted as ``injected_loss``; all of a
    tick's kinds are lost together, as a lost network packet loses them), seeded by the agent
    id."""

    def __init__(
        self,
        fleet: str,
        agent_id: int,
        known: Iterable[int],
        settings: ZenohSettings,
        drops: DropCounter,
        listen_to: Iterable[int] | None = None,
        inject_loss: float = 0.0,
        listen_kinds: Iterable[tuple[int, str]] = (),
    ) -> None:
        if not 0.0 <= inject_loss < 1.0:
            raise ValueError(f"inject_loss must be in [0, 1), got {inject_loss}")
        self.fleet = fleet
        self.inject_loss = inject_loss
        self._loss_rng = random.Random(agent_id)
        self.listen_to = frozenset(listen_to) if listen_to is not None else None
        self.id = agent_id
        self.known = frozenset(known)
        self.drops = drops
        self.session = open_session(settings)
        self._lock = threading.Lock()
        self._inbox: deque[Payload] = deque(maxlen=10_000)
        self._commands: deque[FleetCommand] = deque(maxlen=100)
        self._formation: FormationChange | None = None
        self._drive: LeaderDrive | None = None
        self._alive: set[int] = set()
        self._handles: list[Any] = []
        self._publishers: dict[str, Any] = {}
        self._ack_seq = 0
        self._envelope_seq = 0
        # the codec as attributes, so the CPU profile (onboard/daemon/profile) can time them
        self.decode = unpack
        self.encode = pack
        self._token = self.session.liveliness().declare_token(alive_key(fleet, agent_id))
        # one subscription per sender, whose handler knows the sender: no key parsing per
        # sample (the key's agent id is the subscription's), and never our own echo; a sender
        # heard only for some kinds (listen_kinds) keeps only those
        peers = self.listen_to if listen_to is not None else self.known
        kinds: dict[int, set[str] | None] = dict.fromkeys(peers - {agent_id})
        for j, kind in listen_kinds:
            if j != agent_id and j not in peers:
                kinds.setdefault(j, set()).add(kind)  # type: ignore[union-attr]
        for j in sorted(kinds):
            only = kinds[j]
            self._handles.append(
                self.session.declare_subscriber(
                    peer_key(fleet, j), self._on_peer(j, frozenset(only) if only else None)
                )
            )
        self._handles.append(
            self.session.declare_subscriber(key(fleet, agent_id, COMMAND_TOPIC), self._on_command)
        )
        self._handles.append(
            self.session.declare_subscriber(
                key(fleet, agent_id, FORMATION_TOPIC), self._on_formation
            )
        )
        self._handles.append(
            self.session.declare_subscriber(key(fleet, agent_id, LEADER_TOPIC), self._on_drive)
        )
        self._handles.append(
            self.session.liveliness().declare_subscriber(
                f"bf/{fleet}/*/alive", self._on_alive, history=True
            )
        )

    # ------------------------------------------------------------------ subscriptions
    def subscribe(self, key_expr: str, handler: Callable[[Any], None]) -> None:
        """Extra subscription on this session (bearing sources, the simulator's clock)."""
        self._handles.append(self.session.declare_subscriber(key_expr, handler))

    def _on_peer(self, key_id: int, kinds: frozenset[str] | None = None) -> Callable[[Any], None]:
        """The handler of the peer envelopes on agent ``key_id``'s key (only ``kinds`` kept)."""

        def on_sample(sample: Any) -> None:
            if self.inject_loss > 0.0:
                with self._lock:
                    lost = self._loss_rng.random() < self.inject_loss
                if lost:
                    self.drops.drop(DropReason.INJECTED_LOSS, "fault injection (zenoh.inject_loss)")
                    return
            try:
                got = self.decode(
                    sample.payload.to_bytes(), sender=key_id, known_senders=self.known, kinds=kinds
                )
            except MessageError as exc:
                self.drops.drop(exc.reason, f"{sample.key_expr}: {exc.detail}")
                return
            for exc in got.errors:  # one bad payload in an envelope: its siblings still count
                self.drops.drop(exc.reason, f"{sample.key_expr}: {exc.detail}")
            if got.payloads:
                with self._lock:
                    self._inbox.extend(got.payloads)

        return on_sample

    def _targeted(self, sample: Any, kind: type[T], what: str) -> T | None:
        """A command-scope payload addressed to this agent, or ``None`` (counted and dropped)."""
        try:
            msg = decode(sample.payload.to_bytes(), kind)
        except MessageError as exc:
            self.drops.drop(exc.reason, exc.detail, DropScope.COMMAND)
            return None
        if msg.target != self.id:
            self.drops.drop(DropReason.FOREIGN, f"{what} for agent {msg.target}", DropScope.COMMAND)
            return None
        return msg

    def _on_command(self, sample: Any) -> None:
        if (cmd := self._targeted(sample, FleetCommand, "command")) is not None:
            with self._lock:
                self._commands.append(cmd)

    def _on_formation(self, sample: Any) -> None:
        if (change := self._targeted(sample, FormationChange, "formation")) is not None:
            with self._lock:
                self._formation = change  # only the newest matters

    def _on_drive(self, sample: Any) -> None:
        if (drive := self._targeted(sample, LeaderDrive, "leader drive")) is not None:
            with self._lock:
                self._drive = drive  # only the newest matters

    def _on_alive(self, sample: Any) -> None:
        try:
            _, agent_id, _ = parse_key(str(sample.key_expr))
        except ValueError:
            return
        with self._lock:
            if str(sample.kind).endswith("PUT"):
                self._alive.add(agent_id)
            else:
                self._alive.discard(agent_id)

    # ------------------------------------------------------------------ the loop's side
    def drain(self, senders: frozenset[int] | set[int] | None = None) -> list[Payload]:
        """Everything received since the last call, oldest first (only from ``senders``)."""
        with self._lock:
            out = list(self._inbox)
            self._inbox.clear()
        if senders is None:
            return out
        return [m for m in out if m.sender in senders]

    def commands(self) -> list[FleetCommand]:
        with self._lock:
            out = list(self._commands)
            self._commands.clear()
        return out

    def formation(self) -> FormationChange | None:
        """The newest formation change received since the last call."""
        with self._lock:
            out, self._formation = self._formation, None
        return out

    def leader_drive(self) -> LeaderDrive | None:
        """The newest leader drive received since the last call."""
        with self._lock:
            out, self._drive = self._drive, None
        return out

    def alive_peers(self) -> set[int]:
        """Agents (other than this one) whose liveliness token is present."""
        with self._lock:
            return {a for a in self._alive if a != self.id and a in self.known}

    def publish(self, payloads: Iterable[Payload]) -> int:
        """Publish peer payloads in one envelope, keeping only the newest of each kind
        (:func:`messages.envelope.pack`); returns how many went out."""
        self._envelope_seq += 1
        packed = self.encode(self.id, self._envelope_seq, payloads)
        for p, exc in packed.rejected:  # never send a non-finite estimate to the fleet
            tag = p.__struct_config__.tag  # type: ignore[attr-defined]
            self.drops.drop(exc.reason, f"{tag}: {exc.detail}", DropScope.OWN)
        if packed.data is None:
            return 0
        self._put(peer_key(self.fleet, self.id), packed.data)
        return len(packed.payloads)

    def publish_status(self, status: Payload) -> None:
        try:
            data = encode(status)
        except MessageError as exc:
            self.drops.drop(exc.reason, exc.detail, DropScope.OWN_STATUS)
            return
        self._put(key(self.fleet, self.id, STATUS_TOPIC), data)

    def ack(self, cmd: FleetCommand, accepted: bool, detail: str, stamp_s: float) -> None:
        self._ack_seq += 1
        ack = CommandAck(
            sender=self.id,
            seq=self._ack_seq,
            stamp_s=stamp_s,
            request_id=cmd.request_id,
            action=cmd.action,
            accepted=accepted,
            detail=detail,
        )
        self._put(key(self.fleet, self.id, ACK_TOPIC), encode(ack))

    def _put(self, key_expr: str, data: bytes) -> None:
        pub = self._publishers.get(key_expr)
        if pub is None:
            pub = self._publishers[key_expr] = self.session.declare_publisher(key_expr)
        pub.put(data)

    def close(self) -> None:
        try:
            self._token.undeclare()
        finally:
            self.session.close()
