"""Paper 002's convergence conditions, checked numerically with ideal measurements.

Eq. 9: along radial lines ``x0 + s v`` from a global minimizer ``x0`` (random state, random
direction) every pairwise cost is non-decreasing in ``s >= 0``; ``d phi_ij / ds`` is computed from
the analytic gradients (themselves checked against finite differences). For rotations the lines are
geodesics ``R0_i exp(s hat(v_i))`` inside the set of eq. 14. Eq. 21 for the shipped ``f_C`` and
``sign f_D' = sign`` for the shipped ``f_D``; a function that violates eq. 21 breaks eq. 9.
"""

from __future__ import annotations

import numpy as np
import pytest

from onboard.distributed.formation import bearings_from_positions, formation_gradients
from onboard.distributed.localization import localization_gradients
from onboard.distributed.reshaping import (
    F_R_PLAIN,
    ReshapeC,
    ReshapeD,
    ReshapeR,
    fc_condition,
    fd_sign_condition,
)
from onboard.distributed.rotation import relative_rotations, rotation_gradients
from onboard.geometry import so3_distance, so3_exp

S_GRID = np.linspace(0.0, 4.0, 41)[1:]
SHIPPED_FC = [ReshapeC(0.0), ReshapeC(0.5), ReshapeC(3.0)]
SHIPPED_FD = [ReshapeD(1.0), ReshapeD(5.0), ReshapeD(1.0, delta=0.3), ReshapeD(0.2, delta=2.0)]


def _graph(n: int) -> np.ndarray:
    und = {(i, (i + 1) % n) for i in range(n)} | {(i, (i + 3) % n) for i in range(n)}
    return np.array([*und, *[(j, i) for i, j in und]])


def _edge_rates(eg, e: np.ndarray, v: np.ndarray, v_edge: np.ndarray | None = None) -> np.ndarray:
    """``d phi_ij / ds`` per edge along the direction ``(v, v_edge)``."""
    rate = np.sum(eg.g_src * v[e[:, 0]], axis=1) + np.sum(eg.g_dst * v[e[:, 1]], axis=1)
    if v_edge is not None:
        rate = rate + eg.g_edge * v_edge
    return rate


@pytest.mark.parametrize("with_ranges", [False, True])
@pytest.mark.parametrize("seed", range(5))
def test_localization_costs_increase_along_radial_lines(seed: int, with_ranges: bool) -> None:
    rng = np.random.default_rng(seed)
    n, dim = 8, 3
    e = _graph(n)
    p = rng.normal(0, 4, (n, dim))
    u, d = bearings_from_positions(p, e)
    scale = 1.0 if with_ranges else rng.uniform(1.0, 3.0) / d.min()
    t0 = scale * p + rng.normal(size=dim)  # a global minimizer: similar (congruent with ranges)
    lam0 = scale * d
    ranges = np.where(np.arange(len(e)) % 3 == 0, d, np.nan) if with_ranges else None
    v, v_lam = rng.normal(size=(n, dim)), rng.normal(size=len(e))
    for f_d in SHIPPED_FD:
        for s in S_GRID:
            eg = localization_gradients(t0 + s * v, lam0 + s * v_lam, e, u, ranges, f_d=f_d)
            assert np.all(_edge_rates(eg, e, v, v_lam) >= -1e-9)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("seed", range(3))
def test_formation_costs_increase_along_radial_lines(seed: int, dim: int) -> None:
    rng = np.random.default_rng(10 + seed)
    n = 7
    e = _graph(n)
    p_des = rng.normal(0, 4, (n, dim))
    t_des, d_des = bearings_from_positions(p_des, e)
    ranged = np.where(np.arange(len(e)) % 5 == 0, d_des, np.nan)
    v = rng.normal(size=(n, dim))
    for f_c in SHIPPED_FC:
        for f_d in SHIPPED_FD[::2]:
            for use_range in (False, True):
                # similar (bearing only) or congruent (ranges) to the desired formation
                alpha = 1.0 if use_range else rng.uniform(0.3, 3.0)
                p0 = alpha * p_des + rng.normal(size=dim)
                for s in S_GRID:
                    t, d = bearings_from_positions(p0 + s * v, e)
                    eg, _ = formation_gradients(
                        t, t_des, d if use_range else None, ranged if use_range else None, f_c, f_d
                    )
                    assert np.all(_edge_rates(eg, e, v) >= -1e-9)


