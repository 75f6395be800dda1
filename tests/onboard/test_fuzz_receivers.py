"""Property-based fuzzing of every receiver (issue 23): random and mutated payloads of every
message type go through the codec and, when accepted, the replay window and into a warm agent
core's step. Invariants: no exception escapes, no estimate becomes non-finite, every table
stays within its bound, and the status is always publishable. Bounded (a fixed number of
derandomized examples) so the suite stays in the fast tier.

The warm team flies once on paper 000's localization and once on paper 002's
(``[core] localization = "paper002"``, :mod:`onboard.core.localization002`; docs/papers.md),
so the ``peer.gradloc`` share (paper 002 eq. 16-17 and 22, docs/equations.md) is fuzzed too.
The command scope (issue 25's :class:`messages.command.FormationChange` and
:class:`~messages.command.LeaderDrive`, and :class:`~messages.command.FleetCommand`) goes
through the daemon's own receive path: the peer link's handlers
(:meth:`onboard.daemon.peers.PeerLink._targeted`) and the loop's adoption
(:meth:`onboard.daemon.loop.AgentDaemon._handle_commands`), then the core flies what was
adopted."""

from __future__ import annotations

import copy
import math
from functools import lru_cache
from typing import Any

import msgspec
import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from messages.agent import AgentStatus, BearingMeasurement, OwnMeasurements, VehicleStatus
from messages.codec import MessageError, Payload, decode, encode
from messages.command import (
    FleetCommand,
    FormationChange,
    FormationSlot,
    LeaderDrive,
    drive_problem,
    formation_problem,
)
from messages.limits import POSITION_MAX_M, SPEED_MAX_M_S
from messages.peer import PeerPayload
from messages.sim import CameraBearings, SimClock
from onboard.core.agent import AgentCore
from onboard.core.config import AgentConfig, build_config
from onboard.core.scale import CONSENSUS_NAMES
from onboard.daemon.bearings import SimCameraSource
from onboard.daemon.clock import SimClockFollower, sim_clock_handler
from onboard.daemon.loop import AgentDaemon
from onboard.daemon.peers import DropCounter, PeerLink
from onboard.daemon.replay import SeqWindow
from onboard.geometry import bearings_body

N = 3
EDGES = ((0, 1), (1, 0), (1, 2), (2, 1), (0, 2), (2, 0))
P0 = np.array([[0.0, 0.0, -2.0], [2.5, 0.5, -2.6], [0.5, 2.6, -1.5]])
YAW0 = np.array([0.3, 2.2, -1.4])
DT = 0.002
TARGET = 1  # the fuzzed receiver
FUZZ = settings(
    max_examples=80,
    deadline=None,
    derandomize=True,
    database=None,
    phases=[Phase.explicit, Phase.generate],  # no shrinking: a failure is reported at once
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)


LOCALIZATIONS = ("paper000", "paper002")
"""The warm team's localization: paper 000's filter, or paper 002's gradient localization."""


def _configs(localization: str = "paper000") -> list[AgentConfig]:
    beta, _ = bearings_body(P0, YAW0, list(EDGES))
    return [
        build_config(
            agent_id=i,
            n_agents=N,
            edges=EDGES,
            mode="formation-active",
            p_hat0_ned=tuple(tuple(float(x) for x in 0.8 * row) for row in P0),
            yaw_hat0_rad=tuple(float(y) for y in YAW0),
            desired_beta_body=tuple(
                (i_, j_, tuple(float(x) for x in b))
                for (i_, j_), b in zip(EDGES, beta, strict=True)
            ),
            desired_yaw_rad=tuple(float(y) for y in YAW0),
            seed=3,
            rigidity_maintenance=True,  # so the rigidity layer's payloads are fuzzed too
            rigidity_period_s=0.02,
            rigidity_scale_from_sfm=True,
            localization=localization,
        )
        for i in range(N)
    ]


