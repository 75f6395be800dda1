"""The daemon's peer link with envelopes (issue 27): one sample per publish tick goes out, and
what comes in reaches the inbox as the individual payloads, every drop counted by reason
(:class:`onboard.daemon.peers.PeerLink`, without a Zenoh session)."""

import random
import threading
from collections import deque
from typing import Any

import msgspec
import numpy as np

from messages.codec import encode_unchecked
from messages.envelope import PeerEnvelope, pack, unpack
from messages.peer import LocalizationState, MotionShare
from messages.rigidity import RigidityEigenShare
from onboard.daemon.peers import DropCounter, PeerLink


class _Bytes:
    def __init__(self, data: bytes) -> None:
        self._data = data

    def to_bytes(self) -> bytes:
        return self._data


class _Sample:
    def __init__(self, key: str, data: bytes) -> None:
        self.key_expr, self.payload = key, _Bytes(data)


def _link(agent_id: int = 0, inject_loss: float = 0.0) -> PeerLink:
    link = PeerLink.__new__(PeerLink)
    link.fleet, link.id, link.known = "alpha", agent_id, frozenset(range(3))
    link.drops, link._lock = DropCounter(), threading.Lock()
    link.inject_loss, link._loss_rng = inject_loss, random.Random(agent_id)
    link._inbox, link._envelope_seq = deque(maxlen=10_000), 0
    link.decode, link.encode = unpack, pack
    link.sent = []  # type: ignore[attr-defined]
    link._put = lambda k, d: link.sent.append((k, d))  # type: ignore[attr-defined,method-assign]
    return link


def _motion(sender: int, seq: int, **kw: Any) -> MotionShare:
    fields = {"v_body": (0.1, 0.0, 0.0), "yaw_rate_rad_s": 0.0, "yaw_rad": 0.0, **kw}
    return MotionShare(sender=sender, seq=seq, stamp_s=1.0 + seq / 100, **fields)


def _loc(sender: int, seq: int) -> LocalizationState:
    return LocalizationState(
        sender=sender, seq=seq, stamp_s=1.0, p_hat_ned=(1.0, 0.0, -2.0), yaw_hat_rad=0.1
    )


def _eigen(sender: int, seq: int) -> RigidityEigenShare:
    return RigidityEigenShare(sender=sender, seq=seq, stamp_s=1.0, lambda_hat=0.2, targets=[0],
                              state=np.ones(2), per_target=np.ones(2))  # fmt: skip


def test_publish_sends_one_envelope_on_one_key_per_tick():
    link = _link(1)
    nan = _loc(1, 2)
    nan = msgspec.structs.replace(nan, yaw_hat_rad=float("nan"))
    assert link.publish([_motion(1, 1), _motion(1, 2), _loc(1, 1), nan, _eigen(1, 2)]) == 2
    assert [k for k, _ in link.sent] == ["bf/alpha/1/peer"]
    got = unpack(link.sent[0][1], sender=1)
    assert [(type(p), p.seq) for p in got.payloads] == [(MotionShare, 2), (RigidityEigenShare, 2)]
    assert link.drops.snapshot() == {"own_nonfinite": 1}  # the NaN localization stayed home
    link.publish([_motion(1, 3)])
    assert unpack(link.sent[1][1]).seq == got.seq + 1


def test_received_envelopes_reach_the_inbox_as_payloads():
    link = _link(0)
    on_1 = link._on_peer(1)
    on_1(_Sample("bf/alpha/1/peer", pack(1, 1, [_motion(1, 1), _loc(1, 1)]).data))
    forged = encode_unchecked(PeerEnvelope(sender=1, payloads=[_motion(1, 2), _loc(2, 2)]))
    on_1(_Sample("bf/alpha/1/peer", forged))
    on_1(_Sample("bf/alpha/1/peer", b"\xc1 not msgpack"))
    on_1(_Sample("bf/alpha/1/peer", pack(2, 3, [_motion(2, 3)]).data))  # 2's on 1's key
    inbox = link.drain()
    assert [(type(p), p.sender, p.seq) for p in inbox] == [
        (MotionShare, 1, 1), (LocalizationState, 1, 1), (MotionShare, 1, 2)
    ]  # fmt: skip
    assert link.drops.snapshot() == {"sender_mismatch": 2, "malformed": 1}


def test_listen_kinds_keeps_only_those_kinds():
    link = _link(0)
    on_2 = link._on_peer(2, frozenset({"rigidity_eigen"}))
    on_2(_Sample("bf/alpha/2/peer", pack(2, 1, [_motion(2, 1), _eigen(2, 1)]).data))
    assert [type(p) for p in link.drain()] == [RigidityEigenShare]
    assert link.drops.total == 0


def test_injected_loss_drops_whole_envelopes():
    link = _link(0, inject_loss=0.5)
    on_1 = link._on_peer(1)
    n = 400
    for k in range(n):
        on_1(_Sample("bf/alpha/1/peer", pack(1, k, [_motion(1, k), _loc(1, k)]).data))
    lost = link.drops.snapshot()["injected_loss"]
    inbox = link.drain()
    assert len(inbox) == 2 * (n - lost)  # a tick's kinds are lost together
    assert 0.4 * n < lost < 0.6 * n
