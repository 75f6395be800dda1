"""The camera layer: the vehicle's own bearings, the neighbours' bearings of it, and the
relative yaws they give (paper 000 Sect. III; :mod:`onboard.estimation.relative_yaw`).

Every mode has it. Per step it records the own odometry (for the yaw at a frame's capture
time), takes the new camera frame (stale, future-stamped and non-unit bearings are counted and
dropped), feeds the relative-yaw trackers of the edges it was given, and publishes the frame as
:class:`messages.peer.BearingShare`. What neighbours measured of this vehicle is kept newest by
stamp (``beta_ji``, used by localization eq. 6 and the formation law).

The ranges of the own measurements (``own.ranges``: the camera's disc ranges, paper 002 eq. 22)
to out-edge targets are kept the same way, newest per target (:attr:`Bearings.range_out`); a
range that is not finite or outside :func:`messages.limits.plausible_range` is counted
(``bad_range``) and dropped, one stamped too far ahead ``future_stamp``. Users check freshness
by stamp, as for the bearings. Paper 003's layer reads ``own.ranges`` itself.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

from messages.codec import Payload
from messages.limits import plausible_range, stamp_ahead
from messages.peer import BearingShare, TargetBearing
from messages.vocabulary import DropReason
from onboard.core.config import Graph
from onboard.core.layer import Command, Own, Vec3
from onboard.core.peers import Drops, Route
from onboard.estimation.relative_yaw import RelativeYawEdge
from onboard.estimation.time_alignment import SignalHistory

MAX_ODOMETRY_GAP_S = 0.25
"""Longest gap between two own (or a peer's) odometry samples the SfM observers integrate across
(an autopilot streams 20-50 Hz); across a longer one they resynchronize after it."""


def finite(v: Iterable[float]) -> bool:
    """Whether every value is finite."""
    return all(math.isfinite(x) for x in v)


class Bearings:
    """Own and received bearings, own odometry history, relative yaws (module docstring)."""

    def __init__(self, graph: Graph, neighbours: frozenset[int], yaw_peers: list[int],
                 drops: Drops) -> None:  # fmt: skip
        me = graph.agent_id
        self.id = me
        self.out_targets = sorted({j for i, j in graph.edges if i == me})
        self.in_sources = sorted({i for i, j in graph.edges if j == me})
        self.routes = {BearingShare: Route(neighbours, self.take)}
        self._yaw_peers = list(yaw_peers)
        self._drops = drops
        self.yaw_edges = {j: RelativeYawEdge() for j in yaw_peers}
        """Relative-yaw tracker per reciprocal edge (the scale layer's)."""
        self.own_hist = SignalHistory(angle_index=4)
        """Own ``(u_x, u_y, u_z, w, yaw)`` by odometry stamp."""
        self.beta_out: dict[int, tuple[float, Vec3]] = {}
        """Target -> (stamp, own bearing of it), newest frame."""
        self.beta_in: dict[int, tuple[float, Vec3]] = {}
        """Neighbour ``j`` -> (stamp, ``beta_ji``), newest by stamp."""
        self.range_out: dict[int, tuple[float, float]] = {}
        """Target -> (stamp, measured range m), newest by stamp (module docstring)."""
        self._last_range_s = -math.inf
        self.new_frames: list[tuple[int, float, Vec3]] = []
        """``(target, stamp, beta)`` of this step's new frame."""
        self._last_frame_s = -math.inf

    def take(self, j: int, msg: BearingShare) -> bool:
        """Keep ``beta_ji`` newest by stamp and feed the relative-yaw tracker."""
        for b in msg.bearings:
            if b.target == self.id:
                beta = tuple(b.beta_body)
                prev = self.beta_in.get(j)
                if prev is None or msg.stamp_s > prev[0]:
                    self.beta_in[j] = (msg.stamp_s, beta)
                if j in self.yaw_edges:
                    self.yaw_edges[j].add_peer(msg.stamp_s, msg.yaw_rad, beta)
        return True

    def step(self, own: Own, outbox: list[Payload]) -> Command | None:
        """Record the odometry, take the new frame, share it."""
        self.own_hist.add(own.odometry_stamp_s, (*own.v_body, own.yaw_rate_rad_s, own.yaw_rad))
        self._take_frame(own, outbox)
        if own.raw.ranges:
            self._take_ranges(own)
        return None

    def _take_ranges(self, own: Own) -> None:
        newest = self._last_range_s
        for r in own.raw.ranges:
            try:
                stamp, range_m = float(r.stamp_s), float(r.range_m)
            except (TypeError, ValueError):
                stamp, range_m = math.nan, math.nan
            if not math.isfinite(stamp):
                self._drops.count(DropReason.BAD_RANGE)
                continue
            if stamp <= self._last_range_s or r.target not in self.out_targets:
                continue  # seen before: a bad one is counted once
            if stamp_ahead(stamp, own.raw.t_s):
                self._drops.count(DropReason.FUTURE_STAMP)
                continue
            newest = max(newest, stamp)
            if not plausible_range(range_m):
                self._drops.count(DropReason.BAD_RANGE)
                continue
            prev = self.range_out.get(r.target)
            if prev is None or stamp > prev[0]:
                self.range_out[r.target] = (stamp, range_m)
        self._last_range_s = newest

    def _take_frame(self, own: Own, outbox: list[Payload]) -> None:
        yaw_own = own.yaw_rad
        fresh: list[tuple[int, float, Vec3]] = []
        newest = self._last_frame_s
        self.new_frames = fresh
        for b in own.raw.bearings:
            if b.stamp_s <= self._last_frame_s or b.target not in self.out_targets:
                continue
            if stamp_ahead(b.stamp_s, own.raw.t_s):  # would blind the camera for good
                self._drops.count(DropReason.FUTURE_STAMP)
                continue
            newest = max(newest, b.stamp_s)  # a bad detection is counted once, not every step
            try:
                beta = (float(b.beta_body[0]), float(b.beta_body[1]), float(b.beta_body[2]))
            except (TypeError, ValueError, IndexError):
                beta = (math.nan,) * 3
            if not finite(beta) or abs(beta[0] ** 2 + beta[1] ** 2 + beta[2] ** 2 - 1.0) > 1e-3:
                self._drops.count(DropReason.BAD_BEARING)
                continue
            fresh.append((b.target, float(b.stamp_s), beta))
        self._last_frame_s = newest
        if not fresh:
            return
        stamp = max(s for _, s, _ in fresh)
        for target, s, beta in fresh:
            self.beta_out[target] = (s, beta)
            if target in self.yaw_edges:
                self.yaw_edges[target].add_own(s, self.yaw_at(s, yaw_own), beta)
        outbox.append(
            BearingShare(
                sender=self.id,
                seq=own.seq,
                stamp_s=stamp,
                yaw_rad=self.yaw_at(stamp, yaw_own),
                bearings=[TargetBearing(t, b) for t, _, b in fresh],
            )
        )

    def yaw_at(self, stamp_s: float, yaw_now: float) -> float:
        """Own odometry yaw when a frame was captured: a frame reaches the core 10-150 ms late
        (Zenoh, image processing) and pairing it with the yaw of its arrival biases the
        relative yaw by ``yaw rate x latency``."""
        hist = self.own_hist
        sample = hist.at(stamp_s)
        if sample is None:
            return yaw_now
        if stamp_s > hist.newest_s:  # captured after the newest odometry: extrapolate
            return sample[4] + sample[3] * min(stamp_s - hist.newest_s, MAX_ODOMETRY_GAP_S)
        return sample[4]

    def finish(self, own: Own, outbox: list[Payload]) -> None:
        return None

    def forget_time(self) -> None:
        self.own_hist = SignalHistory(angle_index=4)
        self.yaw_edges = {j: RelativeYawEdge() for j in self._yaw_peers}
        self.beta_in.clear()
        self.beta_out.clear()
        self.range_out.clear()
        self._last_range_s = -math.inf
        self.new_frames = []
        self._last_frame_s = -math.inf

    def status(self) -> dict[str, Any]:
        return {}