def _own(t_s: float, p: np.ndarray, yaw: np.ndarray, v: np.ndarray, w: np.ndarray, i: int):
    others = [j for j in range(N) if j != i]
    b, _ = bearings_body(p, yaw, [(i, j) for j in others])
    frame = tuple(BearingMeasurement(j, tuple(b[k]), t_s) for k, j in enumerate(others))
    return OwnMeasurements(
        t_s=t_s, yaw_rad=float(yaw[i]), v_body=tuple(float(x) for x in v[i]),
        yaw_rate_rad_s=float(w[i]), bearings=frame if round(t_s / DT) % 10 == 0 else (),
    )  # fmt: skip


@lru_cache(maxsize=len(LOCALIZATIONS))
def _warm_team(localization: str = "paper000") -> tuple[AgentCore, dict[str, list[bytes]], float]:
    """Three cores flown for 1 s with every payload through the codec: the fuzzed receiver
    (warm, with every table filled) and a corpus of real payloads of every kind."""
    from onboard.geometry import rot_z

    cores = [AgentCore(c) for c in _configs(localization)]
    p, yaw = P0.copy(), YAW0.copy()
    v, w = np.zeros((N, 3)), np.zeros(N)
    inbox: list[list[Payload]] = [[] for _ in range(N)]
    corpus: dict[str, list[bytes]] = {}
    t = 0.0
    for k in range(500):
        t = k * DT
        outs = []
        for i, c in enumerate(cores):
            sp, out = c.step(t, _own(t, p, yaw, v, w, i), inbox[i])
            v[i], w[i] = sp.v_body, sp.yaw_rate_rad_s
            outs.append([encode(m) for m in out])
            if i != TARGET:
                for m, data in zip(out, outs[-1], strict=True):
                    corpus.setdefault(type(m).__struct_config__.tag, []).append(data)
        inbox = [
            [decode(d, PeerPayload) for j in range(N) if j != i for d in outs[j]] for i in range(N)
        ]
        p = p + DT * np.einsum("nij,nj->ni", rot_z(yaw), v)
        yaw = yaw + DT * w
    corpus = {tag: datas[-50:] for tag, datas in corpus.items()}
    return cores[TARGET], corpus, t


# ------------------------------------------------------------------ strategies
LEAVES = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([1e300, -1e300, 1e154, 1e6, -0.0, 0.0, 1.0, 2.0**53]),
    st.integers(min_value=-(2**63), max_value=2**64 - 1),
    st.sampled_from([0, 1, 2, 3, 7, -1, 65_536]),
    st.text(max_size=8),
    st.booleans(),
    st.none(),
    st.binary(max_size=24),
)
NAMES = st.one_of(st.sampled_from(sorted(CONSENSUS_NAMES)), st.text(max_size=8))
VALUES = st.recursive(LEAVES, lambda inner: st.lists(inner, max_size=4), max_leaves=6)


def _leaf_paths(value: Any, path: tuple = ()) -> list[tuple]:
    if isinstance(value, dict):
        return [p for k, v in value.items() for p in _leaf_paths(v, (*path, k))] or [path]
    if isinstance(value, list):
        return [p for i, v in enumerate(value) for p in _leaf_paths(v, (*path, i))] or [path]
    return [path]


def _set(value: Any, path: tuple, new: Any) -> Any:
    if not path:
        return new
    value[path[0]] = _set(value[path[0]], path[1:], new)
    return value


HUGE = st.sampled_from([1e300, -1e300, 1e200, 1e154, -1e154, 1e20, 1e6])
"""Finite magnitudes far beyond physics (issue 23: one 1e300 or 1e154 broke a receiver)."""


def _get(value: Any, path: tuple) -> Any:
    for k in path:
        value = value[k]
    return value


