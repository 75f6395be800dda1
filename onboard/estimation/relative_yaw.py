"""Relative yaw on a reciprocal edge from the exchanged bearing pair (paper 000 Sect. III-C).

Agents share no frame, but on a reciprocal edge ``iR_j beta_ji = -beta_ij`` gives
``psi_ij = psi_j - psi_i`` directly (:func:`onboard.geometry.relative_yaw`, paper 002 fig. 6),
provided the bearings are not vertical. Camera frames are only 50 Hz and reach the neighbour
late, so each agent pairs frames by capture stamp and turns every pair into an *offset*
between the two vehicles' own odometry yaws:

    offset_ij = relative_yaw(beta_ij, beta_ji) - (yaw_j - yaw_i)      (both at the same stamp),

which is constant when the odometry yaws are drift-free integrals of the yaw rates. Between
frames ``psi_ij(t) = yaw_j(t) - yaw_i(t) + offset_ij`` is then exact for any motion, and the
offset is low-pass filtered on the circle to average bearing noise.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from onboard.estimation.angles import wrap_rad

Vec3 = tuple[float, float, float]

MIN_HORIZONTAL = 0.1
"""Pairs whose bearings have a smaller horizontal norm are too close to vertical and ignored."""
FILTER_GAIN = 0.2
"""Weight of a new pair in the circular low-pass filter of the offset (1 = no filtering)."""
STAMP_TOLERANCE_S = 0.005
"""Largest stamp difference of an own and a peer frame that still make a pair."""
PAIR_HISTORY = 16
"""Frames of each side kept for pairing."""


def yaw_offset(beta_ij: Vec3, beta_ji: Vec3, yaw_i_rad: float, yaw_j_rad: float) -> float:
    """Offset between the two odometry yaws implied by one simultaneous reciprocal pair.

    ``psi_ij`` is :func:`onboard.geometry.relative_yaw` in scalar float math (equal to
    rounding: it runs for every shared frame, where numpy's per-call overhead was most of the
    cost)."""
    psi_ij = (
        math.atan2(-beta_ij[1], -beta_ij[0]) - math.atan2(beta_ji[1], beta_ji[0]) + math.pi
    ) % math.tau - math.pi
    return wrap_rad(psi_ij - (yaw_j_rad - yaw_i_rad))


def relative_yaw_now(yaw_i_rad: float, yaw_j_rad: float, offset_rad: float) -> float:
    """``psi_ij = psi_j - psi_i`` (wrapped) from the two current odometry yaws and the offset."""
    return wrap_rad(yaw_j_rad - yaw_i_rad + offset_rad)


def filter_offset(
    cos_prev: float, sin_prev: float, first: bool, offset_rad: float, gain: float = FILTER_GAIN
) -> tuple[float, float, float]:
    """Circular low-pass filter of the offset: the unit vector ``(cos, sin)`` moves a fraction
    ``gain`` towards the new pair's (``first``: it starts there). Returns the filter's new
    ``(cos, sin)`` and its angle."""
    c, s = math.cos(offset_rad), math.sin(offset_rad)
    if not first:
        c = cos_prev + gain * (c - cos_prev)
        s = sin_prev + gain * (s - sin_prev)
    return c, s, math.atan2(s, c)


def is_usable_pair(beta_ij: Vec3, beta_ji: Vec3, min_horizontal: float = MIN_HORIZONTAL) -> bool:
    """Both bearings far enough from the vertical for the horizontal angle to be meaningful."""
    return (
        math.hypot(beta_ij[0], beta_ij[1]) >= min_horizontal
        and math.hypot(beta_ji[0], beta_ji[1]) >= min_horizontal
    )


@dataclass(slots=True)
class RelativeYawEdge:
    """Relative-yaw tracker of one reciprocal edge, kept by both of its agents.

    Call :meth:`add_own` with each own frame's bearing to the neighbour and :meth:`add_peer`
    with each frame the neighbour shares; :meth:`psi` returns ``psi_j - psi_i`` at any time
    from the two current odometry yaws, or ``None`` until one pair has been matched.
    """

    gain: float = FILTER_GAIN
    """Weight of a new pair in the circular low-pass filter of the offset (1 = no filtering)."""
    stamp_tolerance_s: float = STAMP_TOLERANCE_S
    history: int = PAIR_HISTORY
    _own: deque[tuple[float, float, Vec3]] = field(default_factory=deque)
    _peer: deque[tuple[float, float, Vec3]] = field(default_factory=deque)
    _cos: float = 0.0
    _sin: float = 0.0
    offset_rad: float | None = None
    pairs: int = 0

    def add_own(self, stamp_s: float, yaw_i_rad: float, beta_ij: Vec3) -> None:
        self._add(self._own, (stamp_s, yaw_i_rad, beta_ij), self._peer, own_first=True)

    def add_peer(self, stamp_s: float, yaw_j_rad: float, beta_ji: Vec3) -> None:
        self._add(self._peer, (stamp_s, yaw_j_rad, beta_ji), self._own, own_first=False)

    def psi(self, yaw_i_rad: float, yaw_j_rad: float) -> float | None:
        """Current ``psi_ij = psi_j - psi_i`` (rad, wrapped) from the two odometry yaws."""
        if self.offset_rad is None:
            return None
        return relative_yaw_now(yaw_i_rad, yaw_j_rad, self.offset_rad)

    def _add(
        self,
        mine: deque[tuple[float, float, Vec3]],
        sample: tuple[float, float, Vec3],
        other: deque[tuple[float, float, Vec3]],
        own_first: bool,
    ) -> None:
        if mine and sample[0] <= mine[-1][0]:
            return
        mine.append(sample)
        if len(mine) > self.history:
            mine.popleft()
        match = min(other, key=lambda s: abs(s[0] - sample[0]), default=None)
        if match is None or abs(match[0] - sample[0]) > self.stamp_tolerance_s:
            return
        own, peer = (sample, match) if own_first else (match, sample)
        if not is_usable_pair(own[2], peer[2]):
            return
        self._update(yaw_offset(own[2], peer[2], own[1], peer[1]))

    def _update(self, offset: float) -> None:
        self._cos, self._sin, self.offset_rad = filter_offset(
            self._cos, self._sin, self.offset_rad is None, offset, self.gain
        )
        self.pairs += 1
