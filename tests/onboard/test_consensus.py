"""PI dynamic average consensus: exact average for constant inputs from any initial state,
tracking of a changing average, and the invariant that makes it work."""

import math

import numpy as np
import pytest

from onboard.estimation.consensus import PIConsensus, pi_consensus_rates

RING = {i: [(i - 1) % 6, (i + 1) % 6] for i in range(6)}


def _run(phi_of_t, duration, dt=0.002, x0=None, seed=0):
    rng = np.random.default_rng(seed)
    x0 = rng.normal(size=(6, 1)) * 5 if x0 is None else x0
    est = [PIConsensus(list(x0[i]), list(rng.normal(size=1))) for i in range(6)]
    hist = []
    for k in range(int(duration / dt)):
        t = k * dt
        phi = phi_of_t(t)
        snapshot = [(list(e.x), list(e.z)) for e in est]  # everyone uses last step's values
        for i, e in enumerate(est):
            e.step(dt, [phi[i]], [snapshot[j] for j in RING[i]])
        hist.append((t, np.array([e.x[0] for e in est]), np.mean(phi)))
    return hist


def test_constant_inputs_reach_the_exact_average_from_any_start():
    phi = np.array([1.0, -2.0, 3.5, 0.0, 10.0, 4.0])
    hist = _run(lambda t: phi, duration=3.0)
    _, x, avg = hist[-1]
    assert np.allclose(x, avg, atol=1e-6)
    assert not np.allclose(hist[0][1], avg, atol=1.0)


def _steady_error(phi, duration=6.0, settle=2.0):
    hist = _run(phi, duration=duration)
    return max(np.max(np.abs(x - avg)) for t, x, avg in hist if t > settle), hist


def test_tracks_a_changing_average():
    base = np.arange(6.0)
    # common-mode ramp: the mean of the estimates lags by rate / gamma = 1.0 / 50
    err_ramp, hist = _steady_error(lambda t: base + 1.0 * t)
    assert err_ramp < 0.025
    assert np.ptp([avg for _, _, avg in hist]) > 5.0  # the average really moved
    # agents' inputs oscillating out of phase: error proportional to their rate of change
    err_fast, _ = _steady_error(lambda t: base + 2.0 * np.sin(0.5 * t + base))
    err_slow, _ = _steady_error(lambda t: base + 2.0 * np.sin(0.05 * t + base), duration=8.0)
    assert err_fast < 0.2  # under 10 % of the input amplitude at 1 unit/s
    assert err_slow < err_fast / 5.0


def test_coupling_terms_cancel_in_the_sum():
    rng = np.random.default_rng(2)
    x = rng.normal(size=(6, 2))
    z = rng.normal(size=(6, 2))
    phi = rng.normal(size=(6, 2))
    dx_sum = np.zeros(2)
    dz_sum = np.zeros(2)
    for i in range(6):
        dx, dz = pi_consensus_rates(x[i], z[i], phi[i], [(x[j], z[j]) for j in RING[i]], 3.0)
        dx_sum += dx
        dz_sum += dz
    assert np.allclose(dx_sum, 3.0 * (phi - x).sum(axis=0))
    assert np.allclose(dz_sum, 0.0)


def test_vector_length_mismatch_is_an_error():
    with pytest.raises(ValueError):
        pi_consensus_rates([0.0, 1.0], [0.0, 0.0], [1.0], [])
    assert math.isfinite(PIConsensus([0.0]).step(0.002, [1.0], [])[0])