@st.composite
def mutated(draw: st.DrawFn, corpus: dict[str, list[bytes]]) -> bytes:
    """A real (recent, so fresh) payload with bytes flipped, one to three fields replaced by
    anything, one to three of its numbers (not its header) made huge, or its ids and names
    (edge ends, targets, consensus names) replaced by made-up ones."""
    tag = draw(st.sampled_from(sorted(corpus)))
    data = draw(st.sampled_from(corpus[tag]))
    how = draw(st.sampled_from(["flip", "replace", "huge", "huge", "ids"]))
    if how == "flip":  # bit flips in the encoding
        raw = bytearray(data)
        for _ in range(draw(st.integers(1, 4))):
            raw[draw(st.integers(0, len(raw) - 1))] ^= 1 << draw(st.integers(0, 7))
        return bytes(raw)
    raw = msgspec.msgpack.decode(data)
    header = ("type", "version", "sender", "seq", "stamp_s")
    for _ in range(draw(st.integers(1, 3))):
        paths = [
            p for p in _leaf_paths(raw) if p and p[0] not in header[: 2 if how == "replace" else 5]
        ]
        if how == "huge":
            paths = [p for p in paths if isinstance(_get(raw, p), float)]
        elif how == "ids":
            paths = [p for p in paths if type(_get(raw, p)) in (int, str)]
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        if how == "ids":
            new = draw(st.integers(0, 70_000) if type(_get(raw, path)) is int else NAMES)
        else:
            new = draw(VALUES if how == "replace" else HUGE)
        _set(raw, path, new)
    return msgspec.msgpack.encode(raw)


@st.composite
def random_payload(draw: st.DrawFn, corpus: dict[str, list[bytes]]) -> bytes:
    """A payload of a real type tag (and mostly a real version and sender) with random fields."""
    tag = draw(st.sampled_from(sorted(corpus)))
    fields = msgspec.msgpack.decode(corpus[tag][0])
    raw = {
        "type": tag,
        "version": draw(st.sampled_from([fields["version"], fields["version"], 1, 99])),
    }
    for name in fields:
        if name not in raw:
            raw[name] = draw(VALUES)
    raw["sender"] = draw(st.sampled_from([0, 2, raw["sender"]]))
    return msgspec.msgpack.encode(raw)


# ------------------------------------------------------------------ invariants
def _check_invariants(c: AgentCore, setpoint: Any) -> None:
    loc = c.localization
    s, r, ctl = c.scale, c.rigidity, c.controller
    assert s is not None and r is not None and ctl is not None
    numbers = [*loc.p_hat_ned, loc.yaw_hat_rad, c.lambda_bar, c.e_index, c.w_l, s.dlam_dwl]
    numbers += [*s.p_bar, *ctl.u_cmd, *setpoint.v_body, setpoint.yaw_rate_rad_s]
    numbers += [e.chi_hat for e in s.sfm.values()]
    numbers += [*r.loc.p_hat_ned, *r.u_rigidity, r.w_rigidity]
    numbers += [] if r.lambda_hat is None else [r.lambda_hat]
    assert all(math.isfinite(x) for x in numbers), numbers
    assert set(s.cons_in) <= CONSENSUS_NAMES
    assert all(set(d) <= set(c.neighbours) for d in s.cons_in.values())
    assert set(s.lam_table) <= s.known_edges
    tables = [c.peers.all(kind) for kind in c.peers.routes]
    for table in (*tables, c.bearings.beta_in, s.sfm_in, c.peers.heard):
        assert set(table) <= set(c.neighbours)
    assert all(len(h) <= 2000 for h in (c.bearings.own_hist, *s.motion_hist.values()))
    g = c.gradient_localization
    if g is not None:  # paper 002's T_i, lambda_ij and the in-edge products: finite, bounded
        bounded = [*g.t_ned, *g.lam.values(), *(x for w in g._w_in.values() for x in w)]
        assert all(math.isfinite(x) and abs(x) <= POSITION_MAX_M for x in bounded), bounded
        assert all(math.isfinite(x) and abs(x) <= SPEED_MAX_M_S for x in g.v_ned), g.v_ned
        assert set(g.lam) == set(g.out_targets) and set(g._w_in) <= set(g.in_sources)
    status = c.status()
    assert decode(encode(status), AgentStatus) == status  # publishable: finite, encodable


def _deliver(c: AgentCore, t0: float, datas: list[bytes]) -> None:
    """What a daemon does with the samples: codec, replay window, core step; then 20 more
    steps so that whatever got in propagates through the estimators."""
    window = SeqWindow()
    inbox = []
    for data in datas:
        try:
            msg = decode(data, PeerPayload, known_senders=range(N))
        except MessageError:
            continue
        if window.admit(msg.sender, type(msg), msg.seq, msg.stamp_s, t0) in (None, "seq_resync"):
            inbox.append(msg)
    own = OwnMeasurements(t_s=t0, yaw_rad=0.3, v_body=(0.2, 0.0, 0.0), yaw_rate_rad_s=0.1)
    setpoint, _ = c.step(t0, own, inbox)
    _check_invariants(c, setpoint)
    for k in range(1, 21):
        t = t0 + k * DT
        setpoint, out = c.step(t, msgspec.structs.replace(own, t_s=t))
        for m in out:
            encode(m)  # what it sends is finite
    _check_invariants(c, setpoint)


