"""Property-based fuzzing of every receiver (issue 23): random and mutated payloads of every
message type go through the codec and, when accepted, the replay window and into a warm agent
core's step. Invariants: no exception escapes, no estimate becomes non-finite, every table
stays within its bound, and the status is always publishable. Bounded (a fixed number of
derandomized examples) so the suite stays in the fast tier."""

from __future__ import annotations

import copy
import math
from functools import lru_cache
from typing import Any

import msgspec
import numpy as np
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from messages.agent import AgentStatus, BearingMeasurement, OwnMeasurements
from messages.codec import MessageError, Payload, decode, encode
from messages.peer import PeerPayload
from messages.sim import CameraBearings, SimClock
from onboard.core.agent import AgentCore
from onboard.core.config import AgentConfig, build_config
from onboard.core.scale import CONSENSUS_NAMES
from onboard.daemon.bearings import SimCameraSource
from onboard.daemon.clock import SimClockFollower, sim_clock_handler
from onboard.daemon.peers import DropCounter
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


def _configs() -> list[AgentConfig]:
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


@lru_cache(maxsize=1)
def _warm_team() -> tuple[AgentCore, dict[str, list[bytes]], float]:
    """Three cores flown for 1 s with every payload through the codec: the fuzzed receiver
    (warm, with every table filled) and a corpus of real payloads of every kind."""
    from onboard.geometry import rot_z

    cores = [AgentCore(c) for c in _configs()]
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
def _batch(draw: st.DrawFn) -> list[bytes]:
    _, corpus, _ = _warm_team()
    one = st.one_of(mutated(corpus), random_payload(corpus))
    return draw(st.lists(one, min_size=2, max_size=6))


def test_the_warm_team_covers_every_peer_payload_of_its_mode():
    _, corpus, _ = _warm_team()
    assert {"peer.motion", "peer.bearings", "peer.sfm", "peer.excitation", "peer.localization",
            "peer.consensus", "peer.angle_localization", "peer.rigidity_eigen"} <= set(corpus)  # fmt: skip


@FUZZ
@given(_batch())
def test_random_and_mutated_peer_payloads_never_break_the_core(datas):
    warm, _, t_end = _warm_team()
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
