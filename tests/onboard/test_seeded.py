"""Seeded standard-normal draws without numpy.random (onboard/seeded.py, issue 27)."""

from __future__ import annotations

import numpy as np

from onboard.seeded import standard_normal


def test_same_seed_same_draws_other_seed_other_draws() -> None:
    a, b = standard_normal((0, 1, 31), (3, 4)), standard_normal((0, 1, 31), (3, 4))
    assert a.shape == (3, 4) and a.dtype == np.float64
    assert np.array_equal(a, b)
    assert not np.array_equal(a, standard_normal((0, 2, 31), (3, 4)))
    assert standard_normal((5,), 3).shape == (3,)


def test_draws_are_standard_normal() -> None:
    x = standard_normal((7, 0), 20_000)
    assert abs(float(x.mean())) < 0.03  # 4 standard errors of the mean
    assert abs(float(x.std()) - 1.0) < 0.03
    assert 0.30 < float(np.mean(np.abs(x) < 0.4)) < 0.33  # P(|z| < 0.4) = 0.311