@st.composite
def _batch(draw: st.DrawFn, localization: str = "paper000") -> list[bytes]:
    _, corpus, _ = _warm_team(localization)
    one = st.one_of(mutated(corpus), random_payload(corpus))
    return draw(st.lists(one, min_size=2, max_size=6))


PAPER000_KINDS = {"peer.motion", "peer.bearings", "peer.sfm", "peer.excitation",
                  "peer.localization", "peer.consensus", "peer.angle_localization",
                  "peer.rigidity_eigen"}  # fmt: skip


@pytest.mark.parametrize(
    "localization, kinds",
    [("paper000", PAPER000_KINDS), ("paper002", PAPER000_KINDS | {"peer.gradloc"})],
)
def test_the_warm_team_covers_every_peer_payload_of_its_mode(localization, kinds):
    warm, corpus, _ = _warm_team(localization)
    assert kinds <= set(corpus)
    assert (warm.gradient_localization is not None) == (localization == "paper002")
    if localization == "paper002":  # the fuzzed receiver takes the shares: its tables are warm
        g = warm.gradient_localization
        assert g.rounds > 100 and set(g._w_in) == set(g.in_sources)


@FUZZ
@given(_batch())
def test_random_and_mutated_peer_payloads_never_break_the_core(datas):
    warm, _, t_end = _warm_team()
    _deliver(copy.deepcopy(warm), t_end + DT, datas)


@settings(FUZZ, max_examples=60)
@given(_batch("paper002"))
def test_random_and_mutated_peer_payloads_never_break_a_paper002_core(datas):
    warm, _, t_end = _warm_team("paper002")
    _deliver(copy.deepcopy(warm), t_end + DT, datas)


# ------------------------------------------------------------------ sim topics
class _Link:
    id, known, fleet = TARGET, frozenset(range(N)), "fuzz"

    def subscribe(self, key_expr: str, handler: Any) -> None:
        self.handler = handler


class _Sample:
    def __init__(self, data: bytes) -> None:
        self.payload, self.data = self, data

    def to_bytes(self) -> bytes:
        return self.data


SIM_CORPUS = {
    "camera_bearings": [
        encode(CameraBearings(sender=TARGET, seq=3, stamp_s=5.0, targets=[0, 2],
                              beta_body=[(1.0, 0.0, 0.0), (0.0, 1.0, 0.0)]))
    ],
    "sim_clock": [
        encode(SimClock(sender=0, seq=50, stamp_s=5.0, t_s=5.0, step=2500, speedup=1.0,
                        lockstep=False))
    ],
}  # fmt: skip


@settings(FUZZ, max_examples=50)
@given(st.lists(st.one_of(mutated(SIM_CORPUS), random_payload(SIM_CORPUS)), max_size=6))
def test_random_and_mutated_camera_and_clock_samples_never_break_their_receivers(datas):
    drops = DropCounter()
    follower = SimClockFollower(drop=drops.drop)
    on_clock = sim_clock_handler(follower, drops.drop)
    on_clock(_Sample(SIM_CORPUS["sim_clock"][0]))
    link = _Link()
    camera = SimCameraSource(link, drops, follower.now)
    for data in datas:
        on_clock(_Sample(data))
        link.handler(_Sample(data))
    t = follower.now()
    assert t is not None and abs(t - 5.0) <= 2.0 + 0.2  # no jump got through
    frame = camera.poll()
    for b in frame or ():
        assert b.target in (0, 2) and abs(math.dist(b.beta_body, (0, 0, 0)) - 1.0) <= 1e-3
        assert b.stamp_s <= t + 1.0
    assert camera.age_s(t) >= 0.0


