"""Relative yaw on a reciprocal edge from the exchanged bearing pair (paper 000 Sect. III-C).

Agents share no frame, but on a reciprocal edge ``iR_j beta_ji = -beta_ij`` gives
``psi_ij = psi_j - psi_i`` directly (:func:`onboard.geometry.relative_yaw`, paper 002 fig. 6),
provided the bearings are not vertical. Camera frames are only 30-50 Hz, reach the neighbour
late, and the two cameras are not synchronized (nor, exactly, the two clocks: real SITL
instances differ by 10-20 ms), so each agent pairs frames by capture stamp, interpolating the
other side's bearing and yaw between its two frames around the stamp (:func:`sample_at`), and
turns every pair into an *offset* between the two vehicles' own odometry yaws:

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
MAX_INTERPOLATION_GAP_S = 0.1
"""Longest interval between two frames of one side across which its bearing and yaw are
interpolated to the other side's stamp (three frames at 30 Hz: a dropped frame or two)."""
PAIR_HISTORY = 16
"""Frames of each side kept for pairing."""

Sample = tuple[float, float, Vec3]
"""One frame of one side: ``(stamp_s, odometry yaw_rad, unit bearing to the other side)``."""


def yaw_offset(beta_ij: Vec3, beta_ji: Vec3, yaw_i_rad: float, yaw_j_rad: float) -> float:
    """Offset between the two odometry yaws implied by one simultaneous reciprocal pair.

    ``psi_ij`` is :func:`onboard.geometry.relative_yaw` in scalar float math (equal to
    rounding: it runs for every shared frame, where numpy's per-call overhead was most of the
    cost)."""
    psi_ij = (
        math.atan2(-beta_ij[1], -beta_ij[0]) - math.atan2(beta_ji[1], beta_ji[0]) + math.pi
    ) % math.tau - math.pi
    return wrap_rad(psi_ij - (yaw_j_rad - yaw_i_rad))


def sample_at(
    samples: deque[Sample],
    t_s: float,
    tolerance_s: float = STAMP_TOLERANCE_S,
    max_gap_s: float = MAX_INTERPOLATION_GAP_S,
    counterpart: deque[Sample] | None = None,
) -> Sample | None:
    """One side's frame at stamp ``t_s``: its frame within ``tolerance_s`` of ``t_s`` if there
    is one, else the two frames around ``t_s`` (at most ``max_gap_s`` apart) interpolated
    linearly (the yaw on the circle, the bearing renormalized); ``None`` when ``t_s`` is outside
    ``samples`` (oldest first) or in a longer gap, and when the two frames around it each
    have a frame of ``counterpart`` (the side ``t_s`` comes from) within ``tolerance_s``: the
    two cameras are then synchronized, and a frame without a counterpart at its stamp is one
    whose counterpart was lost or not seen (as the compiled engine, :mod:`sim.team_kernel`,
    pairs them).

    Between frames 33 ms apart the interpolation error of a bearing turning at ``w`` rad/s
    with angular acceleration ``a`` is at most ``a dt^2 / 8``: far below the camera noise for
    a formation's motion, where taking the nearest frame instead would err by ``w dt / 2``."""
    before = after = None
    for s in samples:
        if s[0] <= t_s:
            before = s
        else:
            after = s
            break
    near = [s for s in (before, after) if s is not None and abs(s[0] - t_s) <= tolerance_s]
    if near:
        return min(near, key=lambda s: abs(s[0] - t_s))
    if before is None or after is None or after[0] - before[0] > max_gap_s:
        return None
    if counterpart is not None and all(
        any(abs(c[0] - s[0]) <= tolerance_s for c in counterpart) for s in (before, after)
    ):
        return None
    w = (t_s - before[0]) / (after[0] - before[0])
    yaw = before[1] + w * math.remainder(after[1] - before[1], math.tau)
    b = tuple(x + w * (y - x) for x, y in zip(before[2], after[2], strict=True))
    norm = math.sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2])
    if not norm > 0.0:
        return None
    return t_s, yaw, (b[0] / norm, b[1] / norm, b[2] / norm)


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
    max_gap_s: float = MAX_INTERPOLATION_GAP_S
    history: int = PAIR_HISTORY
    _own: deque[Sample] = field(default_factory=deque)
    _peer: deque[Sample] = field(default_factory=deque)
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
        self, mine: deque[Sample], sample: Sample, other: deque[Sample], own_first: bool
    ) -> None:
        """Keep ``sample`` and pair it with the other side at its stamp (:func:`sample_at`),
        and pair the other side's frames that ``sample`` now brackets: frames of either side
        arrive in any order and late, and each frame is paired once, when its pair is known."""
        if mine and sample[0] <= mine[-1][0]:
            return
        prev_s = mine[-1][0] if mine else None
        mine.append(sample)
        if len(mine) > self.history:
            mine.popleft()
        tol, gap_s = self.stamp_tolerance_s, self.max_gap_s
        match = sample_at(other, sample[0], tol, gap_s, mine)
        if match is not None:
            self._pair(sample, match, own_first)
        if prev_s is None:
            return
        for theirs in other:  # bracketed only now, and not matched to either frame by stamp
            if prev_s + tol < theirs[0] < sample[0] - tol:
                ours = sample_at(mine, theirs[0], tol, gap_s, other)
                if ours is not None:
                    self._pair(ours, theirs, own_first)

    def _pair(self, mine: Sample, theirs: Sample, own_first: bool) -> None:
        own, peer = (mine, theirs) if own_first else (theirs, mine)
        if is_usable_pair(own[2], peer[2]):
            self._update(yaw_offset(own[2], peer[2], own[1], peer[1]))

    def _update(self, offset: float) -> None:
        self._cos, self._sin, self.offset_rad = filter_offset(
            self._cos, self._sin, self.offset_rad is None, offset, self.gain
        )
        self.pairs += 1
