"""Consensus counted in message rounds: PI average consensus with Metropolis weights, and a max
consensus that forgets, for estimators whose speed must not depend on the message rate.

**PI average consensus per round** (Freeman, Yang, Lynch 2006, discretized). Every agent has a
time-varying input ``phi_i`` and tracks the network average with an estimate ``x_i`` and an
integral state ``z_i``; per round, with the neighbours' latest ``(x_j, z_j)``,

    ``x_i+ = x_i + e_g (phi_i - x_i) - e_p sum_j a_ij (x_i - x_j) + e_i sum_j a_ij (z_i - z_j)``,
    ``z_i+ = z_i - e_i sum_j a_ij (x_i - x_j)``,

with symmetric Metropolis weights ``a_ij = 1 / (1 + max(deg_i, deg_j))`` (Xiao, Boyd 2004):
the weighted Laplacian's spectrum lies in ``[0, 2)`` whatever the graph, so one set of per-round
gains works for 5 agents and for 30. The couplings cancel in the network sum (``a`` is
symmetric), so ``mean(x)`` follows ``mean(phi)`` as a first-order filter of gain ``e_g`` per
round. With ``mu < 2`` an eigenvalue of that Laplacian, each mode's matrix
``[[1 - e_g - e_p mu, e_i mu], [-e_i mu, 1]]`` is stable (Jury) when
``e_i^2 mu^2 < e_g + e_p mu`` and ``e_g + e_p mu < 2`` (the defaults). A disagreement mode of
Laplacian eigenvalue ``mu`` settles at about ``(e_i mu)^2 / e_g`` per round: sparse graphs
(small ``mu_2``) are slow, which is why ``e_i`` is near its bound and ``e_g`` small.

**Max consensus that forgets.** ``y_i+ = max(s_i, rho max(y_i, max_j y_j))``: every agent
holds the network maximum of the ``s`` (exactly, after as many rounds as the graph's diameter)
while it grows, and lets go of an old maximum at the rate ``rho`` per round when it shrinks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import FloatArray


@dataclass(frozen=True)
class RoundGains:
    """Per-round gains of the PI consensus (module docstring)."""

    e_g: float = 0.15
    e_p: float = 0.5
    e_i: float = 0.45

    def __post_init__(self) -> None:
        ok = (
            0.0 < self.e_g < 1.0
            and self.e_p >= 0.0
            and self.e_i >= 0.0
            and self.e_g + 2.0 * self.e_p < 2.0
            and 4.0 * self.e_i**2 < self.e_g + 2.0 * self.e_p
        )
        if not ok:
            raise ValueError(f"unstable per-round consensus gains {self!r}")


def metropolis_weights(deg_own: int, deg_nbrs: ArrayLike) -> FloatArray:
    """``a_ij = 1 / (1 + max(deg_i, deg_j))`` for every neighbour ``j``."""
    return 1.0 / (1.0 + np.maximum(float(deg_own), np.asarray(deg_nbrs, dtype=float)))


def pi_round(
    x: FloatArray,
    z: FloatArray,
    phi: FloatArray,
    x_nbrs: FloatArray,
    z_nbrs: FloatArray,
    a: FloatArray,
    gains: RoundGains,
) -> tuple[FloatArray, FloatArray]:
    """One round of the PI consensus (module docstring); ``x_nbrs, z_nbrs`` are ``(K, n)``, ``a``
    the ``K`` Metropolis weights. Returns ``(x+, z+)``."""
    a_sum = a.sum()
    dx = a_sum * x - a @ x_nbrs  # sum_j a_ij (x_i - x_j)
    dz = a_sum * z - a @ z_nbrs
    x_new = x + gains.e_g * (phi - x) - gains.e_p * dx + gains.e_i * dz
    z_new = z - gains.e_i * dx
    return x_new, z_new


def max_round(own: float, y: float, y_nbrs: ArrayLike, rho: float) -> float:
    """One round of the forgetting max consensus ``max(own, rho max(y, y_nbrs))``."""
    nb = np.asarray(y_nbrs, dtype=float)
    top = max(y, float(nb.max())) if nb.size else y
    return max(own, rho * top)