# ------------------------------------------------------------------ command scope
@lru_cache(maxsize=1)
def _command_fleet() -> tuple[Any, Any]:
    """The demo's three-vehicle fleet file (formation-active), loaded once: the daemon's."""
    import tempfile
    from pathlib import Path

    from groundstation.demo import DemoPorts, plan_formation, write_demo_files
    from onboard.daemon.config import load_fleet

    plan = plan_formation(N, seed=1)
    with tempfile.TemporaryDirectory() as d:
        path = write_demo_files(Path(d), plan, DemoPorts(zenoh=1, mavlink=2, gcs=3), "fuzz",
                                "formation-active")  # fmt: skip
        return load_fleet(path), plan


def _slots(p_ned: np.ndarray, yaw_rad: np.ndarray) -> list[FormationSlot]:
    return [
        FormationSlot(id=k, position_ned=tuple(float(x) for x in p_ned[k]),
                      yaw_rad=float(yaw_rad[k]))
        for k in range(N)
    ]  # fmt: skip


def _command_corpus() -> dict[str, list[bytes]]:
    """Valid command-scope payloads for the fuzzed vehicle :data:`TARGET`: formation changes
    (a scale change led by it, a shape change led by another, none led), leader drives (a
    velocity for a time, waypoints, a hold) and every fleet command."""
    _, plan = _command_fleet()
    c = plan.p_ned.mean(axis=0)
    p2 = c + 2.0 * (plan.p_ned - c)
    p_iso = plan.p_ned.copy()
    p_iso[2] += 3.0 * (p_iso[2] - c) / np.linalg.norm(p_iso[2] - c)
    changes = [
        FormationChange(sender=0, seq=1, stamp_s=5.0, target=TARGET, formation_id=9,
                        agents=_slots(p2, plan.yaw_rad), name="double", leader=TARGET,
                        distances=True, ramp_s=0.5),
        FormationChange(sender=0, seq=2, stamp_s=5.0, target=TARGET, formation_id=10,
                        agents=_slots(p_iso, plan.yaw_rad), name="isosceles", leader=0),
        FormationChange(sender=0, seq=3, stamp_s=5.0, target=TARGET, formation_id=11,
                        agents=_slots(plan.p_ned, plan.yaw_rad), ramp_s=0.0),
    ]  # fmt: skip
    drives = [
        LeaderDrive(sender=0, seq=1, stamp_s=5.0, target=TARGET, drive_id=5,
                    velocity_ned=(0.3, -0.1, 0.0), duration_s=4.0),
        LeaderDrive(sender=0, seq=2, stamp_s=5.0, target=TARGET, drive_id=6,
                    waypoints_ned=[(2.0, 0.0, -5.0), (2.0, 2.0, -5.5), (0.0, 0.0, -5.0)],
                    speed_m_s=0.8, tolerance_m=0.2),
        LeaderDrive(sender=0, seq=3, stamp_s=5.0, target=TARGET, drive_id=7),
    ]  # fmt: skip
    commands = [
        FleetCommand(sender=0, seq=k, stamp_s=5.0, target=TARGET, action=a, request_id=40 + k)
        for k, a in enumerate(("start", "hold", "land", "stop"))
    ]
    return {
        "command.formation": [encode(m) for m in changes],
        "command.leader": [encode(m) for m in drives],
        "command": [encode(m) for m in commands],
    }


COMMAND_CORPUS = _command_corpus()
TINY = st.sampled_from([0.0, -0.0, 5e-324, 1e-300, -1e-200, 1e-160, 1e-12, 1e-7])
"""Coordinates near zero: two vehicles this close together have no bearing."""


@st.composite
def collapsed(draw: st.DrawFn) -> bytes:
    """A real formation change with two of its vehicles (almost) at one place near the origin
    (a formation file often has a vehicle at ``(0, 0, 0)``)."""
    raw = msgspec.msgpack.decode(draw(st.sampled_from(COMMAND_CORPUS["command.formation"])))
    k, m = draw(st.permutations(range(N)))[:2]
    at = [draw(TINY) for _ in range(3)]
    near = list(at)
    near[draw(st.integers(0, 2))] = draw(TINY)
    raw["agents"][k]["position_ned"], raw["agents"][m]["position_ned"] = at, near
    return msgspec.msgpack.encode(raw)


