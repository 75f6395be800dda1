"""Bearing-landmark information (paper 004 eq. 6, 7, 10, 16-18, 34) against its definitions."""

from __future__ import annotations

import numpy as np
import pytest

from onboard.geometry import projector
from onboard.rigidity.information import (
    PAPER_ZETA_SQUARED,
    ZETA_CAP,
    bearing_information,
    bearing_information_terms,
    covariance_trace,
    covariance_trace_gradient,
    prior_information,
    smoothed_bearing,
    smoothing_delta,
    smoothing_zeta_squared,
    trace_of_inverse_3x3,
)


def _scenario(seed: int, n: int = 4, m: int = 3) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.uniform(-10.0, 10.0, (n, 3)), rng.uniform(-15.0, 15.0, (m, 3))


def _numerical_bearing_jacobian(x: np.ndarray, z: np.ndarray, delta: float) -> np.ndarray:
    """``d h_delta(x_i, z_j) / d x_i`` by central differences, shape ``(N, M, 3, 3)``."""
    eps = 1e-6
    cols = []
    for k in range(3):
        dx = np.zeros(3)
        dx[k] = eps
        plus = smoothed_bearing(x + dx, z, delta)
        minus = smoothed_bearing(x - dx, z, delta)
        cols.append((plus - minus) / (2.0 * eps))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("delta", [0.0, 0.3, 2.0])
def test_information_matches_definition_by_numerical_jacobians(delta: float) -> None:
    x, z = _scenario(1)
    sigma_m, prior = 0.2, np.diag([30.0, 20.0, 10.0])
    h_x = _numerical_bearing_jacobian(x, z, delta)
    expected = np.linalg.inv(prior) + np.einsum("nmka,nmkb->nab", h_x, h_x) / sigma_m**2
    got = bearing_information(x, z, sigma_m, prior, delta)
    np.testing.assert_allclose(got, expected, rtol=1e-7, atol=1e-9)


def test_unsmoothed_terms_are_projectors_over_squared_range() -> None:
    x, z = _scenario(2)
    r = z[None] - x[:, None]
    d = np.linalg.norm(r, axis=-1)
    expected = projector(r / d[..., None]) / (d**2)[..., None, None]
    np.testing.assert_allclose(bearing_information_terms(x, z, 0.0), expected, atol=1e-14)


def test_smoothed_bearing_norm_and_limit() -> None:
    x, z = _scenario(3)
    h0 = smoothed_bearing(x, z, 0.0)
    np.testing.assert_allclose(np.linalg.norm(h0, axis=-1), 1.0, atol=1e-14)
    assert np.all(np.linalg.norm(smoothed_bearing(x, z, 1.0), axis=-1) < 1.0)


def test_no_landmarks_leaves_the_prior() -> None:
    x, _ = _scenario(4)
    j = bearing_information(x, np.zeros((0, 3)), 0.1, 30.0, 1e-3)
    np.testing.assert_allclose(j, np.broadcast_to(np.eye(3) / 30.0, (4, 3, 3)))
    np.testing.assert_allclose(covariance_trace(x, np.zeros((0, 3)), 0.1, 30.0, 1e-3), 90.0)


def test_trace_of_inverse_matches_numpy() -> None:
    rng = np.random.default_rng(5)
    a = rng.normal(size=(50, 3, 3))
    spd = a @ np.swapaxes(a, -1, -2) + 0.1 * np.eye(3)
    np.testing.assert_allclose(
        trace_of_inverse_3x3(spd), np.trace(np.linalg.inv(spd), axis1=-2, axis2=-1), rtol=1e-10
    )


@pytest.mark.parametrize(("seed", "delta"), [(6, 0.0), (7, 1e-3), (8, 1.5)])
def test_trace_gradient_matches_central_differences(seed: int, delta: float) -> None:
    x, z = _scenario(seed, n=3, m=4)
    sigma_m, prior = 0.5, 30.0
    grad = covariance_trace_gradient(x, z, sigma_m, prior, delta)
    eps = 1e-5
    fd = np.zeros_like(grad)
    for j in range(z.shape[0]):
        for k in range(3):
            dz = np.zeros_like(z)
            dz[j, k] = eps
            plus = covariance_trace(x, z + dz, sigma_m, prior, delta)
            minus = covariance_trace(x, z - dz, sigma_m, prior, delta)
            fd[:, j, k] = (plus - minus) / (2.0 * eps)
    np.testing.assert_allclose(grad, fd, rtol=1e-6, atol=1e-6 * np.max(np.abs(fd)))


def test_zeta_formula_and_delta_rule() -> None:
    # eq. 16 with the paper's eq. 17 values: 10^2 * 10 * 10^4 * 2 / 0.1
    assert smoothing_zeta_squared(20.0, 2.0, 10, 1e-2, 0.1) == pytest.approx(2e8)
    delta = smoothing_delta(2.0)
    zeta = np.sqrt(PAPER_ZETA_SQUARED)
    assert 0.0 < delta < 2.0 / zeta
    # the cap binds for large zeta^2: delta stays at fraction * R_min / 1e5
    assert smoothing_delta(2.0, zeta_squared=1e14) == pytest.approx(0.5 * 2.0 / ZETA_CAP)
    with pytest.raises(ValueError, match="r_min_m"):
        smoothing_delta(0.0)


def test_theorem_v1_bound_holds_for_the_delta_rule() -> None:
    """Traces under ``s_0`` stay within ``1 + eta`` of the unsmoothed ones (Theorem V.1)."""
    r_min, m, sigma_m, eta = 2.0, 3, 0.1, 0.1
    zeta_sq = smoothing_zeta_squared(20.0, r_min, m, sigma_m, eta)
    delta = smoothing_delta(r_min, zeta_sq, fraction=0.999)
    x, z = _scenario(9, n=20, m=m)
    z = z * 0.2  # close landmarks (some within a few metres) to make the smoothing matter
    d_min = np.min(np.linalg.norm(z[None] - x[:, None], axis=-1))
    s_delta = covariance_trace(x, z, sigma_m, 30.0, delta)
    s_0 = covariance_trace(x, z, sigma_m, 30.0, 0.0)
    s0_bound = eta / (eta + 1.0) * d_min**2 / m * sigma_m**2 * (1.0 + zeta_sq)
    assert np.all(s_delta <= s0_bound)
    assert np.all(s_0 <= s_delta * (1.0 + eta)) and np.all(s_0 >= s_delta / (1.0 + eta))
    assert np.all(s_delta != s_0)  # the smoothing is small but not lost to rounding


def test_bad_prior_is_rejected() -> None:
    with pytest.raises(ValueError, match="positive definite"):
        prior_information(-1.0)
    with pytest.raises(ValueError, match="3x3"):
        prior_information(np.eye(2))
