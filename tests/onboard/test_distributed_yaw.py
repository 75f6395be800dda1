"""The yaw-only case of paper 002's rotation estimation (onboard/distributed/yaw.py): relative
yaws from reciprocal levelled bearings (fig. 6) with their degenerate case and noise law, and
eq. 13-15 on SO(2) (gradients against finite differences, the same iterates as the SO(3) flow,
convergence from random yaws, the winding trap of the unreshaped cost)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from onboard.distributed.flow import node_gradient, so2_step
from onboard.distributed.metrics import rotation_error_deg
from onboard.distributed.reshaping import F_R, F_R_PLAIN, ReshapeR
from onboard.distributed.solvers import estimate_rotations, estimate_yaws
from onboard.distributed.yaw import (
    relative_yaw_from_reciprocal,
    relative_yaw_std_rad,
    relative_yaws,
    yaw_costs,
    yaw_error_deg,
    yaw_errors,
    yaw_gradients,
)
from onboard.geometry import rot_z, wrap_angle
from onboard.vision.levelling import level_bearings, unlevel_bearings

EPS = 1e-6


def _pairs(n: int) -> np.ndarray:
    """Undirected ring with hops 1 and 3, ``i < j``: one relative yaw per reciprocal pair."""
    und = {tuple(sorted((i, (i + h) % n))) for h in (1, 3) for i in range(n)}
    return np.array(sorted(und))


def _levelled_pairs(rng: np.random.Generator, n: int, e: np.ndarray):
    """Random positions, yaws, rolls and pitches; the levelled reciprocal bearings of ``e``."""
    p = rng.uniform(-5, 5, (n, 3))
    psi = rng.uniform(-np.pi, np.pi, n)
    roll, pitch = rng.normal(0, 0.2, n), rng.normal(0, 0.2, n)
    b = p[e[:, 1]] - p[e[:, 0]]
    b /= np.linalg.norm(b, axis=1)[:, None]
    # what the tilted cameras measure (heading frame -> body), then the levelling undoes the tilt
    lev_ij = np.einsum("eba,eb->ea", rot_z(psi[e[:, 0]]), b)
    lev_ji = np.einsum("eba,eb->ea", rot_z(psi[e[:, 1]]), -b)
    body_ij = unlevel_bearings(lev_ij, roll[e[:, 0]], pitch[e[:, 0]])
    body_ji = unlevel_bearings(lev_ji, roll[e[:, 1]], pitch[e[:, 1]])
    return (
        psi,
        level_bearings(body_ij, roll[e[:, 0]], pitch[e[:, 0]]),
        level_bearings(body_ji, roll[e[:, 1]], pitch[e[:, 1]]),
    )


def test_relative_yaw_from_levelled_reciprocal_bearings_is_the_truth() -> None:
    rng = np.random.default_rng(3)
    n = 12
    e = _pairs(n)
    psi, bij, bji = _levelled_pairs(rng, n, e)
    ry = relative_yaw_from_reciprocal(bij, bji)
    assert ry.usable.all()
    err = wrap_angle(ry.psi_rad - (psi[e[:, 1]] - psi[e[:, 0]]))
    assert np.abs(err).max() < 1e-12
    # the defining relation beta_ij = -R_z(psi_ij) beta_ji
    np.testing.assert_allclose(bij, -np.einsum("eab,eb->ea", rot_z(ry.psi_rad), bji), atol=1e-12)


def test_vertical_bearings_are_flagged_not_guessed() -> None:
    up = np.array([0.0, 0.0, -1.0])
    tilt = np.array([0.05, 0.0, -1.0])
    tilt /= np.linalg.norm(tilt)
    level = np.array([1.0, 0.0, 0.0])
    bij = np.stack([level, -up, -tilt, level, level])
    bji = np.stack([-level, up, tilt, [np.nan, 0, 0], -level])
    ry = relative_yaw_from_reciprocal(bij, bji)
    assert ry.usable.tolist() == [True, False, False, False, True]
    assert np.isnan(ry.psi_rad[1:4]).all()
    assert ry.psi_rad[0] == pytest.approx(0.0)
    # a threshold below the tilt's horizontal norm (0.05) accepts the tilted pair
    assert relative_yaw_from_reciprocal(bij, bji, min_horizontal=0.01).usable[2]
    with pytest.raises(ValueError):
        relative_yaw_from_reciprocal(bij, bji[:, :2])
    with pytest.raises(ValueError):
        relative_yaw_from_reciprocal(bij[:3], bji)
    with pytest.raises(ValueError):
        relative_yaw_from_reciprocal(bij, bji, min_horizontal=0.0)


@pytest.mark.parametrize("elevation_deg", [0.0, 60.0])
def test_relative_yaw_noise_follows_the_first_order_law(elevation_deg: float) -> None:
    """Monte Carlo std of psi from noisy bearings against sigma / cos(elevation)."""
    rng = np.random.default_rng(4)
    m, sigma = 40000, math.radians(1.0)
    el = math.radians(elevation_deg)
    b = np.array([math.cos(el), 0.0, -math.sin(el)])  # j is up and ahead of i
    psi_true = 0.7
    bij = np.tile(b, (m, 1))
    bji = np.tile(-rot_z(-psi_true) @ b, (m, 1))

    def noisy(x: np.ndarray) -> np.ndarray:
        nz = rng.normal(0, sigma / math.sqrt(2), x.shape)
        nz -= np.sum(nz * x, axis=1)[:, None] * x
        y = x + nz
        return y / np.linalg.norm(y, axis=1)[:, None]

    ry = relative_yaw_from_reciprocal(noisy(bij), noisy(bji))
    std = float(np.std(wrap_angle(ry.psi_rad - psi_true)))
    pred = float(relative_yaw_std_rad(b, -rot_z(-psi_true) @ b, sigma))
    assert pred == pytest.approx(sigma / math.cos(el), rel=1e-9)
    assert std == pytest.approx(pred, rel=0.03)


@pytest.mark.parametrize("f", [ReshapeR(2.0), ReshapeR(5.0), F_R_PLAIN])
def test_yaw_gradient_matches_differences_and_the_closed_form(f: ReshapeR) -> None:
    rng = np.random.default_rng(1)
    n = 7
    e = _pairs(n)
    psi = rng.uniform(-np.pi, np.pi, n)
    meas = rng.uniform(-np.pi, np.pi, len(e))
    g = node_gradient(e, n, yaw_gradients(psi, e, meas, f))
    assert g.shape == (n,)
    for i in range(n):
        pp, pm = psi.copy(), psi.copy()
        pp[i] += EPS
        pm[i] -= EPS
        fd = (yaw_costs(pp, e, meas, f).sum() - yaw_costs(pm, e, meas, f).sum()) / (2 * EPS)
        assert g[i] == pytest.approx(fd, abs=1e-6)
    # closed form on SO(2): phi = f_R(|e|), grad_{psi_j} = f_R'(|e|)/|e| e = -grad_{psi_i}
    err = yaw_errors(psi, e, meas)
    np.testing.assert_allclose(yaw_costs(psi, e, meas, f), f.value(np.abs(err)), atol=1e-12)
    eg = yaw_gradients(psi, e, meas, f)
    np.testing.assert_allclose(eg.g_dst, f.deriv_over_x(np.abs(err)) * err, atol=1e-12)
    np.testing.assert_allclose(eg.g_src, -eg.g_dst, atol=1e-12)


def test_yaw_flow_is_the_so3_flow_at_rotations_about_the_vertical() -> None:
    rng = np.random.default_rng(2)
    n = 9
    e = _pairs(n)
    psi_true = rng.uniform(-np.pi, np.pi, n)
    meas = wrap_angle(relative_yaws(psi_true, e) + rng.normal(0, 0.3, len(e)))
    psi0 = rng.uniform(-np.pi, np.pi, n)
    y = estimate_yaws(e, meas, psi0, 40)
    r = estimate_rotations(e, rot_z(meas), rot_z(psi0), 40)
    np.testing.assert_allclose(rot_z(y.psi_rad), r.rot, atol=1e-9)
    np.testing.assert_allclose(y.cost, r.cost, atol=1e-9)


def test_so2_step_wraps() -> None:
    out = so2_step(np.array([3.1, -3.1]), np.array([-0.1, 0.1]), 1.0)
    np.testing.assert_allclose(out, [3.2 - 2 * np.pi, -3.2 + 2 * np.pi])


def test_yaws_converge_from_random_starts_with_reshaping() -> None:
    rng = np.random.default_rng(5)
    n = 10
    e = _pairs(n)
    for _ in range(5):
        psi_true = rng.uniform(-np.pi, np.pi, n)
        psi0 = rng.uniform(-np.pi, np.pi, n)
        res = estimate_yaws(e, relative_yaws(psi_true, e), psi0, 2000, grad_tol=1e-9)
        assert yaw_error_deg(res.psi_rad, psi_true) < 1e-4
        assert np.all(np.diff(res.cost) <= 1e-12)  # 1 / L descends every round
        # the gauge: the sum of the yaws is kept (mod 2 pi)
        assert abs(wrap_angle(res.psi_rad.sum() - psi0.sum())) < 1e-9
        anch = estimate_yaws(e, relative_yaws(psi_true, e), psi0, 2000, anchor=0)
        assert anch.psi_rad[0] == pytest.approx(psi0[0])
        # the error metric agrees with the SO(3) one
        assert yaw_error_deg(anch.psi_rad, psi_true) == pytest.approx(
            rotation_error_deg(rot_z(anch.psi_rad), rot_z(psi_true)), abs=1e-6
        )


def test_plain_cost_is_trapped_by_a_winding_start_reshaped_one_escapes() -> None:
    """Starting one full turn wound around the ring (every edge off by 2 pi / N): a local minimum
    of the plain x^2 / 2, left by f_R of eq. 15 (its curvature is negative beyond 1 / b)."""
    rng = np.random.default_rng(6)
    n = 10
    e = _pairs(n)
    psi_true = rng.uniform(-np.pi, np.pi, n)
    psi0 = psi_true + 2 * np.pi * np.arange(n) / n + rng.normal(0, 0.01, n)
    meas = relative_yaws(psi_true, e)
    plain = estimate_yaws(e, meas, psi0, 3000, F_R_PLAIN)
    reshaped = estimate_yaws(e, meas, psi0, 3000, F_R)
    assert yaw_error_deg(plain.psi_rad, psi_true) > 90
    assert yaw_error_deg(reshaped.psi_rad, psi_true) < 1e-4
