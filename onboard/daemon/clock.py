"""The daemon's clock: wall time on real vehicles, the simulator's published time in simulation.

Time is injected (``shared/design.md``): the agent core integrates with the differences of
this clock, so in a simulation that runs faster than real time the daemon must follow the
simulator's clock, or every velocity it integrates would be scaled by the speed-up.
"""

from __future__ import annotations

import threading
import time
from typing import Protocol


class Clock(Protocol):
    def now(self) -> float | None:
        """Seconds, or ``None`` while the clock is not known yet."""
        ...


class WallClock:
    """``time.time()``: vehicles that share NTP/PTP time agree on it, so bearing stamps from
    different vehicles are comparable (relative yaw pairs bearings captured together)."""

    def now(self) -> float:
        return time.time()


class SimClockFollower:
    """Follows ``SimClock`` samples (``messages.sim``): between samples it extrapolates with the
    published speed-up (or holds, in lockstep). Feed it with :meth:`update`."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._t_sim: float | None = None
        self._t_mono = 0.0
        self._speedup = 1.0
        self._lockstep = False
        self._last = -float("inf")

    def update(self, t_sim_s: float, speedup: float, lockstep: bool) -> None:
        with self._lock:
            if self._t_sim is not None and t_sim_s < self._t_sim - 1e-9:
                return  # a late duplicate: never run backwards
            self._t_sim, self._t_mono = t_sim_s, time.monotonic()
            self._speedup, self._lockstep = speedup, lockstep

    @property
    def speedup(self) -> float:
        """Simulation seconds per wall second (last published)."""
        with self._lock:
            return self._speedup

    def now(self) -> float | None:
        with self._lock:
            if self._t_sim is None:
                return None
            t = self._t_sim
            if not self._lockstep:
                t += self._speedup * (time.monotonic() - self._t_mono)
            self._last = max(self._last, t)  # extrapolation may overshoot a late sample
            return self._last
