"""The daemon's clock: wall time on real vehicles, the simulator's published time in simulation.

Time is injected (``docs/design.md``): the agent core integrates with the differences of
this clock, so in a simulation that runs faster than real time the daemon must follow the
simulator's clock, or every velocity it integrates would be scaled by the speed-up.
"""

from __future__ import annotations

import math
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


class OffsetClock:
    """``inner`` shifted by ``offset_s``: fault injection (``bearingflock agent --clock-offset``)
    to rehearse a vehicle whose clock disagrees with its team's (:mod:`onboard.daemon.peer_clock`).
    """

    def __init__(self, inner: Clock, offset_s: float) -> None:
        self.inner = inner
        self.offset_s = offset_s

    def now(self) -> float | None:
        t = self.inner.now()
        return None if t is None else t + self.offset_s

    @property
    def speedup(self) -> float:
        return float(getattr(self.inner, "speedup", 1.0))

    def observe(self, t_sim_s: float) -> None:
        observe = getattr(self.inner, "observe", None)
        if observe is not None:
            observe(t_sim_s)


MAX_EXTRAPOLATION_S = 0.1
"""Simulation seconds the follower runs ahead of the newest simulation time it has seen."""


class SimClockFollower:
    """Follows the simulator's time: ``SimClock`` samples (``messages.sim``, 10 Hz) with their
    speed-up, and any newer simulation time seen elsewhere (:meth:`observe`: the autopilot's
    ``time_boot_ms``, 20 Hz). Between them it extrapolates with the speed-up, by at most
    ``max_extrapolation_s`` (or holds, in lockstep).

    The cap matters on a loaded machine: a simulator that stalls for a few hundred milliseconds
    also stops its world, and a follower that kept extrapolating would run the agents' estimators
    (and stamp their data) ahead of a world that did not move."""

    def __init__(self, max_extrapolation_s: float = MAX_EXTRAPOLATION_S) -> None:
        self.max_extrapolation_s = max_extrapolation_s
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

    def observe(self, t_sim_s: float) -> None:
        """The simulation has reached at least ``t_sim_s`` (a stamp just received)."""
        with self._lock:
            if self._t_sim is None or t_sim_s <= self._extrapolated():
                return
            self._t_sim, self._t_mono = t_sim_s, time.monotonic()

    def _extrapolated(self) -> float:
        assert self._t_sim is not None
        if self._lockstep:
            return self._t_sim
        ahead = self._speedup * (time.monotonic() - self._t_mono)
        return self._t_sim + min(ahead, self.max_extrapolation_s)

    @property
    def speedup(self) -> float:
        """Simulation seconds per wall second (last published)."""
        with self._lock:
            return self._speedup

    def now(self) -> float | None:
        with self._lock:
            if self._t_sim is None:
                return None
            t = self._extrapolated()
            self._last = max(self._last, t)  # extrapolation may overshoot a late sample
            return self._last


def autopilot_stamp(t_boot_s: float | None, age_s: float, now_s: float, sim: bool) -> float | None:
    """When the autopilot measured a sample, in the daemon's clock: its own stamp
    (``time_boot_ms``) with the simulator's clock, whose autopilots count simulation time;
    otherwise the daemon's clock at its arrival (``now_s - age_s``: a serial or UDP link adds
    milliseconds, and an autopilot's boot clock is not the vehicles' shared clock)."""
    if sim:
        return t_boot_s
    return now_s - age_s if math.isfinite(age_s) else None
