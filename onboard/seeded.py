"""Seeded start draws without ``numpy.random`` (issue 27: onboard footprint).

A daemon draws random numbers at start only: the active controller's first direction (paper
000 eq. 12, :mod:`onboard.core.motion`) and the distributed eigenvector estimator's start
block and restart blocks (:mod:`onboard.estimation.distributed_eigen`). ``numpy.random`` is a
lazily loaded subpackage of numpy and the first ``np.random`` touch loads it: 6.8 MB resident
(measured in a fresh interpreter after numpy, this machine) for a handful of numbers. Python's
:class:`random.Random` is loaded anyway; seeded with a string it is reproducible across runs
and platforms (seed version 2 hashes the string's bytes with SHA-512, not its salted
``hash``; Python docs, ``random.seed``). Each draw is a fixed function of its seed tuple.

The compiled engine (:mod:`sim.compiled_rigidity`, :mod:`sim.compiled_runner`) draws through
these same functions, so both engines start from the same numbers.

**Why the eigen start is small** (:data:`EIGEN_START_SCALE`). When the estimate first stays
within 2% of ``lambda_8`` is not set by the start block's overlap with the eigenvectors: on the
4-agent framework of ``tests/onboard/test_rigidity_layer.py`` the exact Rayleigh-Ritz value of
the iterated block is within 0.05% of ``lambda_8`` after 20 rounds, whatever the start
(``benchmarks/bench_eigen_start.py --exact``). It is set by the *consensus-averaged* Ritz
problem: the column on a mode the normalisation term cannot hold (``alpha lambda > k_n / 2``,
here ``lambda_10``) shrinks by about 3% per round, and while its direction of ``G'`` is small
but above ``RITZ_RCOND`` the averages' consensus error gives it a Ritz value near half of
``lambda_8`` (0.41 against 0.83) until ``RITZ_RCOND`` drops it, about round 150 from a block of
unit entries (``V^T V / N`` about ``3 I``, three times the equilibrium ``I``). Measured, not
derived: from entries of standard deviation 0.1 (``V^T V / N`` about ``0.03 I``) 19 of 20 start
streams got there within 150 rounds (median 122), from the unit ``numpy.random`` start of
before 6 (median 154), from unit ``random.Random`` draws 11 (median 150); scales 0.02-0.3
gave 18-19 of 20, a scale of 2 made the iteration diverge and restart.
"""

from __future__ import annotations

import math
import random
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

EIGEN_START_SCALE = 0.1
"""Standard deviation of the entries of an eigen-estimator start or restart block (module
docstring: why small)."""

EIGEN_START_PURPOSE = 31
"""Third entry of the start block's seed tuple ``(fleet seed, agent id, 31)``."""

ACTIVE_START_PURPOSE = 500
"""Third entry of the active controller's first-direction seed tuple."""


def standard_normal(seed: Sequence[int], shape: int | tuple[int, ...]) -> NDArray[np.float64]:
    """An array of ``shape`` independent standard-normal draws, a fixed function of ``seed``
    (a sequence of integers, e.g. ``(fleet seed, agent id, purpose)``)."""
    rng = random.Random("bearingflock:" + ",".join(str(int(s)) for s in seed))
    dims = (shape,) if isinstance(shape, int) else tuple(shape)
    draws = [rng.gauss(0.0, 1.0) for _ in range(math.prod(dims))]
    return np.array(draws, dtype=np.float64).reshape(dims)


def eigen_start_block(fleet_seed: int, agent_id: int, columns: int) -> NDArray[np.float64]:
    """Agent ``agent_id``'s start block ``V_i`` ``(3, columns)`` of the distributed eigen
    estimator: entries of standard deviation :data:`EIGEN_START_SCALE`."""
    seed = (fleet_seed, agent_id, EIGEN_START_PURPOSE)
    return EIGEN_START_SCALE * standard_normal(seed, (3, columns))


def eigen_restart_block(estimator_seed: int, restart: int, columns: int) -> NDArray[np.float64]:
    """The block ``(3, columns)`` the estimator restarts from after its ``restart``-th
    divergence (``estimator_seed`` is ``fleet seed * 7919 + agent id``)."""
    return EIGEN_START_SCALE * standard_normal((estimator_seed, restart), (3, columns))


def active_start_direction(fleet_seed: int, agent_id: int) -> NDArray[np.float64]:
    """The active controller's first unit direction ``(3,)`` (paper 000 eq. 12)."""
    d = standard_normal((fleet_seed, agent_id, ACTIVE_START_PURPOSE), 3)
    return d / float(np.linalg.norm(d))