@st.composite
def spliced(draw: st.DrawFn) -> bytes:
    """Two real payloads of one kind crossed: one to three fields of the second replace the
    first's (a velocity drive with waypoints, a duration without a velocity, another leader,
    another target, ...), often under a new id."""
    tag = draw(st.sampled_from(sorted(COMMAND_CORPUS)))
    a, b = (msgspec.msgpack.decode(draw(st.sampled_from(COMMAND_CORPUS[tag]))) for _ in "ab")
    fields = sorted(set(b) - {"type", "version", "sender", "seq", "stamp_s"})
    for name in draw(st.lists(st.sampled_from(fields), min_size=1, max_size=3, unique=True)):
        a[name] = b[name]
    if draw(st.booleans()):
        a["target"] = draw(st.sampled_from([0, 2, TARGET]))  # another vehicle's, on this key
    for name in ("formation_id", "drive_id"):
        if name in a and draw(st.booleans()):
            a[name] = draw(st.integers(12, 40))  # a new one: not taken for a repeat
    return msgspec.msgpack.encode(a)


COMMAND_KINDS = {
    "command.formation": FormationChange,
    "command.leader": LeaderDrive,
    "command": FleetCommand,
}


class _Setpoints:
    """The autopilot link as far as the command path uses it (a hold or stop zeroes it)."""

    def __init__(self) -> None:
        self.sent: list[Any] = []

    def set_setpoint(self, sp: Any) -> None:
        self.sent.append(sp)


def _receiver(agent_id: int, drops: DropCounter) -> PeerLink:
    """The daemon's Zenoh link without its session: its command-scope handlers
    (``_on_formation``, ``_on_drive``, ``_on_command``) and what the loop drains are real."""
    import threading
    from collections import deque

    link = PeerLink.__new__(PeerLink)
    link.id, link.drops, link._lock = agent_id, drops, threading.Lock()
    link._commands, link._formation, link._drive = deque(maxlen=100), None, None
    return link


HANDLERS = {"command.formation": "_on_formation", "command.leader": "_on_drive",
            "command": "_on_command"}  # fmt: skip


def _command_outcome(daemon: AgentDaemon, link: PeerLink, topic: str, data: bytes) -> str:
    """Deliver one sample on ``topic``'s key as Zenoh would and let the loop handle it; what
    happened: ``dropped`` (counted), ``adopted``, ``queued`` or ``repeat`` (the id flown now,
    which the ground station repeats until the status shows it)."""
    before = (daemon._formation, daemon._drive_id, daemon.drops.total, daemon._actions.qsize())
    getattr(link, HANDLERS[topic])(_Sample(data))
    daemon._handle_commands()
    formation, drive_id = daemon._formation, daemon._drive_id
    dropped = daemon.drops.total - before[2]
    queued = daemon._actions.qsize() - before[3]
    changed = formation != before[0] or drive_id != before[1]
    assert dropped + queued + changed <= 1, (dropped, queued, changed)
    if dropped:
        return "dropped"
    msg = decode(data, COMMAND_KINDS[topic])  # it got through: the codec took it
    assert msg.target == daemon.id  # and it was this vehicle's
    if queued:
        return "queued"
    if changed:
        if isinstance(msg, FormationChange):
            assert formation == (msg.formation_id, msg.leader)
            assert formation_problem(msg, frozenset(range(N))) == ""
        else:
            assert isinstance(msg, LeaderDrive) and drive_id == msg.drive_id
            assert drive_problem(msg) == "" and formation[1] == daemon.id  # only its leader
        return "adopted"
    repeat = msg.formation_id == before[0][0] if isinstance(msg, FormationChange) else (
        (isinstance(msg, LeaderDrive) and msg.drive_id in (before[1], 0)) or
        msg.drive_id == drive_id
    )  # fmt: skip
    assert repeat, f"{type(msg).__name__} neither adopted nor counted: {msg}"
    return "repeat"


