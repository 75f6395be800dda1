"""The peer clock check: a low quantile of the apparent delay of each peer's messages."""

from __future__ import annotations

import math

import numpy as np
import pytest

from onboard.daemon.peer_clock import PeerClockCheck


def _feed(
    check: PeerClockCheck,
    sender: int,
    offset_s: float,
    seconds: float,
    seed: int = 0,
    start_s: float = 100.0,
) -> float:
    """50 Hz messages whose sender's clock is ``offset_s`` behind ours, 2-30 ms latency;
    returns the time of the last one."""
    rng = np.random.default_rng(seed)
    t_send = start_s
    for k in range(int(seconds * 50)):
        t_send = start_s + k / 50  # our clock
        latency = rng.uniform(0.002, 0.03)
        check.observe(sender, t_send - offset_s, t_send + latency)
    return t_send


def test_synchronized_peers_pass_and_skewed_ones_are_named() -> None:
    check = PeerClockCheck()
    _feed(check, 1, 0.0, 5.0)
    _feed(check, 2, 1.5, 5.0)  # behind: every message looks 1.5 s old
    now = _feed(check, 3, -0.5, 5.0)  # ahead: messages from the future
    offsets = check.offsets(now)
    assert 0.0 < offsets[1] < 0.01
    assert offsets[2] == pytest.approx(1.5, abs=0.01)
    assert offsets[3] == pytest.approx(-0.5, abs=0.01)
    assert set(check.skewed(now)) == {2, 3}


def test_nothing_is_reported_before_a_whole_window() -> None:
    check = PeerClockCheck(window_s=2.0)
    now = _feed(check, 1, 3.0, 1.5)
    assert check.offsets(now) == {} and check.skewed(now) == {}
    now = _feed(check, 1, 3.0, 3.0, start_s=101.5)
    assert set(check.skewed(now)) == {1}


def test_a_silent_peer_is_forgotten() -> None:
    """A skewed peer that died must not hold its team forever: its liveliness reports it."""
    check = PeerClockCheck(window_s=2.0)
    now = _feed(check, 1, 3.0, 5.0)
    assert set(check.skewed(now)) == {1}
    assert check.skewed(now + 2.5) == {}


def test_a_latency_burst_is_not_a_clock_error() -> None:
    """Messages delayed by a stalled loop for a second, among timely ones, do not trip it."""
    check = PeerClockCheck()
    for k in range(300):
        t_send = k / 50
        stalled = 1.0 <= t_send < 2.0
        check.observe(1, t_send, (2.0 if stalled else t_send) + 0.01)
    assert check.offsets(6.0)[1] == pytest.approx(0.01)
    assert check.skewed(6.0) == {}


def test_a_moment_of_clock_disagreement_is_not_flagged() -> None:
    """A simulated clock that stalls for 0.3 s on a loaded machine (messages from the future
    for a moment) is not a clock error; a lasting one is."""
    check = PeerClockCheck()
    for k in range(300):
        t = k / 50
        glitch = 1.0 if 3.0 <= t < 3.3 else 0.0
        check.observe(1, t + glitch, t + 0.01)
    assert check.skewed(6.0) == {}
    for k in range(300):
        t = 6.0 + k / 50
        check.observe(1, t + 1.0, t + 0.01)
    assert set(check.skewed(12.0)) == {1}


def test_the_check_recovers_once_the_clocks_agree() -> None:
    check = PeerClockCheck()
    now = _feed(check, 1, 2.0, 5.0)
    assert 1 in check.skewed(now)
    now = _feed(check, 1, 0.0, 5.0, start_s=105.0)  # chrony stepped the peer's clock
    assert check.skewed(now) == {}


def test_non_finite_stamps_are_ignored() -> None:
    check = PeerClockCheck()
    _feed(check, 1, 0.0, 3.0)
    check.observe(1, math.nan, 103.0)
    check.observe(1, -math.inf, 103.0)
    now = _feed(check, 1, 0.0, 3.0, seed=1, start_s=103.0)
    assert check.offsets(now)[1] < 0.01 and check.skewed(now) == {}
