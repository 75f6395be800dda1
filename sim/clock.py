"""Simulation time: real time with a speed-up factor, or lockstep.

The simulator advances its world in fixed steps of ``dt_s`` seconds of *simulation* time and
asks its clock how far it may go:

* :class:`RealTimeClock` — simulation time runs ``speedup`` times faster than the wall clock
  (``speedup = 1`` is real time). Streams and timeouts (heartbeat 1 Hz, COM_OF_LOSS_T,
  GUID_TIMEOUT) are in simulation time, so a client that measures its own timeouts on the
  wall clock sees them ``speedup`` times sooner.
* :class:`LockstepClock` — simulation time stands still until someone calls
  :meth:`LockstepClock.advance_to` (in process, or via a published ``SimStep`` message);
  the simulator then runs as fast as it can up to that time and stops again. Two runs given the
  same steps and the same inputs at the same simulation times produce the same world.

Clients follow simulation time from the ``SimClock`` messages the server publishes or from
``time_boot_ms`` of any MAVLink message (docs/sim.md). No global state: a clock is an object
that the server owns.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from messages.codec import encode
from messages.sim import SimClock, clock_key


@dataclass
class RealTimeClock:
    """Simulation time ``= speedup * (wall - wall_at_start)``."""

    speedup: float = 1.0
    wall: Callable[[], float] = time.monotonic
    _wall0: float = field(init=False)
    _sim0: float = field(init=False, default=0.0)

    def __post_init__(self) -> None:
        if not self.speedup > 0.0:
            raise ValueError(f"speedup must be > 0, got {self.speedup}")
        self._wall0 = self.wall()

    lockstep = False

    def target_s(self) -> float:
        """How far simulation time may advance now."""
        return self._sim0 + (self.wall() - self._wall0) * self.speedup

    def wall_wait_s(self, t_sim_s: float) -> float | None:
        """Wall seconds until simulation time reaches ``t_sim_s`` (0 if already there)."""
        return max(0.0, (t_sim_s - self.target_s()) / self.speedup)

    def resync(self, t_sim_s: float) -> None:
        """Restart counting from ``t_sim_s`` now (used after the simulator fell behind)."""
        self._wall0 = self.wall()
        self._sim0 = t_sim_s


@dataclass
class LockstepClock:
    """Simulation time advances only when told to (thread-safe)."""

    _target: float = 0.0
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    on_advance: Callable[[], None] | None = None
    """Called after each advance (the server uses it to wake its loop)."""

    lockstep = True

    def target_s(self) -> float:
        with self._lock:
            return self._target

    def advance_to(self, t_s: float) -> None:
        """Allow simulation time up to ``t_s`` (never backwards; NaN is ignored)."""
        if not t_s == t_s:  # NaN
            return
        with self._lock:
            self._target = max(self._target, float(t_s))
        if self.on_advance is not None:
            self.on_advance()

    def advance(self, dt_s: float) -> None:
        """Allow ``dt_s`` more seconds of simulation time."""
        if dt_s > 0.0:
            self.advance_to(self.target_s() + dt_s)

    def wall_wait_s(self, t_sim_s: float) -> float | None:
        """``None`` (wait for an advance) unless ``t_sim_s`` is already allowed."""
        return 0.0 if t_sim_s <= self.target_s() else None

    def resync(self, t_sim_s: float) -> None:
        """Nothing to resynchronize: lockstep time never runs ahead of the world."""


Clock = RealTimeClock | LockstepClock


class ClockPublisher:
    """Tick hook that publishes :class:`messages.sim.SimClock` at ``rate_hz`` of simulation time
    and, in lockstep, also whenever the simulation has reached the time it was allowed."""

    def __init__(
        self,
        fleet: str,
        put: Callable[[str, bytes], None],
        clock: RealTimeClock | LockstepClock,
        dt_s: float,
        rate_hz: float = 10.0,
    ) -> None:
        self.key = clock_key(fleet)
        self.put = put
        self.clock = clock
        self.dt_s = dt_s
        self.period_s = 1.0 / rate_hz
        self.next_t_s = 0.0
        self.steps = 0
        self.seq = 0

    def __call__(self, t_s: float, _world: object) -> None:
        self.steps += 1
        reached = self.clock.lockstep and t_s + self.dt_s > self.clock.target_s() + 1e-9
        if t_s + 1e-9 < self.next_t_s and not reached:
            return
        self.next_t_s = max(self.next_t_s + self.period_s, t_s)
        speedup = getattr(self.clock, "speedup", 0.0)
        msg = SimClock(
            sender=0,
            seq=self.seq,
            stamp_s=t_s,
            t_s=t_s,
            step=self.steps,
            speedup=float(speedup),
            lockstep=self.clock.lockstep,
        )
        self.seq += 1
        self.put(self.key, encode(msg))
