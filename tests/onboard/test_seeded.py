"""Seeded start draws without ``numpy.random`` (``onboard/seeded.py``, issue 27): fixed
functions of their seeds, and an eigen start from which the distributed estimate reaches 2%
of ``lambda_8`` within 150 rounds in more start streams than the ``numpy.random`` start did
(``benchmarks/bench_eigen_start.py``: 19 and 6 of 20)."""

from __future__ import annotations

import numpy as np

from benchmarks.bench_eigen_start import N, rounds_to_converge
from onboard.seeded import (
    EIGEN_START_SCALE,
    active_start_direction,
    eigen_restart_block,
    eigen_start_block,
    standard_normal,
)


def test_draws_are_fixed_functions_of_their_seed() -> None:
    a = standard_normal((3, 1, 31), (3, 3))
    np.testing.assert_array_equal(a, standard_normal((3, 1, 31), (3, 3)))
    assert not np.array_equal(a, standard_normal((3, 2, 31), (3, 3)))
    assert not np.array_equal(eigen_start_block(0, 1, 3), eigen_restart_block(1, 1, 3))
    d = active_start_direction(2, 0)
    assert abs(float(np.linalg.norm(d)) - 1.0) < 1e-12
    assert not np.allclose(d, active_start_direction(2, 1))


def test_draws_are_standard_normal() -> None:
    x = standard_normal((7,), 20000)
    assert abs(float(x.mean())) < 0.03 and abs(float(x.std()) - 1.0) < 0.03
    v = np.stack([eigen_start_block(5, i, 3) for i in range(200)])
    assert abs(float(v.std()) - EIGEN_START_SCALE) < 0.1 * EIGEN_START_SCALE


def test_eigen_estimate_converges_from_most_start_streams_in_150_rounds() -> None:
    """Streams 0-9 on the 4-agent framework of test_rigidity_layer: 9 reach 2% within 150
    rounds from today's start (streams 0-9 of the numpy.random start: 4)."""
    got = [
        rounds_to_converge(np.stack([eigen_start_block(s, i, 3) for i in range(N)]), 160)
        for s in range(10)
    ]
    assert sum(r is not None and r <= 150 for r in got) >= 8, got
