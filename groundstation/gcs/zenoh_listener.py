"""What the ground station hears on Zenoh: every sample under ``bf/<fleet>/**`` and the agents'
liveliness tokens ``bf/<fleet>/<id>/alive``.

:func:`classify` maps one sample's key and bytes to a decoded payload or a
:class:`~messages.codec.MessageError` whose ``reason`` is counted: the codec's reasons
(``malformed``, ``version``, ``nonfinite``, ``oversize``) plus ``foreign`` (a key or topic that
is not ours), ``wrong_fleet`` and ``sender_mismatch`` (a payload whose sender is not the agent
its key names). A peer envelope (``bf/<fleet>/<id>/peer``, :mod:`messages.envelope`) holds a
tick's peer payloads: :func:`classify_all` unpacks it into one :class:`Decoded` per payload,
topic ``peer/<kind>`` (the key each kind had before envelopes), and an error per bad payload;
``peer/<kind>`` samples of older recordings are still read. :class:`ZenohState` folds samples
into one :class:`AgentTelemetry` per agent; both are pure. :class:`ZenohListener` wires them to
a session under a lock.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from messages.agent import VehicleStatus
from messages.codec import MessageError, Payload, decode
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
from messages.envelope import PeerEnvelope, kind_of, unpack
from messages.keys import ALIVE_TOPIC, PEER_TOPIC, STATUS_TOPIC, fleet_keys, is_sim_key, parse_key
from messages.peer import PeerPayload
from messages.sim import CAMERA_TOPIC, TRUTH_TOPIC, CameraBearings, SimClock, SimStep, Truth
from messages.vocabulary import DropReason

TOPIC_TYPES: dict[str, Any] = {
    STATUS_TOPIC: VehicleStatus,
    COMMAND_TOPIC: FleetCommand,
    ACK_TOPIC: CommandAck,
    FORMATION_TOPIC: FormationChange,
    LEADER_TOPIC: LeaderDrive,
    CAMERA_TOPIC: CameraBearings,
    TRUTH_TOPIC: Truth,
}
"""Payload type of each per-agent topic (``peer`` carries a :class:`PeerEnvelope`, the
``peer/<kind>`` topics of recordings made before envelopes one :data:`PeerPayload`)."""
SIM_TOPIC_TYPES: dict[str, Any] = {"clock": SimClock, "step": SimStep}

SampleHook = Callable[[str, bytes, float], None]
"""Called with (key, payload bytes, wall-clock receive time in s) for every sample."""
AliveHook = Callable[[str, bool, float], None]
"""Called with (liveliness key, alive, wall-clock receive time in s)."""


@dataclass(frozen=True)
class Decoded:
    """A valid sample: the agent its key names (``None`` for the simulator's fleet-wide keys),
    the topic, and the payload."""

    agent_id: int | None
    topic: str
    payload: Payload


def payload_type(topic: str) -> Any:
    """The payload type of a per-agent topic; ``None`` if the topic is not one we know."""
    if topic in TOPIC_TYPES:
        return TOPIC_TYPES[topic]
    if topic == PEER_TOPIC:
        return PeerEnvelope
    if topic.startswith(PEER_TOPIC + "/") and topic.count("/") == 1:
        return PeerPayload
    return None


def classify(fleet: str, key: str, data: bytes) -> Decoded:
    """Decode one sample of fleet ``fleet``; raises :class:`MessageError` (see module doc). A
    peer envelope is one :class:`Decoded` (its payload the :class:`PeerEnvelope`) only if every
    payload in it is valid, else the first bad one's error is raised: :func:`classify_all`
    keeps the good ones."""
    agent_id, topic, kind = _locate(fleet, key)
    if kind is PeerEnvelope:
        got = unpack(data, sender=agent_id)
        if got.errors:
            raise got.errors[0]
        return Decoded(agent_id, topic, got.envelope())
    return _single(key, agent_id, topic, decode(data, kind))


def classify_all(fleet: str, key: str, data: bytes) -> tuple[list[Decoded], list[MessageError]]:
    """Decode one sample of fleet ``fleet`` into what it holds: one :class:`Decoded`, or for a
    peer envelope one per valid payload (topic ``peer/<kind>``) and a :class:`MessageError` per
    invalid one. Raises :class:`MessageError` when the sample itself is bad (module doc)."""
    agent_id, topic, kind = _locate(fleet, key)
    if kind is PeerEnvelope:
        got = unpack(data, sender=agent_id)
        out = [Decoded(agent_id, f"{PEER_TOPIC}/{kind_of(p)}", p) for p in got.payloads]
        return out, got.errors
    return [_single(key, agent_id, topic, decode(data, kind))], []


def _locate(fleet: str, key: str) -> tuple[int | None, str, Any]:
    """The agent (``None`` for the simulator's keys), topic and payload type of a key."""
    parts = key.split("/", 3)
    if len(parts) == 4 and parts[0] == "bf" and parts[1] != fleet:
        raise MessageError(DropReason.WRONG_FLEET, f"{key} is not under fleet {fleet!r}")
    if is_sim_key(key):
        kind = SIM_TOPIC_TYPES.get(parts[3])
        if kind is None:
            raise MessageError(DropReason.FOREIGN, f"unknown simulator topic in {key}")
        return None, parts[3], kind
    try:
        _fleet, agent_id, topic = parse_key(key)
    except ValueError as exc:
        raise MessageError(DropReason.FOREIGN, str(exc)) from None
    kind = payload_type(topic)
    if kind is None:
        raise MessageError(DropReason.FOREIGN, f"unknown topic {topic!r} in {key}")
    return agent_id, topic, kind


def _single(key: str, agent_id: int | None, topic: str, payload: Any) -> Decoded:
    """A sample holding one payload: its owner must be the agent its key names."""
    if agent_id is None:
        return Decoded(None, topic, payload)
    owner = (
        payload.target
        if isinstance(payload, FleetCommand | FormationChange | LeaderDrive)
        else payload.sender
    )
    if owner != agent_id:
        raise MessageError(
            DropReason.SENDER_MISMATCH, f"{type(payload).__name__} of {owner} on {key}"
        )
    if isinstance(payload, CameraBearings) and len(payload.targets) != len(payload.beta_body):
        raise MessageError(
            DropReason.MALFORMED, f"{key}: {len(payload.targets)} targets, bearings differ"
        )
    return Decoded(agent_id, topic, payload)


def alive_agent(fleet: str, key: str) -> int | None:
    """Agent id of a liveliness key ``bf/<fleet>/<id>/alive``; ``None`` if it is not one."""
    try:
        f, agent_id, topic = parse_key(key)
    except ValueError:
        return None
    return agent_id if f == fleet and topic == ALIVE_TOPIC else None


@dataclass
class AgentTelemetry:
    """The latest status of one agent and its liveliness, with receive times (monotonic s)."""

    agent_id: int
    first_seen_s: float
    status: VehicleStatus | None = None
    status_s: float | None = None
    alive: bool | None = None
    """Liveliness token present (``None``: never seen one)."""
    alive_s: float | None = None


@dataclass
class ZenohState:
    """Everything heard under one fleet's keys."""

    fleet: str
    agents: dict[int, AgentTelemetry] = field(default_factory=dict)
    counters: dict[str, int] = field(default_factory=dict)
    """Dropped samples by reason."""
    topics: dict[str, int] = field(default_factory=dict)
    """Accepted samples by topic (``peer/<kind>`` kept apart, so peer traffic is visible)."""
    acks: list[tuple[float, CommandAck]] = field(default_factory=list)
    clock: SimClock | None = None
    last_error: str = ""
    scale_pending_s: float | None = None
    """First time an agent reported a scale not yet converged."""
    scale_converged_s: float | None = None
    """First time every agent reported ``scale_converged`` (at or after ``scale_pending_s``;
    also set, with ``scale_pending_s`` left ``None``, if the first statuses heard had already
    converged: the monitor started late)."""
    max_acks: int = 1000

    def count(self, reason: DropReason) -> None:
        self.counters[reason] = self.counters.get(reason, 0) + 1

    def agent(self, agent_id: int, t_s: float) -> AgentTelemetry:
        a = self.agents.get(agent_id)
        if a is None:
            a = self.agents[agent_id] = AgentTelemetry(agent_id, t_s)
        return a

    def fold_sample(self, key: str, data: bytes, t_s: float) -> list[Decoded]:
        """Fold one sample received at ``t_s``: what it held (a peer envelope's payloads one by
        one, :func:`classify_all`); what was dropped is counted by reason."""
        try:
            decoded, errors = classify_all(self.fleet, key, data)
        except MessageError as exc:
            decoded, errors = [], [exc]
        for exc in errors:
            self.count(exc.reason)
            self.last_error = f"{key}: {exc}"[:200]
        for d in decoded:
            self._fold(d, t_s)
        return decoded

    def _fold(self, d: Decoded, t_s: float) -> None:
        self.topics[d.topic] = self.topics.get(d.topic, 0) + 1
        if d.agent_id is None:
            if isinstance(d.payload, SimClock):
                self.clock = d.payload
            return
        if isinstance(d.payload, VehicleStatus):
            a = self.agent(d.agent_id, t_s)
            a.status, a.status_s = d.payload, t_s
            self._track_scale(t_s)
        elif isinstance(d.payload, CommandAck):
            self.acks.append((t_s, d.payload))
            del self.acks[: max(0, len(self.acks) - self.max_acks)]
        # commands are ours (or another ground station's); camera, truth and peer samples are
        # counted by topic: only a status or a liveliness token makes an agent appear

    def fold_alive(self, key: str, alive: bool, t_s: float) -> int | None:
        agent_id = alive_agent(self.fleet, key)
        if agent_id is None:
            self.count(DropReason.FOREIGN)
            return None
        a = self.agent(agent_id, t_s)
        a.alive, a.alive_s = alive, t_s
        return agent_id

    def _track_scale(self, t_s: float) -> None:
        if self.scale_converged_s is not None:
            return
        statuses = [a.status for a in self.agents.values() if a.status is not None]
        if all(s.agent.scale_converged for s in statuses):
            self.scale_converged_s = t_s
        elif self.scale_pending_s is None:
            self.scale_pending_s = t_s


class ZenohListener:
    """Subscribes to a fleet on an open session and keeps a :class:`ZenohState` under a lock."""

    def __init__(
        self, session: Any, fleet: str, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.session = session
        self.fleet = fleet
        self.clock = clock
        self.state = ZenohState(fleet)
        self.lock = threading.Condition()
        self.sample_hooks: list[SampleHook] = []
        self.alive_hooks: list[AliveHook] = []
        self._subs: list[Any] = []

    def start(self) -> ZenohListener:
        import zenoh

        self._kind_put = zenoh.SampleKind.PUT
        self._subs.append(self.session.declare_subscriber(fleet_keys(self.fleet), self._on_sample))
        self._subs.append(
            self.session.liveliness().declare_subscriber(
                f"bf/{self.fleet}/*/{ALIVE_TOPIC}", self._on_alive, history=True
            )
        )
        return self

    def close(self) -> None:
        for sub in self._subs:
            try:
                sub.undeclare()
            except Exception:  # the session may be closing already
                pass
        self._subs = []

    def _on_sample(self, sample: Any) -> None:
        key = str(sample.key_expr)
        try:
            data = sample.payload.to_bytes()
        except Exception:  # a payload zenoh cannot hand over: count it, never raise
            with self.lock:
                self.state.count(DropReason.MALFORMED)
            return
        t_wall = time.time()
        with self.lock:
            self.state.fold_sample(key, data, self.clock())
            self.lock.notify_all()
        for hook in self.sample_hooks:
            hook(key, data, t_wall)

    def _on_alive(self, sample: Any) -> None:
        key = str(sample.key_expr)
        alive = sample.kind == self._kind_put
        t_wall = time.time()
        with self.lock:
            self.state.fold_alive(key, alive, self.clock())
            self.lock.notify_all()
        for hook in self.alive_hooks:
            hook(key, alive, t_wall)

    def wait_for(self, predicate: Callable[[ZenohState], bool], timeout_s: float) -> bool:
        with self.lock:  # every update notifies the condition
            return self.lock.wait_for(lambda: predicate(self.state), timeout_s)
