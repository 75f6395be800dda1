"""Conic fitting, RANSAC (eq. 35) and the disc pose from its conic (paper 002 eq. 32-34)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from onboard.vision.conics import (
    circle_conic,
    conic_from_ellipse,
    disc_poses_from_conic,
    ellipse_geometry,
    fit_conic_exact,
    fit_ellipse_direct,
    ransac_ellipse,
    ransac_iterations,
    sampson_distance,
)


def _ellipse_points(t: np.ndarray, c=(40.0, -12.0), a=9.0, b=4.0, ang=0.6) -> np.ndarray:
    x, y = a * np.cos(t), b * np.sin(t)
    co, si = math.cos(ang), math.sin(ang)
    return np.column_stack([c[0] + co * x - si * y, c[1] + si * x + co * y])


def test_ransac_iteration_count_eq35() -> None:
    # N = log(1-p)/log(1-(1-eps)^n): p=0.99, eps=0.5, n=5 -> 145.05...
    assert ransac_iterations(0.99, 0.5, 5) == pytest.approx(math.log(0.01) / math.log(1 - 0.5**5))
    assert ransac_iterations(0.99, 0.5, 5) == pytest.approx(145.05, abs=0.01)
    assert ransac_iterations(0.99, 0.0, 5) == 0.0
    assert ransac_iterations(0.99, 1.0, 5) == math.inf
    assert ransac_iterations(0.99, 0.3, 5) < ransac_iterations(0.999, 0.3, 5)


def test_eq32_conic_from_ellipse_round_trip() -> None:
    q = conic_from_ellipse([40.0, -12.0], 0.6, 9.0, 4.0)
    pts = _ellipse_points(np.linspace(0, 2 * np.pi, 30))
    assert np.max(sampson_distance(q, pts)) < 1e-9
    g = ellipse_geometry(q)
    np.testing.assert_allclose(g.center, [40.0, -12.0], atol=1e-9)
    assert (g.semi_major, g.semi_minor) == pytest.approx((9.0, 4.0))
    assert math.tan(g.major_angle_rad) == pytest.approx(math.tan(0.6))


def test_exact_and_direct_fits_recover_the_ellipse() -> None:
    pts = _ellipse_points(np.array([0.1, 1.3, 2.0, 3.9, 5.1]))
    for q in (fit_conic_exact(pts), fit_ellipse_direct(_ellipse_points(np.linspace(0, 6, 40)))):
        g = ellipse_geometry(q)
        np.testing.assert_allclose(g.center, [40.0, -12.0], atol=1e-7)
        assert (g.semi_major, g.semi_minor) == pytest.approx((9.0, 4.0), abs=1e-7)


def test_ransac_rejects_outliers() -> None:
    rng = np.random.default_rng(3)
    good = _ellipse_points(rng.uniform(0, 2 * np.pi, 140)) + rng.normal(0, 0.05, (140, 2))
    bad = rng.uniform([25, -25], [55, 0], (60, 2))
    pts = np.vstack([good, bad])
    fit = ransac_ellipse(pts, 0.3, rng)
    g = ellipse_geometry(fit.conic)
    np.testing.assert_allclose(g.center, [40.0, -12.0], atol=0.05)
    assert (g.semi_major, g.semi_minor) == pytest.approx((9.0, 4.0), abs=0.05)
    assert fit.inliers[:140].mean() > 0.95 and fit.inliers[140:].mean() < 0.15
    naive = ellipse_geometry(fit_ellipse_direct(pts))
    assert abs(naive.semi_minor - 4.0) > 1.0  # the outliers matter without RANSAC


@pytest.mark.parametrize("seed", range(6))
def test_disc_pose_exact_on_noiseless_conic(seed: int) -> None:
    rng = np.random.default_rng(seed)
    center = np.array([rng.uniform(-2, 2), rng.uniform(-1.5, 1.5), rng.uniform(3, 15)])
    normal = -center / np.linalg.norm(center) + rng.normal(0, 0.5, 3)
    normal /= np.linalg.norm(normal)
    if normal @ center > 0:
        normal = -normal
    radius = rng.uniform(0.1, 0.5)
    q = circle_conic(center, normal, radius) * rng.choice([-1.0, 1.0]) * rng.uniform(0.1, 10)
    centers, normals = disc_poses_from_conic(q, radius)
    k = int(np.argmax(normals @ normal))
    np.testing.assert_allclose(centers[k], center, atol=1e-9 * np.linalg.norm(center))
    np.testing.assert_allclose(normals[k], normal, atol=1e-9)
    # the other candidate reproduces the same image conic (the two-fold ambiguity)
    q_other = circle_conic(centers[1 - k], normals[1 - k], radius)
    q_ref = circle_conic(center, normal, radius)
    assert min(np.abs(q_other - q_ref).max(), np.abs(q_other + q_ref).max()) < 1e-9
    assert np.all(centers[:, 2] > 0) and np.all(np.sum(normals * centers, axis=1) < 0)


def test_disc_pose_from_points_via_fit() -> None:
    # the conic fitted to projected boundary points gives the same pose (independent path)
    center, normal, r = np.array([0.4, -0.2, 6.0]), np.array([0.3, 0.1, -1.0]), 0.25
    normal /= np.linalg.norm(normal)
    u = np.cross(normal, [1.0, 0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    t = np.linspace(0, 2 * np.pi, 50, endpoint=False)
    x3 = center + r * (np.cos(t)[:, None] * u + np.sin(t)[:, None] * v)
    xy = x3[:, :2] / x3[:, 2:]
    centers, normals = disc_poses_from_conic(fit_ellipse_direct(xy), r)
    k = int(np.argmax(normals @ normal))
    np.testing.assert_allclose(centers[k], center, atol=1e-6)


def test_non_ellipse_rejected() -> None:
    with pytest.raises(ValueError):
        disc_poses_from_conic(np.diag([1.0, -1.0, -1.0]) * 0 + np.diag([1.0, 1.0, 1.0]), 0.1)
    with pytest.raises(ValueError):
        ellipse_geometry(np.diag([1.0, -1.0, -1.0]))


def _direct_fit_reference(points: np.ndarray) -> np.ndarray:
    """Halir-Flusser direct fit written out with numpy's general eigensolver (the form
    :func:`fit_ellipse_direct` had before it used OpenCV's real-eigenvalue solver)."""
    mean = points.mean(axis=0)
    s = math.sqrt(2.0) / math.sqrt(np.mean(np.sum((points - mean) ** 2, axis=1)))
    t = np.array([[s, 0.0, -s * mean[0]], [0.0, s, -s * mean[1]], [0.0, 0.0, 1.0]])
    x, y = s * (points[:, 0] - mean[0]), s * (points[:, 1] - mean[1])
    d = np.column_stack([x * x, x * y, y * y, x, y, np.ones_like(x)])
    sc = d.T @ d
    tm = -np.linalg.solve(sc[3:, 3:], sc[3:, :3])
    m = sc[:3, :3] + sc[:3, 3:] @ tm
    w, v = np.linalg.eig(np.stack([m[2] / 2.0, -m[1], m[0] / 2.0]))
    v = np.real(v)
    ok = np.flatnonzero(4.0 * v[0] * v[2] - v[1] ** 2 > 0.0)
    a1 = v[:, ok[np.argmin(np.abs(np.real(w[ok])))]]
    a, b, c, dd, e, f = np.concatenate([a1, tm @ a1])
    q = np.array([[a, b / 2, dd / 2], [b / 2, c, e / 2], [dd / 2, e / 2, f]])
    q = t.T @ q @ t
    return q / np.linalg.norm(q)


@pytest.mark.parametrize("seed", range(6))
def test_direct_fit_matches_the_general_eigensolver(seed: int) -> None:
    """Same ellipse as the textbook form on noisy full contours and short arcs, and a sign
    fixed by the conic (positive 2x2 block), whatever the solver's eigenvector signs."""
    rng = np.random.default_rng(seed)
    span = (2 * np.pi, 2.0, 1.0)[seed % 3]
    t = rng.uniform(0.0, span, 60)
    pts = _ellipse_points(t, a=rng.uniform(3, 30), b=rng.uniform(1, 3), ang=rng.uniform(0, 3))
    pts += rng.normal(0.0, 0.05, pts.shape)
    q = fit_ellipse_direct(pts)
    ref = _direct_fit_reference(pts)
    assert min(np.abs(q - ref).max(), np.abs(q + ref).max()) < 1e-9
    assert q[0, 0] + q[1, 1] > 0.0
