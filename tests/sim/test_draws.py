"""Counter-based draws: the same value in Python and compiled code, in any order."""

from __future__ import annotations

import math

import numpy as np

from sim import draws
from sim.jit import compiled

fast = compiled(draws)
uniform_c, normal_c, lost_c = fast.uniform, fast.normal, fast.lost


def test_compiled_and_python_agree_bit_for_bit() -> None:
    for seed in (0, 1, 7, -3, 2**31 + 5):
        for k in (0, 1, 99, 123456):
            for a in (0, 5, 29):
                assert draws.uniform(seed, 1, k, a, 3) == uniform_c(seed, 1, k, a, 3)
                assert draws.normal(seed, 2, k, a, 1) == normal_c(seed, 2, k, a, 1)
                assert draws.lost(seed, k, 2, a, 30, 4, 0.3) == lost_c(seed, k, 2, a, 30, 4, 0.3)


def test_uniform_and_normal_have_the_right_moments() -> None:
    u = np.array([draws.uniform(3, 1, k, 0, 0) for k in range(20000)])
    z = np.array([draws.normal(3, 2, k, 1, 2) for k in range(20000)])
    assert u.min() >= 0.0 and u.max() < 1.0
    assert abs(u.mean() - 0.5) < 0.01 and abs(u.var() - 1.0 / 12.0) < 0.003
    assert abs(z.mean()) < 0.03 and abs(z.std() - 1.0) < 0.03
    assert np.all(np.isfinite(z))
    # neighbouring counters are not correlated
    assert abs(np.corrcoef(u[:-1], u[1:])[0, 1]) < 0.03


def test_draws_depend_on_every_word() -> None:
    base = draws.hash32(1, 2, 3, 4, 5)
    for changed in (
        (9, 2, 3, 4, 5),
        (1, 9, 3, 4, 5),
        (1, 2, 9, 4, 5),
        (1, 2, 3, 9, 5),
        (1, 2, 3, 4, 9),
    ):
        assert draws.hash32(*changed) != base


def test_loss_rate_and_zero_loss() -> None:
    hits = sum(draws.lost(0, k, 1, 2, 6, 0, 0.1) for k in range(20000))
    assert abs(hits / 20000 - 0.1) < 0.01
    assert not any(draws.lost(0, k, 1, 2, 6, 0, 0.0) for k in range(1000))
    assert math.isclose(draws.uniform(0, 0, 0, 0, 0), draws.uniform(0, 0, 0, 0, 0))
