"""Per-round PI average consensus with Metropolis weights and the forgetting max consensus."""

from __future__ import annotations

import numpy as np
import pytest

from onboard.estimation.round_consensus import (
    RoundGains,
    max_round,
    metropolis_weights,
    pi_round,
)


def _run(adj: list[list[int]], phi: np.ndarray, rounds: int, gains: RoundGains) -> np.ndarray:
    n = len(adj)
    deg = [len(a) for a in adj]
    x, z = phi.copy(), np.zeros_like(phi)
    x = x + np.random.default_rng(0).normal(size=x.shape)  # any start: the integral fixes it
    for _ in range(rounds):
        nx, nz = np.zeros_like(x), np.zeros_like(z)
        for i in range(n):
            a = metropolis_weights(deg[i], [deg[j] for j in adj[i]])
            nx[i], nz[i] = pi_round(x[i], z[i], phi[i], x[adj[i]], z[adj[i]], a, gains)
        x, z = nx, nz
    return x


@pytest.mark.parametrize(
    "adj",
    [
        [[1], [0, 2], [1, 3], [2, 4], [3, 5], [4]],  # path
        [[1, 2, 3, 4], [0], [0], [0], [0]],  # star: degrees differ a lot
    ],
)
def test_pi_round_reaches_the_average_of_constant_inputs(adj: list[list[int]]) -> None:
    phi = np.random.default_rng(1).normal(size=(len(adj), 4))
    x = _run(adj, phi, 1200, RoundGains())
    np.testing.assert_allclose(x, np.broadcast_to(phi.mean(axis=0), x.shape), atol=1e-4)


def test_metropolis_weights_are_symmetric() -> None:
    assert metropolis_weights(3, [5])[0] == metropolis_weights(5, [3])[0] == pytest.approx(1 / 6)


def test_round_gains_reject_unstable_values() -> None:
    with pytest.raises(ValueError):
        RoundGains(e_g=0.2, e_p=1.0, e_i=0.3)
    with pytest.raises(ValueError):
        RoundGains(e_g=0.2, e_p=0.3, e_i=0.6)


def test_max_round_spreads_the_maximum_then_forgets_it() -> None:
    adj = [[1], [0, 2], [1, 3], [2]]  # diameter 3
    own = np.array([1.0, 2.0, 7.0, 3.0])
    y = np.zeros(4)
    for _ in range(3):
        y = np.array([max_round(own[i], y[i], y[adj[i]], 0.99) for i in range(4)])
    assert np.all(y >= 7.0 * 0.99**3) and y[2] == 7.0
    own[2] = 1.0  # the maximum goes away: estimates decay toward the new one (3)
    for _ in range(400):
        y = np.array([max_round(own[i], y[i], y[adj[i]], 0.99) for i in range(4)])
    np.testing.assert_allclose(y, 3.0, rtol=0.05)
    assert np.all(y >= 3.0 * 0.99**3 - 1e-12)  # at most 3 hops of forgetting below it
