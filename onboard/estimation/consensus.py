"""Dynamic average consensus: the PI estimator (Freeman, Yang, Lynch 2006), the "ACE" blocks of
paper 000 fig. 1.

Every agent ``i`` has a local, time-varying input ``phi_i`` and wants the network average
``(1/N) sum_k phi_k`` (network sums are ``N`` times it). Over the undirected communication
graph, with ``x_i`` the estimate and ``z_i`` an integral state,

    x_i' = gamma (phi_i - x_i) - k_p sum_j (x_i - x_j) + k_i sum_j (z_i - z_j),
    z_i' = -k_i sum_j (x_i - x_j).

Summing over agents, the ``L``-terms cancel, so ``mean(x)`` follows ``mean(phi)`` as a first
order filter with rate ``gamma``; the proportional and integral couplings drive every ``x_i``
to the mean, and the integral term removes the steady-state disagreement for constant inputs
whatever the initial ``x, z``. A slowly varying average is tracked with an error proportional
to its rate of change. Explicit Euler is stable when ``dt (gamma + k_p mu_max) < 1`` (``mu_max``
the largest Laplacian eigenvalue, at most ``N``): with the defaults and ``dt = 2 ms`` that
holds for a Laplacian spectrum up to about 20 (e.g. up to 10 neighbours each).

Quantities are short vectors (tuples/lists of floats); the math is plain float arithmetic.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

GAMMA = 50.0
K_P = 20.0
K_I = 20.0


def pi_input_rate(phi_i: float, x_i: float, gamma: float = GAMMA) -> float:
    """One component of ``x_i'``'s input term, ``gamma (phi_i - x_i)``."""
    return gamma * (phi_i - x_i)


def pi_coupling_rates(
    x_i: float, z_i: float, x_j: float, z_j: float, k_p: float = K_P, k_i: float = K_I
) -> tuple[float, float]:
    """One neighbour's share of one component of ``(x_i', z_i')``:
    ``(-k_p (x_i - x_j) + k_i (z_i - z_j), -k_i (x_i - x_j))``."""
    dxm = x_i - x_j
    return -k_p * dxm + k_i * (z_i - z_j), -(k_i * dxm)


def pi_consensus_rates(
    x_i: Sequence[float],
    z_i: Sequence[float],
    phi_i: Sequence[float],
    neighbours: Sequence[tuple[Sequence[float], Sequence[float]]],
    gamma: float = GAMMA,
    k_p: float = K_P,
    k_i: float = K_I,
) -> tuple[list[float], list[float]]:
    """``(x_i', z_i')`` of the PI estimator given the neighbours' latest ``(x_j, z_j)``: the
    input term (:func:`pi_input_rate`) plus each neighbour's coupling
    (:func:`pi_coupling_rates`), summed in neighbour order."""
    dx = [pi_input_rate(f, x, gamma) for f, x in zip(phi_i, x_i, strict=True)]
    dz = [0.0] * len(x_i)
    for x_j, z_j in neighbours:
        for m in range(len(x_i)):
            a, b = pi_coupling_rates(x_i[m], z_i[m], x_j[m], z_j[m], k_p, k_i)
            dx[m] += a
            dz[m] += b
    return dx, dz


@dataclass(slots=True)
class PIConsensus:
    """One agent's PI average-consensus estimator of a vector quantity."""

    x: list[float]
    z: list[float] = field(default_factory=list)
    gamma: float = GAMMA
    k_p: float = K_P
    k_i: float = K_I

    def __post_init__(self) -> None:
        if not self.z:
            self.z = [0.0] * len(self.x)

    def step(
        self,
        dt: float,
        phi: Sequence[float],
        neighbours: Sequence[tuple[Sequence[float], Sequence[float]]],
    ) -> list[float]:
        """Advance by ``dt`` with local input ``phi``; returns the new average estimate."""
        dx, dz = pi_consensus_rates(self.x, self.z, phi, neighbours, self.gamma, self.k_p, self.k_i)
        self.x = [x + dt * d for x, d in zip(self.x, dx, strict=True)]
        self.z = [z + dt * d for z, d in zip(self.z, dz, strict=True)]
        return self.x
