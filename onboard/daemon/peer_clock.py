"""Are the neighbours' clocks ours? A check on the stamps of the peer payloads received.

Every peer payload carries its sender's clock (``stamp_s``), and the agent core compares stamps
across vehicles: freshness (``peer_timeout_s``), bearings paired by capture time for the
relative yaw, peer motion interpolated at own instants for the SfM observers. The vehicles'
clocks must therefore agree (chrony/NTP or PTP on real vehicles, docs/flying.md). Nothing in
the estimates shows it when they do not: a peer whose clock runs behind looks like one whose
messages are all stale, a peer ahead pairs bearings captured at different instants.

A receiver sees the apparent delay ``d = t_recv - stamp = latency + (own clock - peer clock)``.
A low quantile of it over a window (the 20th percentile of 2 s) is the clock difference plus
the latency of the faster messages (milliseconds on a network that works), and it ignores what
lasts less than a fifth of the window: a latency burst, or a simulated clock that stalled for
a moment on a loaded machine. A peer is flagged when it is below ``-ahead_tol_s`` (its clock is
ahead) or above ``behind_tol_s`` (behind, or every message older than the core accepts).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass
class _Window:
    start_s: float
    delays_s: list[float] = field(default_factory=list)
    last_s: float = -math.inf
    """When the newest payload arrived (our clock)."""
    last_delay_s: float | None = None
    """The quantile of the apparent delays of the last complete window (``None`` before one)."""


@dataclass
class PeerClockCheck:
    """A low quantile of each peer's apparent message delay per window (module docstring)."""

    ahead_tol_s: float = 0.2
    behind_tol_s: float = 0.5
    window_s: float = 2.0
    quantile: float = 0.2
    _peers: dict[int, _Window] = field(default_factory=dict)

    def observe(self, sender: int, stamp_s: float, recv_s: float) -> None:
        """A payload of ``sender`` stamped ``stamp_s`` (its clock) received at ``recv_s`` (ours)."""
        if not (math.isfinite(stamp_s) and math.isfinite(recv_s)):
            return
        w = self._peers.get(sender)
        if w is None:
            w = self._peers[sender] = _Window(start_s=recv_s)
        if recv_s - w.start_s >= self.window_s:
            w.last_delay_s = float(np.quantile(w.delays_s, self.quantile))
            w.start_s, w.delays_s = recv_s, []
        w.delays_s.append(recv_s - stamp_s)
        w.last_s = max(w.last_s, recv_s)

    def offsets(self, now_s: float) -> dict[int, float]:
        """Per peer heard within the last window and with a complete one: the low quantile of
        its apparent delays (s), i.e. how far its clock is behind ours plus the latency of the
        faster messages. A peer gone silent is forgotten (its liveliness says it is lost, its
        data ages out)."""
        return {
            j: w.last_delay_s
            for j, w in self._peers.items()
            if w.last_delay_s is not None and now_s - w.last_s <= self.window_s
        }

    def skewed(self, now_s: float) -> dict[int, float]:
        """The peers whose clocks disagree with ours, with their apparent delay (:meth:`offsets`)."""
        return {
            j: d
            for j, d in self.offsets(now_s).items()
            if d < -self.ahead_tol_s or d > self.behind_tol_s
        }
