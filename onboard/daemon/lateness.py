"""Whether a daemon keeps up with its schedule: the ``ticks_late`` alarm (issue 29).

A machine too slow for the chosen simulation speed does not stop the flight stack: the core
ticks later than scheduled (or is descheduled for whole periods), each step integrates a
longer ``dt``, and the estimates quietly get worse (6 vehicles: 1.3-2.1% scale error on a
loaded machine instead of 0.2%). :class:`TickLateness` measures it as the fraction of the
last :data:`LATE_WINDOW_S` of wall time that ticks started late (the sum of their lateness
over the window) and raises the alarm above :data:`LATE_FRACTION_RAISE`: the core then runs
at under three quarters of its rate. It clears below :data:`LATE_FRACTION_CLEAR`, so a
machine on the edge does not flicker.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

LATE_WINDOW_S = 2.0
"""Wall seconds over which lateness is summed."""
LATE_FRACTION_RAISE = 0.25
LATE_FRACTION_CLEAR = 0.125


@dataclass
class TickLateness:
    """Sliding window of tick lateness (wall seconds); :attr:`late` is the alarm's state."""

    window_s: float = LATE_WINDOW_S
    raise_fraction: float = LATE_FRACTION_RAISE
    clear_fraction: float = LATE_FRACTION_CLEAR
    late: bool = False
    _ticks: deque[tuple[float, float]] = field(default_factory=deque)
    _sum_s: float = 0.0

    def add(self, mono_s: float, late_s: float) -> bool:
        """Fold in one tick that started ``late_s`` after its schedule at monotonic time
        ``mono_s``; returns :attr:`late`."""
        late_s = max(0.0, late_s)
        self._ticks.append((mono_s, late_s))
        self._sum_s += late_s
        while self._ticks and mono_s - self._ticks[0][0] > self.window_s:
            self._sum_s -= self._ticks.popleft()[1]
        fraction = self.fraction
        if fraction > self.raise_fraction:
            self.late = True
        elif fraction < self.clear_fraction:
            self.late = False
        return self.late

    @property
    def fraction(self) -> float:
        """Share of the last ``window_s`` of wall time that ticks started late."""
        return max(0.0, self._sum_s) / self.window_s
