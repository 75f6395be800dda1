"""Random-motion baseline (paper 000 Sect. V-A, case 2): random directions at the same speed.

The paper rescales random inputs so that ``|u_i|`` equals the active controller's
``sqrt(2 nu*)``. Here the direction follows a 3-D Ornstein-Uhlenbeck process ``z`` with time
constant ``tau`` (a smooth random walk) and ``u = sqrt(2 nu*) z / |z|``. Seeded, so the same
seed gives the same trajectory.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

Vec3 = tuple[float, float, float]

TAU_S = 1.0
_BLOCK = 512


def ou_direction_step(z: Vec3, noise: Vec3, dt: float, tau_s: float = TAU_S) -> Vec3:
    """Exact discretization of the Ornstein-Uhlenbeck direction process over ``dt``:
    ``z <- a z + sqrt(1 - a^2) n`` with ``a = exp(-dt / tau)`` and ``n`` standard normal."""
    a = math.exp(-dt / tau_s)
    b = math.sqrt(1.0 - a * a)
    return (a * z[0] + b * noise[0], a * z[1] + b * noise[1], a * z[2] + b * noise[2])


def ou_velocity(z: Vec3, speed_m_s: float) -> Vec3:
    """``u = speed z / |z|`` (zero for ``z = 0``)."""
    n = math.sqrt(z[0] * z[0] + z[1] * z[1] + z[2] * z[2])
    k = speed_m_s / n if n > 0.0 else 0.0
    return (k * z[0], k * z[1], k * z[2])


@dataclass(slots=True)
class RandomMotion:
    """Velocity generator of one agent; :meth:`step` returns the body velocity to command."""

    seed: int
    speed_m_s: float
    tau_s: float = TAU_S
    _rng: np.random.Generator = field(init=False)
    _z: Vec3 = field(init=False)
    _noise: list[list[float]] = field(init=False, default_factory=list)

    def __post_init__(self) -> None:
        self._rng = np.random.default_rng(self.seed)
        z = self._rng.standard_normal(3).tolist()
        self._z = (z[0], z[1], z[2])

    @property
    def velocity(self) -> Vec3:
        return ou_velocity(self._z, self.speed_m_s)

    def step(self, dt: float) -> Vec3:
        """Advance the direction process by ``dt`` (exact OU discretization) and return ``u``."""
        if dt > 0.0:
            if not self._noise:
                self._noise = self._rng.standard_normal((_BLOCK, 3)).tolist()
            n = self._noise.pop()
            self._z = ou_direction_step(self._z, (n[0], n[1], n[2]), dt, self.tau_s)
        return self.velocity