@pytest.mark.parametrize("f", [ReshapeR(2.0), F_R_PLAIN])
@pytest.mark.parametrize("seed", range(5))
def test_rotation_costs_increase_along_geodesics_inside_eq14(seed: int, f: ReshapeR) -> None:
    rng = np.random.default_rng(20 + seed)
    n = 8
    e = _graph(n)
    r0 = so3_exp(rng.normal(0, 2.0, (n, 3)))
    meas = relative_rotations(r0, e)
    v = rng.normal(size=(n, 3))
    checked = 0
    for s in np.linspace(0.0, 3.0, 121)[1:]:
        rot = r0 @ so3_exp(s * v)
        if np.any(so3_distance(relative_rotations(rot, e), meas) >= np.pi / 2):
            break  # the radial line leaves the set X of eq. 14
        eg = rotation_gradients(rot, e, meas, f)
        assert np.all(_edge_rates(eg, e, v) >= -1e-9)
        checked += 1
    assert checked >= 10


@pytest.mark.parametrize("f", SHIPPED_FC)
def test_shipped_fc_are_decreasing_and_satisfy_eq21(f: ReshapeC) -> None:
    c = np.linspace(-1.0, 1.0, 2001)
    assert np.all(f.deriv(c) < 0)
    assert np.all(fc_condition(f, c) <= 1e-15)


@pytest.mark.parametrize("f", SHIPPED_FD)
def test_shipped_fd_have_the_sign_of_their_argument(f: ReshapeD) -> None:
    x = np.concatenate([np.linspace(-20, 20, 4001), [0.0, 1e-9, -1e-9]])
    assert fd_sign_condition(f, x)


def test_sign_check_rejects_a_bad_fd() -> None:
    """``f_D(x) = x^2 - x`` has ``f_D'(0.2) < 0``: the checker must say no."""

    class Bad(ReshapeD):
        def deriv(self, x):  # type: ignore[override]
            return 2 * np.asarray(x) - 1.0

    assert not fd_sign_condition(Bad(), np.linspace(-1, 1, 11))


def test_fc_violating_eq21_breaks_monotonicity() -> None:
    """A saturating ``f_C(c) = 1 - exp(-(1 - c) / 0.05)`` (decreasing, eq. 21 > 0 for c < 1):
    eq. 9 fails on a radial line passing beside the neighbour, so the condition is not vacuous."""

    class Saturating(ReshapeC):
        def value(self, c):  # type: ignore[override]
            return 1.0 - np.exp(-(1.0 - np.asarray(c)) / 0.05)

        def deriv(self, c):  # type: ignore[override]
            return -np.exp(-(1.0 - np.asarray(c)) / 0.05) / 0.05

    f = Saturating()
    assert np.all(fc_condition(f, np.linspace(-1, 0.99, 50)) > 0)
    e = np.array([(0, 1)])
    t_des = np.array([[1.0, 0.0]])
    p0 = np.array([[0.0, 0.0], [1.0, 0.0]])
    v = np.array([[0.0, 0.0], [np.cos(3.0), np.sin(3.0)]])  # back past the neighbour
    rates = []
    for s in S_GRID:
        t, _ = bearings_from_positions(p0 + s * v, e)
        eg, _ = formation_gradients(t, t_des, f_c=f)
        rates.append(_edge_rates(eg, e, v)[0])
    assert min(rates) < -1e-3
