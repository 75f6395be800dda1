"""The fused team scale (onboard/estimation/team_scale.py, docs/equations.md "Fused team
scale"): the law-of-sines shape, and SfM distances fused through it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from onboard.estimation.team_scale import (
    fused_distances,
    triangle_log_shape,
    vertex_angle,
)

P = np.array([[0.0, 0.0, -5.0], [9.0, 1.0, -6.0], [3.0, 7.5, -5.5]])
PAIRS = [(0, 1), (0, 2), (1, 2)]


def _unit(v: np.ndarray) -> tuple[float, float, float]:
    v = v / np.linalg.norm(v)
    return (float(v[0]), float(v[1]), float(v[2]))


def _true() -> dict[tuple[int, int], float]:
    return {(a, b): float(np.linalg.norm(P[b] - P[a])) for a, b in PAIRS}


def _triangle(p: np.ndarray = P) -> tuple:
    angles = [
        vertex_angle(_unit(p[(v + 1) % 3] - p[v]), _unit(p[(v + 2) % 3] - p[v])) for v in range(3)
    ]
    shape = triangle_log_shape(angles)
    assert shape is not None
    return (((1, 2), (0, 2), (0, 1)), shape)  # the sides opposite vertices 0, 1, 2


def test_law_of_sines_gives_the_side_ratios() -> None:
    (_, shape) = _triangle()
    d = _true()
    ratio = math.exp(shape[2] - shape[0])  # side (0, 1) over side (1, 2)
    assert ratio == pytest.approx(d[(0, 1)] / d[(1, 2)], rel=1e-9)


def test_degenerate_or_inconsistent_triangles_have_no_shape() -> None:
    assert triangle_log_shape([math.pi - 0.02, 0.01, 0.01]) is None  # collinear
    assert triangle_log_shape([1.0, 1.0, 0.5]) is None  # does not add up to pi
    assert triangle_log_shape([1.0, float("nan"), 1.0]) is None
    assert triangle_log_shape([math.pi / 3] * 3) == pytest.approx(
        (math.log(math.sin(math.pi / 3)),) * 3
    )


def test_one_biased_edge_is_pulled_to_the_team_scale() -> None:
    """Edge (0, 1) 9 % long, the others 1 % short: per edge the worst pair is 9 % off, on the
    fused scale every pair is off by the (weighted) mean, under 3 %."""
    d = _true()
    meas = {(0, 1): d[(0, 1)] * 1.09, (0, 2): d[(0, 2)] * 0.99, (1, 2): d[(1, 2)] * 0.99}
    fused = fused_distances(PAIRS, meas, {e: 1.0 for e in PAIRS}, [_triangle()])
    err = {e: abs(fused[e] / d[e] - 1.0) for e in PAIRS}
    assert max(err.values()) < 0.03
    assert max(err.values()) < max(abs(meas[e] / d[e] - 1.0) for e in PAIRS) / 3
    # the same shape (near-hard: K = 1e4 max w): the fused distances keep the true ratios
    assert fused[(0, 1)] / fused[(1, 2)] == pytest.approx(d[(0, 1)] / d[(1, 2)], rel=1e-4)


def test_a_weakly_excited_edge_has_little_say() -> None:
    d = _true()
    meas = {(0, 1): d[(0, 1)] * 1.30, (0, 2): d[(0, 2)], (1, 2): d[(1, 2)]}
    equal = fused_distances(PAIRS, meas, {e: 1.0 for e in PAIRS}, [_triangle()])
    weighted = fused_distances(PAIRS, meas, {(0, 1): 0.01, (0, 2): 1.0, (1, 2): 1.0}, [_triangle()])
    assert abs(weighted[(0, 2)] / d[(0, 2)] - 1.0) < 0.01 < abs(equal[(0, 2)] / d[(0, 2)] - 1.0)


def test_without_a_triangle_each_edge_keeps_its_own_estimate() -> None:
    meas = {(0, 1): 9.0, (0, 2): 8.0}
    fused = fused_distances(PAIRS, meas, {e: 1.0 for e in PAIRS}, [])
    assert fused == pytest.approx({(0, 1): 9.0, (0, 2): 8.0})  # (1, 2): unmeasured, left out


def test_an_unmeasured_side_follows_from_the_shape() -> None:
    d = _true()
    meas = {(0, 1): d[(0, 1)], (0, 2): d[(0, 2)]}
    fused = fused_distances(PAIRS, meas, {e: 1.0 for e in PAIRS}, [_triangle()])
    assert fused[(1, 2)] == pytest.approx(d[(1, 2)], rel=1e-4)


def test_bad_measurements_are_ignored() -> None:
    d = _true()
    meas = {(0, 1): float("nan"), (0, 2): -3.0, (1, 2): d[(1, 2)], (5, 6): 1.0}
    fused = fused_distances(PAIRS, meas, {e: 1.0 for e in (*PAIRS, (5, 6))}, [_triangle()])
    assert fused[(0, 1)] == pytest.approx(d[(0, 1)], rel=1e-4)
    assert fused_distances(PAIRS, {(0, 1): 5.0}, {(0, 1): 0.0}, [_triangle()]) == {}
