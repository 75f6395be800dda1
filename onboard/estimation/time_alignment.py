"""Timestamped signal histories, so estimators can combine own and peer data of the *same* instant.

A peer's velocity reaches an agent one network delay late. The SfM observer of paper 000 (eq. 8)
integrates the relative velocity ``u_ij = iR_j u_j - u_i``; pairing the peer's *old* ``u_j``
with the agent's *current* ``u_i`` biases ``chihat`` whenever the vehicles accelerate or turn
(headless runs with 40-100 ms latency ended 1-1.5% off in scale instead of 0.2%). The remedy is
the usual delayed-state one: run the observer at the newest instant for which both sides are
known, ``tau = min(t, newest peer stamp)``, replaying the own samples in between. A few tens of
milliseconds of lag in ``chihat`` is harmless; a bias is not.

:class:`SignalHistory` keeps the last ``horizon_s`` seconds of a sampled vector signal and
interpolates it linearly (a yaw component is interpolated along the short arc).
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from collections.abc import Sequence
from dataclasses import dataclass, field

from onboard.estimation.angles import wrap_rad

Sample = tuple[float, ...]


@dataclass(slots=True)
class SignalHistory:
    """Samples ``(t_s, x)`` in increasing time, at most ``horizon_s`` old (relative to the newest).

    ``angle_index``: the component of ``x`` that is an angle (rad), interpolated on the circle.
    """

    horizon_s: float = 1.0
    angle_index: int | None = None
    _t: list[float] = field(default_factory=list)
    _x: list[Sample] = field(default_factory=list)

    def add(self, t_s: float, x: Sequence[float]) -> bool:
        """Append a sample; returns ``False`` (and ignores it) unless ``t_s`` is newer."""
        if self._t and t_s <= self._t[-1]:
            return False
        self._t.append(t_s)
        self._x.append(tuple(x))
        cut = bisect_left(self._t, t_s - self.horizon_s)
        if cut > 16:  # trim in batches: list deletion is O(n)
            del self._t[:cut], self._x[:cut]
        return True

    def __len__(self) -> int:
        return len(self._t)

    @property
    def newest_s(self) -> float:
        return self._t[-1] if self._t else -math.inf

    @property
    def oldest_s(self) -> float:
        return self._t[0] if self._t else math.inf

    def times_in(self, t0_s: float, t1_s: float) -> list[float]:
        """Sample times in ``(t0_s, t1_s]``."""
        return self._t[bisect_right(self._t, t0_s) : bisect_right(self._t, t1_s)]

    def gap_at(self, t_s: float) -> float:
        """Length of the interval between the samples around ``t_s`` (``0`` on a sample; after
        the newest, the time since it; ``inf`` before the oldest): how far :meth:`at` bridges."""
        ts = self._t
        k = bisect_right(ts, t_s)
        if k == 0:
            return math.inf
        if ts[k - 1] == t_s:
            return 0.0
        return (ts[k] if k < len(ts) else t_s) - ts[k - 1]

    def at(self, t_s: float) -> Sample | None:
        """The signal at ``t_s``: linear between the bracketing samples, the newest sample held
        after it, ``None`` before the oldest."""
        ts = self._t
        k = bisect_right(ts, t_s)
        if k == 0:
            return None
        if k == len(ts) or ts[k - 1] == t_s:
            return self._x[k - 1]
        a = interpolation_weight(t_s, ts[k - 1], ts[k])
        x0, x1 = self._x[k - 1], self._x[k]
        out = [u + a * (v - u) for u, v in zip(x0, x1, strict=True)]  # lerp, inline: hot
        if self.angle_index is not None:
            m = self.angle_index
            out[m] = lerp_angle(x0[m], x1[m], a)
        return tuple(out)


def interpolation_weight(t_s: float, t0_s: float, t1_s: float) -> float:
    """Weight ``(t - t0) / (t1 - t0)`` of the later sample in a linear interpolation."""
    return (t_s - t0_s) / (t1_s - t0_s)


def lerp(x0: float, x1: float, a: float) -> float:
    """``x0 + a (x1 - x0)``."""
    return x0 + a * (x1 - x0)


def lerp_angle(x0_rad: float, x1_rad: float, a: float) -> float:
    """Linear interpolation of an angle along the short arc (not wrapped)."""
    return x0_rad + a * wrap_rad(x1_rad - x0_rad)


def step_times(
    sample_times: Sequence[float], t0_s: float, t1_s: float, max_step_s: float
) -> list[float]:
    """Integration instants in ``(t0_s, t1_s]``: every sample time in that interval and ``t1_s``,
    with any interval longer than ``max_step_s`` split into equal sub-steps. An explicit
    integrator stepping through them takes no step longer than ``max_step_s``."""
    if not max_step_s > 0.0:
        raise ValueError(f"max_step_s must be > 0, got {max_step_s}")
    knots = [t for t in sample_times if t0_s < t < t1_s]
    if t1_s > t0_s:
        knots.append(t1_s)
    out: list[float] = []
    prev = t0_s
    for t in knots:
        n = math.ceil((t - prev) / max_step_s - 1e-9)
        out.extend(prev + (t - prev) * k / n for k in range(1, n))
        out.append(t)
        prev = t
    return out
