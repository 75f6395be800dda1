"""Replay protection (issue 23, defect 11): per-sender sequence-number windows."""

from __future__ import annotations

from messages.peer import LocalizationState, MotionShare
from onboard.daemon.peer_clock import PeerClockCheck
from onboard.daemon.replay import SEQ_WINDOW, SeqWindow


def test_duplicates_old_and_far_ahead_numbers_are_dropped_per_sender_and_kind():
    w = SeqWindow()
    assert w.admit(1, MotionShare, 10, 1.0, 1.0) is None
    assert w.admit(1, MotionShare, 10, 1.0, 1.0) == "seq_replay"  # duplicate
    assert w.admit(1, MotionShare, 4, 1.0, 1.0) == "seq_replay"  # older
    assert w.admit(1, MotionShare, 13, 1.0, 1.0) is None  # a gap is normal
    assert w.admit(1, MotionShare, 13 + SEQ_WINDOW + 1, 9.0, 1.0) == "seq_window"
    assert w.admit(1, MotionShare, 14, 1.0, 1.0) is None  # the real sender is not locked out
    assert w.admit(1, LocalizationState, 14, 1.0, 1.0) is None  # kinds are separate
    assert w.admit(2, MotionShare, 3, 1.0, 1.0) is None  # so are senders
    assert len(w) == 3


def test_a_restarted_sender_is_followed_again_but_not_a_replay_of_old_captures():
    w = SeqWindow()
    for k in range(100):
        assert w.admit(1, MotionShare, 1000 + k, 10.0 + 0.01 * k, 10.0 + 0.01 * k) is None
    now = 20.0
    # a replay of the old captures: old stamps never resynchronize the window
    assert {w.admit(1, MotionShare, 1000 + k, 10.0 + 0.01 * k, now) for k in range(50)} == {
        "seq_replay"
    }
    # the sender restarted: its numbers start again at 0, freshly stamped
    reasons = [w.admit(1, MotionShare, k, now + 0.01 * k, now + 0.01 * k) for k in range(6)]
    assert reasons == ["seq_replay"] * 4 + ["seq_resync", None]


def test_a_replay_at_eight_times_the_rate_no_longer_flags_the_senders_clock():
    """What held the team: replayed samples of a peer (old stamps) dominated the apparent delay
    of its messages, so the receiver flagged its clock (``peer_clock``) and held."""
    window, check = SeqWindow(), PeerClockCheck()
    captured = [(k, 0.02 * k) for k in range(200)]  # 4 s of a peer's samples at 50 Hz
    seq = 200
    for tick in range(300):  # 6 s more: the live stream and, 8 per tick, the replay
        now = 4.0 + 0.02 * tick
        stream = [(seq + tick, now - 0.005)]
        stream += [captured[(8 * tick + m) % len(captured)] for m in range(8)]
        for s, stamp in stream:
            if window.admit(1, MotionShare, s, stamp, now) is None:
                check.observe(1, stamp, now)
    assert check.skewed(now) == {}
    unfiltered = PeerClockCheck()  # the same traffic without the window: flagged
    for tick in range(300):
        now = 4.0 + 0.02 * tick
        for m in range(8):
            unfiltered.observe(1, captured[(8 * tick + m) % len(captured)][1], now)
        unfiltered.observe(1, now - 0.005, now)
    assert 1 in unfiltered.skewed(now)


def test_a_replay_of_recent_captures_never_resynchronizes_but_a_clock_reset_does():
    w = SeqWindow()
    for k in range(100):
        assert w.admit(1, MotionShare, 1000 + k, 100.0 + 0.01 * k, 100.0 + 0.01 * k) is None
    now = 100.99
    # the last 0.5 s, captured and replayed at once: fresh stamps, but none newer than the
    # last accepted one
    replay = {w.admit(1, MotionShare, 1000 + k, 100.0 + 0.01 * k, now) for k in range(50, 100)}
    assert replay == {"seq_replay"}
    # the simulator restarted: the receiver's clock and the sender's numbers and stamps restart
    reasons = [w.admit(1, MotionShare, k, 0.01 * k, 0.01 * k) for k in range(6)]
    assert reasons == ["seq_replay"] * 4 + ["seq_resync", None]
