"""Paper 002's pairwise-cost gradients against central finite differences: rotations (eq. 13-15,
on SO(3) through the exponential map), localization (eq. 16, 22) and formation (eq. 18-20, 23),
plus the assembly of eq. 7 (each agent reads only its incident edges)."""

from __future__ import annotations

import numpy as np
import pytest

from onboard.control.formation import formation_velocity
from onboard.distributed.flow import check_edges, node_gradient
from onboard.distributed.formation import (
    bearings_from_positions,
    formation_costs,
    formation_gradients,
)
from onboard.distributed.localization import localization_costs, localization_gradients
from onboard.distributed.reshaping import F_R_PLAIN, ReshapeC, ReshapeD, ReshapeR
from onboard.distributed.rotation import rotation_costs, rotation_gradients
from onboard.geometry import so3_exp

EPS = 1e-6


def _graph(n: int) -> np.ndarray:
    und = {(i, (i + 1) % n) for i in range(n)} | {(i, (i + 2) % n) for i in range(n)}
    return np.array([*und, *[(j, i) for i, j in und]])


def _fd_node(fun, x: np.ndarray, i: int) -> np.ndarray:
    out = np.zeros(x.shape[1])
    for k in range(x.shape[1]):
        xp, xm = x.copy(), x.copy()
        xp[i, k] += EPS
        xm[i, k] -= EPS
        out[k] = (fun(xp) - fun(xm)) / (2 * EPS)
    return out


@pytest.mark.parametrize("f", [ReshapeR(2.0), ReshapeR(5.0), F_R_PLAIN])
def test_rotation_gradient_matches_exponential_map_differences(f: ReshapeR) -> None:
    rng = np.random.default_rng(1)
    n = 6
    e = _graph(n)
    rot = so3_exp(rng.normal(0, 1.0, (n, 3)))
    meas = so3_exp(rng.normal(0, 1.0, (len(e), 3)))
    g = node_gradient(e, n, rotation_gradients(rot, e, meas, f))
    for i in range(n):
        fd = np.zeros(3)
        for k in range(3):
            d = np.zeros(3)
            d[k] = EPS
            rp, rm = rot.copy(), rot.copy()
            rp[i] = rot[i] @ so3_exp(d)
            rm[i] = rot[i] @ so3_exp(-d)
            fd[k] = (
                rotation_costs(rp, e, meas, f).sum() - rotation_costs(rm, e, meas, f).sum()
            ) / (2 * EPS)
        np.testing.assert_allclose(g[i], fd, atol=1e-6)


@pytest.mark.parametrize("with_ranges", [False, True])
@pytest.mark.parametrize("dim", [2, 3])
def test_localization_gradient_matches_differences(with_ranges: bool, dim: int) -> None:
    rng = np.random.default_rng(2)
    n = 7
    e = _graph(n)
    t = rng.normal(0, 3, (n, dim))
    lam = rng.uniform(1, 4, len(e))
    u = rng.normal(size=(len(e), dim))
    u /= np.linalg.norm(u, axis=1)[:, None]
    ranges = np.where(rng.random(len(e)) < 0.5, rng.uniform(1, 5, len(e)), np.nan)
    ranges = ranges if with_ranges else None
    fd_ = ReshapeD(w=3.0, delta=0.7)
    eg = localization_gradients(t, lam, e, u, ranges, f_d=fd_)
    g = node_gradient(e, n, eg)
    for i in range(n):
        fd = _fd_node(lambda x: localization_costs(x, lam, e, u, ranges, f_d=fd_).sum(), t, i)
        np.testing.assert_allclose(g[i], fd, atol=1e-6)
    for k in range(len(e)):
        lp, lm = lam.copy(), lam.copy()
        lp[k] += EPS
        lm[k] -= EPS
        fd = (
            localization_costs(t, lp, e, u, ranges, f_d=fd_).sum()
            - localization_costs(t, lm, e, u, ranges, f_d=fd_).sum()
        ) / (2 * EPS)
        assert eg.g_edge is not None
        assert eg.g_edge[k] == pytest.approx(fd, abs=1e-6)


