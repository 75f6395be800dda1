"""The lost-peers rule (issue 23, defect 6): a stalled vehicle keeps its liveliness token but
goes silent; its peers count it lost after the loss time and raise ``peer_lost:<id>`` (and the
rigidity guard decides whether the rest fly); it rejoins when it speaks again. Pure logic, the
daemon's clock given."""

from __future__ import annotations

from messages.vocabulary import Alarm, alarm_text
from onboard.daemon.guards import GuardInput, LostPeersGuard
from onboard.daemon.presence import PeerPresence

HOLD_S = 2.0


def _heard_every(p: PeerPresence, ids: list[int], t0: float, t1: float, dt: float = 0.02) -> None:
    """Tokens of ``ids`` present and their payloads arriving every ``dt`` from t0 to t1."""
    t = t0
    while t <= t1 + 1e-9:
        p.update(ids, t)
        for j in ids:
            p.heard(j, t)
        t += dt


def test_a_silent_peer_with_its_token_is_lost_and_rejoins() -> None:
    p = PeerPresence([0, 1, 2], own_id=0, hold_s=HOLD_S)
    _heard_every(p, [1, 2], 0.0, 5.0)
    assert p.lost(5.0) == []
    # agent 1 stalls at t = 5: its token stays, its payloads stop
    for t in (5.5, 6.5, 6.99):
        p.update([1, 2], t)
        p.heard(2, t)
        assert p.lost(t) == [], t
    p.update([1, 2], 7.0)
    assert p.lost(7.0) == [1] and p.silent(7.0) == [1]
    verdict = LostPeersGuard().check(GuardInput(lost_peers=tuple(p.lost(7.0))))
    assert verdict.alarms == (alarm_text(Alarm.PEER_LOST, 1),)
    # it resumes: one payload and it is back
    p.heard(1, 8.0)
    p.update([1, 2], 8.0)
    assert p.lost(8.0) == []


def test_a_token_gone_is_lost_after_the_hold_as_before() -> None:
    p = PeerPresence([0, 1, 2], own_id=0, hold_s=HOLD_S)
    p.update([1, 2], 0.0)  # tokens only: payloads never heard (a graph id we do not subscribe to)
    p.update([2], 1.0)
    assert p.lost(2.9) == []
    assert p.lost(3.0) == [1] and p.silent(3.0) == []
    p.update([1, 2], 3.5)
    assert p.lost(3.5) == []


def test_never_seen_peers_and_our_own_id_are_not_lost() -> None:
    p = PeerPresence([0, 1, 2], own_id=0, hold_s=HOLD_S)
    p.update([0], 0.0)
    p.heard(0, 0.0)
    assert p.lost(100.0) == []


def test_after_our_own_stall_the_ages_restart() -> None:
    """The stalled daemon itself resumes with every peer's last payload 3 s old: they were not
    silent, it was; no false ``peer_lost`` while their buffered payloads arrive."""
    p = PeerPresence([0, 1, 2], own_id=0, hold_s=HOLD_S)
    _heard_every(p, [1, 2], 0.0, 5.0)
    p.restart(8.0)  # we were stopped from 5 to 8
    p.update([1, 2], 8.0)
    assert p.lost(8.0) == []
    assert p.lost(10.0) == [1, 2]  # ... but peers that stay silent are still lost