def _fly_commands(daemon: AgentDaemon, t0: float, steps: int = 30) -> None:
    """Step the core (bearings of the planned ring, the odometry position a waypoint drive
    needs) and check that what it flies is finite and bounded and its status publishable."""
    from onboard.autopilot.base import LinkConfig, LinkCounters, StreamState
    from onboard.autopilot.states import Saturated, TelemetryState, snapshot

    _, plan = _command_fleet()
    p, yaw = plan.p_ned, plan.yaw_rad
    others = [j for j in range(N) if j != TARGET]
    b, _ = bearings_body(p, yaw, [(TARGET, j) for j in others])
    ctl, v_max = daemon.core.controller, daemon.core.config.safety.v_max_m_s
    for k in range(steps):
        t = t0 + 0.02 * k
        frame = tuple(BearingMeasurement(j, tuple(b[m]), t) for m, j in enumerate(others))
        own = OwnMeasurements(t_s=t, yaw_rad=float(yaw[TARGET]), v_body=(0.2, 0.0, 0.0),
                              yaw_rate_rad_s=0.05, bearings=frame,
                              position_ned=tuple(float(x) for x in p[TARGET]))  # fmt: skip
        sp, out = daemon.core.step(t, own)
        assert all(math.isfinite(x) for x in (*sp.v_body, sp.yaw_rate_rad_s)), sp
        assert math.hypot(*sp.v_body) <= v_max * (1 + 1e-9)
        for m in out:
            encode(m)  # what it sends is finite
    for (i, j), beta in ctl.desired.items():
        assert abs(math.hypot(*beta) - 1.0) < 1e-6, ((i, j), beta)
    for e, d in ctl.desired_distance.items():
        assert math.isfinite(d) and 0.0 < d <= 4 * POSITION_MAX_M, (e, d)
    assert 0.0 <= ctl.ramp_progress <= 1.0
    tel = snapshot(TelemetryState(), t0, LinkConfig(), 1, StreamState.IDLE,
                   Saturated((0.0, 0.0, 0.0), 0.0, False, False), LinkCounters())  # fmt: skip
    status = daemon._status(t0, tel)
    assert decode(encode(status), VehicleStatus) == status
    assert status.formation_id == daemon._formation[0]
    assert status.leader_drive_id == daemon._drive_id


@st.composite
def _command_batch(draw: st.DrawFn) -> list[tuple[str, bytes]]:
    valid = st.sampled_from([d for datas in COMMAND_CORPUS.values() for d in datas])
    bad = st.one_of(mutated(COMMAND_CORPUS), random_payload(COMMAND_CORPUS), collapsed(), spliced(),
                    st.binary(max_size=40).map(lambda b: b"\x8a" + b))  # fmt: skip
    n = draw(st.integers(1, 8))
    # half of them valid (one_of flattens and weighs its branches alike): the adopted
    # changes and drives interleave with the bad ones
    datas = [draw(valid if draw(st.booleans()) else bad) for _ in range(n)]
    topics = sorted(COMMAND_KINDS)
    # each on its own kind's key, or (a fifth) on another kind's
    return [
        (topic_of(d) if draw(st.integers(0, 4)) else draw(st.sampled_from(topics)), d)
        for d in datas
    ]


def topic_of(data: bytes) -> str:
    """The key a sample's own type goes on (the command key for one that names none)."""
    try:
        tag = msgspec.msgpack.decode(data).get("type")
    except (msgspec.DecodeError, AttributeError):
        return "command"
    return tag if tag in COMMAND_KINDS else "command"


@settings(FUZZ, max_examples=150)
@given(_command_batch())
def test_random_and_mutated_commands_never_break_the_daemon_or_its_core(samples):
    fleet, _ = _command_fleet()
    drops = DropCounter()
    link = _receiver(TARGET, drops)
    daemon = AgentDaemon(fleet, TARGET, _Setpoints(), link, None, None, drops, "fuzz")
    # it leads a scale change: the drives are taken, and the formation flown is not the file's
    lead = COMMAND_CORPUS["command.formation"][0]
    assert _command_outcome(daemon, link, "command.formation", lead) == "adopted"
    outcomes = [_command_outcome(daemon, link, topic, data) for topic, data in samples]
    assert drops.total == outcomes.count("dropped")
    assert all(k.startswith("command_") for k in drops.snapshot()), drops.snapshot()
    _fly_commands(daemon, 6.0)