@pytest.mark.parametrize("f_c", [ReshapeC(0.0), ReshapeC(0.7)])
@pytest.mark.parametrize("f_d", [ReshapeD(1.0), ReshapeD(2.0, delta=0.5)])
@pytest.mark.parametrize("dim", [2, 3])
def test_formation_gradient_from_measurements_matches_differences(
    f_c: ReshapeC, f_d: ReshapeD, dim: int
) -> None:
    """Eq. 20 (+ 23) from measured bearings and ranges equals the derivative of the cost of
    eq. 18, whose distances it never reads."""
    rng = np.random.default_rng(3)
    n = 7
    e = _graph(n)
    p = rng.normal(0, 3, (n, dim))
    t_des = rng.normal(size=(len(e), dim))
    t_des /= np.linalg.norm(t_des, axis=1)[:, None]
    d_des = np.where(np.arange(len(e)) % 4 == 0, rng.uniform(1, 4, len(e)), np.nan)
    t, d = bearings_from_positions(p, e)
    eg, dropped = formation_gradients(t, t_des, d, d_des, f_c, f_d)
    assert dropped == 0
    g = node_gradient(e, n, eg)
    for i in range(n):
        fd = _fd_node(lambda x: formation_costs(x, e, t_des, d_des, f_c, f_d).sum(), p, i)
        np.testing.assert_allclose(g[i], fd, atol=1e-6)


def test_linear_fc_is_the_flight_stacks_formation_law() -> None:
    """With ``f_C = 1 - c``, ``-grad`` equals :func:`onboard.control.formation.formation_velocity`
    (yaw-only agents, body bearings)."""
    from onboard.geometry import rot_z

    rng = np.random.default_rng(4)
    n = 5
    e = _graph(n)
    p = rng.normal(0, 3, (n, 3))
    yaw = rng.uniform(-3, 3, n)
    t, _ = bearings_from_positions(p, e)
    t_des = rng.normal(size=(len(e), 3))
    t_des /= np.linalg.norm(t_des, axis=1)[:, None]
    g = node_gradient(e, n, formation_gradients(t, t_des)[0])
    r = rot_z(yaw)
    beta = np.einsum("eba,eb->ea", r[e[:, 0]], t)
    beta_des = np.einsum("eba,eb->ea", r[e[:, 0]], t_des)
    for i in range(n):
        out = [(tuple(beta[k]), tuple(beta_des[k])) for k in range(len(e)) if e[k, 0] == i]
        inn = [
            (yaw[e[k, 0]] - yaw[i], tuple(beta[k]), tuple(beta_des[k]))
            for k in range(len(e))
            if e[k, 1] == i
        ]
        u_body = np.array(formation_velocity(out, inn, k_f=1.0))
        np.testing.assert_allclose(r[i] @ u_body, -g[i], atol=1e-12)


def test_agent_gradient_reads_only_incident_edges() -> None:
    """Eq. 7 is distributed: moving a non-neighbour leaves an agent's gradient unchanged."""
    rng = np.random.default_rng(5)
    n = 8
    e = np.array([(0, 1), (1, 0), (1, 2), (2, 1), (2, 3), (3, 4), (4, 5), (5, 6), (6, 7), (7, 0)])
    t = rng.normal(size=(n, 3))
    lam = np.ones(len(e))
    u = rng.normal(size=(len(e), 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    g0 = node_gradient(e, n, localization_gradients(t, lam, e, u))
    t2 = t.copy()
    t2[4] += 10.0  # agent 4 is not a neighbour of 0 or 1
    g1 = node_gradient(e, n, localization_gradients(t2, lam, e, u))
    np.testing.assert_array_equal(g0[[0, 1]], g1[[0, 1]])
    assert not np.allclose(g0[3], g1[3])


def test_coincident_agents_drop_their_edge() -> None:
    p = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 0.0]])
    e = check_edges([(0, 1), (0, 2)], 3)
    t, _ = bearings_from_positions(p, e)
    eg, dropped = formation_gradients(t, np.array([[1.0, 0.0], [0.0, 1.0]]))
    assert dropped == 1
    np.testing.assert_array_equal(eg.g_src[0], 0.0)
    assert np.all(np.isfinite(eg.g_src))


def test_bad_edges_are_refused() -> None:
    with pytest.raises(ValueError):
        check_edges([(0, 3)], 3)
    with pytest.raises(ValueError):
        check_edges([(1, 1)], 3)
