"""The daemon's clock: wall time on real vehicles, the simulator's published time in simulation.

Time is injected (``docs/design.md``): the agent core integrates with the differences of
this clock, so in a simulation that runs faster than real time the daemon must follow the
simulator's clock, or every velocity it integrates would be scaled by the speed-up.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import Any, Protocol

from messages.codec import MessageError, decode
from messages.sim import SIM_SENDER, SimClock
from messages.vocabulary import Alarm, DropReason, DropScope

Drop = Callable[[DropReason, str, DropScope | None], None]
"""Where a dropped clock sample is counted (:meth:`onboard.daemon.peers.DropCounter.drop`)."""


class Clock(Protocol):
    """Everything the daemon's loop asks of its clock. A clock that subclasses this protocol
    inherits the real-time answers of :attr:`speedup`, :meth:`observe` and :meth:`fault`."""

    def now(self) -> float | None:
        """Seconds, or ``None`` while the clock is not known yet."""
        ...

    @property
    def speedup(self) -> float:
        """Clock seconds per wall second (1 for wall time)."""
        return 1.0

    def observe(self, t_sim_s: float) -> None:
        """A time stamp the autopilot reported (simulation time in simulation): a clock that
        follows the simulator moves up to it; others ignore it."""
        return None

    def fault(self) -> Alarm | None:
        """An alarm while the clock rejected or followed an implausible time, else ``None``."""
        return None


class WallClock(Clock):
    """``time.time()``: vehicles that share NTP/PTP time agree on it, so bearing stamps from
    different vehicles are comparable (relative yaw pairs bearings captured together)."""

    def now(self) -> float:
        return time.time()


class OffsetClock(Clock):
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
        return self.inner.speedup

    def observe(self, t_sim_s: float) -> None:
        self.inner.observe(t_sim_s)

    def fault(self) -> Alarm | None:
        return self.inner.fault()


MAX_EXTRAPOLATION_S = 0.1
"""Simulation seconds the follower runs ahead of the newest simulation time it has seen."""
MAX_CLOCK_JUMP_S = 2.0
"""A simulation time further than this from what the follower expects (its time plus the
elapsed wall time at the announced speed-up, at least real time) is implausible: rejected and
counted (``clock_jump``), unless :data:`RESYNC_SAMPLES` consistent ``SimClock`` samples in a row
confirm the new timeline (a restarted simulator: ``clock_resync``)."""
RESYNC_SAMPLES = 5
"""Consecutive ``SimClock`` samples on one new timeline before the follower adopts it (0.5 s of
simulation at the simulator's 10 Hz; a single forged sample never moves the clock)."""
CLOCK_ALARM_S = 5.0
"""Wall seconds a rejected jump or a resynchronization stays an alarm (``clock_jump``,
``clock_resync`` in the daemon's status)."""


class SimClockFollower(Clock):
    """Follows the simulator's time: ``SimClock`` samples (``messages.sim``, 10 Hz) with their
    speed-up, and any newer simulation time seen elsewhere (:meth:`observe`: the autopilot's
    ``time_boot_ms``, 20 Hz). Between them it extrapolates with the speed-up, by at most
    ``max_extrapolation_s`` (or holds, in lockstep).

    The cap matters on a loaded machine: a simulator that stalls for a few hundred milliseconds
    also stops its world, and a follower that kept extrapolating would run the agents' estimators
    (and stamp their data) ahead of a world that did not move."""

    def __init__(
        self,
        max_extrapolation_s: float = MAX_EXTRAPOLATION_S,
        drop: Drop | None = None,
        max_jump_s: float = MAX_CLOCK_JUMP_S,
    ) -> None:
        self.max_extrapolation_s = max_extrapolation_s
        self.max_jump_s = max_jump_s
        self._drop = drop
        self._lock = threading.Lock()
        self._t_sim: float | None = None
        self._t_mono = 0.0
        self._speedup = 1.0
        self._lockstep = False
        self._last = -float("inf")
        self._candidate: tuple[float, float, int] | None = None  # (t_sim, t_mono, count)
        self._fault: tuple[str, float] | None = None  # (alarm, wall time)

    def _plausible_from(self, t_from: float, mono_from: float, t_sim_s: float, now: float) -> bool:
        """Whether ``t_sim_s`` can follow ``t_from`` (seen at ``mono_from``) by ``now``."""
        ahead = max(self._speedup, 1.0) * (now - mono_from) + self.max_jump_s
        return t_from - self.max_jump_s <= t_sim_s <= t_from + ahead

    def _reject(self, reason: DropReason, detail: str, now: float) -> None:
        self._fault = (reason, now)
        if self._drop is not None:
            self._drop(reason, detail, None)

    def update(self, t_sim_s: float, speedup: float, lockstep: bool) -> None:
        """A ``SimClock`` sample (already decoded and checked, :func:`sim_clock_handler`)."""
        with self._lock:
            now = time.monotonic()
            if self._t_sim is not None and not self._plausible_from(
                self._t_sim, self._t_mono, t_sim_s, now
            ):
                c = self._candidate
                if (
                    c is not None
                    and c[0] < t_sim_s
                    and self._plausible_from(c[0], c[1], t_sim_s, now)
                ):
                    self._candidate = c = (t_sim_s, now, c[2] + 1)
                else:
                    self._candidate = c = (t_sim_s, now, 1)
                if c[2] < RESYNC_SAMPLES:
                    self._reject(
                        DropReason.CLOCK_JUMP, f"simulation time {t_sim_s} after {self._t_sim}", now
                    )
                    return
                self._reject(
                    DropReason.CLOCK_RESYNC, f"simulation time {self._t_sim} -> {t_sim_s}", now
                )
                self._last = -math.inf  # the new timeline may lie behind: follow it
            elif self._t_sim is not None and t_sim_s < self._t_sim - 1e-9:
                return  # a late duplicate: never run backwards
            self._candidate = None
            self._t_sim, self._t_mono = t_sim_s, now
            self._speedup, self._lockstep = speedup, lockstep

    def observe(self, t_sim_s: float) -> None:
        """The simulation has reached at least ``t_sim_s`` (a stamp just received); a stamp
        more than :attr:`max_jump_s` ahead is implausible (``clock_jump``: one forged ATTITUDE
        with ``time_boot_ms = 4e9`` moved a daemon 46 days ahead)."""
        with self._lock:
            if self._t_sim is None or t_sim_s <= self._extrapolated():
                return
            now = time.monotonic()
            if t_sim_s > self._extrapolated() + self.max_jump_s:
                self._reject(
                    DropReason.CLOCK_JUMP, f"autopilot time {t_sim_s} at {self._t_sim}", now
                )
                return
            self._t_sim, self._t_mono = t_sim_s, now

    def fault(self) -> Alarm | None:
        """``clock_jump`` or ``clock_resync`` for :data:`CLOCK_ALARM_S` after one, else ``None``."""
        with self._lock:
            f = self._fault
            recent = f is not None and time.monotonic() - f[1] <= CLOCK_ALARM_S
            return Alarm(f[0]) if f is not None and recent else None

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


def sim_clock_handler(follower: SimClockFollower, drop: Drop) -> Callable[[Any], None]:
    """The Zenoh handler of the simulation-clock key: every sample through the checked codec
    (size, schema version, finiteness and ranges, :mod:`messages.limits`) and from the
    simulator's sender id only, else counted as ``clock_<reason>`` and dropped."""

    def on_clock(sample: Any) -> None:
        try:
            msg = decode(sample.payload.to_bytes(), SimClock, known_senders=(SIM_SENDER,))
        except MessageError as exc:
            drop(exc.reason, exc.detail, DropScope.CLOCK)
            return
        follower.update(msg.t_s, msg.speedup, msg.lockstep)

    return on_clock
