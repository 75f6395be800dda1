"""The SfM observer's estimate of its edge's relative velocity bias (issue 22; docs/equations.md,
"Relative velocity bias of an SfM edge"): :func:`bias_rate`, :func:`bias_update` and
:class:`SfmEdge` with ``bias_gain > 0``. Off (``bias_gain = 0``) it is paper 000's observer."""

from __future__ import annotations

import math

import numpy as np
import pytest

from onboard.estimation.sfm_observer import SfmEdge, bias_rate, bias_update

D0_M = 5.0
BIAS_M_S = (0.02, -0.02, 0.01)  # 3 cm/s: u_true - u_odom


def _unit(v: np.ndarray) -> tuple[float, float, float]:
    n = v / np.linalg.norm(v)
    return (float(n[0]), float(n[1]), float(n[2]))


def _fly(edge: SfmEdge, delta: tuple[float, float, float], amp_m_s: float, duration_s: float,
         dt: float = 0.002) -> list[float]:  # fmt: skip
    """Agent ``j`` starts ``D0_M`` ahead of ``i`` and moves relative to it at ``u_true(t)`` (an
    exciting input of ``amp_m_s``, no rotation); the odometry says ``u_true - delta``. Frames
    at 50 Hz. Returns the relative distance error after 20 s."""
    r = np.array([D0_M, 0.0, 0.0])
    errors = []
    for k in range(round(duration_s / dt)):
        t = k * dt
        u_true = amp_m_s * np.array(
            [math.sin(0.31 * t), math.cos(0.23 * t), 0.2 * math.sin(0.17 * t)]
        )
        u_odom = tuple(float(x) for x in u_true - np.array(delta))
        if k % 10 == 0:
            edge.new_bearing(_unit(r), t, t, u_odom, 0.0)  # type: ignore[arg-type]
        edge.step(t, dt, u_odom, 0.0)  # type: ignore[arg-type]
        r = r + u_true * dt
        if t > 20.0:
            errors.append(abs(1.0 / edge.chi_hat / float(np.linalg.norm(r)) - 1.0))
    return errors


def test_the_correction_is_tangent_and_leaves_the_excited_direction_to_the_depth() -> None:
    beta = (1.0, 0.0, 0.0)
    beta_hat = _unit(np.array([1.0, 0.02, -0.01]))
    u = (0.3, 0.5, 0.0)  # P u along e2
    full = bias_rate(beta_hat, beta, u, 0.2, 0.0, 5.0)
    gated = bias_rate(beta_hat, beta, u, 0.2, 1.0, 5.0)
    assert abs(full[0]) < 1e-15 and abs(gated[0]) < 1e-15  # no radial part: P xi
    xi = np.subtract(beta_hat, beta)
    assert full[1] == pytest.approx(-5.0 / 0.2 * xi[1]) and full[2] == pytest.approx(-25 * xi[2])
    assert gated[1] == pytest.approx(0.0, abs=1e-15)  # along P u: the inverse depth's
    assert gated[2] == pytest.approx(full[2])
    assert bias_rate(beta, beta, u, 0.2, 0.0, 5.0) == (0.0, 0.0, 0.0)  # no error, no change


def test_the_bias_pair_is_dissipative() -> None:
    """``V = |xi|^2 / 2 + chi^2 |e|^2 / (2 gamma)`` with ``e = deltahat - delta`` decreases along
    the bearing-error dynamics ``xi' = -h xi + chi P e`` (exact depth; docs/equations.md)."""
    rng = np.random.default_rng(3)
    chi, gamma, h = 0.2, 5.0, 10.0
    for _ in range(50):
        beta = _unit(rng.normal(size=3))
        b = np.array(beta)
        proj = np.eye(3) - np.outer(b, b)
        xi = proj @ rng.normal(scale=0.01, size=3)
        e = rng.normal(scale=0.03, size=3)
        d_e = np.array(bias_rate(tuple(b + xi), beta, (0.0, 0.0, 0.0), chi, 0.0, gamma))
        d_xi = -h * xi + chi * proj @ e
        v_dot = xi @ d_xi + chi**2 / gamma * e @ d_e
        assert v_dot == pytest.approx(-h * xi @ xi, rel=1e-9, abs=1e-15)


def test_the_update_is_clamped_and_ignores_non_finite_steps() -> None:
    assert bias_update((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), 0.01, 0.1) == (0.01, 0.0, 0.0)
    big = bias_update((0.09, 0.0, 0.0), (0.0, 10.0, 0.0), 0.01, 0.1)
    assert math.hypot(*big) == pytest.approx(0.1)
    assert bias_update((0.01, 0.0, 0.0), (math.nan, 0.0, 0.0), 0.01, 0.1) == (0.01, 0.0, 0.0)


def test_the_bias_is_recovered_and_the_distance_error_falls_with_exciting_input() -> None:
    """3 cm/s of relative velocity bias and a 0.5 m/s exciting input: today's observer (the gate
    and no estimate) has the distance off by about 4 % median; with the estimate it is under 1 %
    and ``deltahat`` is within 1.2 cm/s of the bias."""
    today = SfmEdge(chi_hat=0.7 / D0_M, bias_speed_m_s=0.1)
    err_today = _fly(today, BIAS_M_S, 0.5, 60.0)
    est = SfmEdge(chi_hat=0.7 / D0_M, bias_speed_m_s=0.1, bias_gain=5.0)
    err_est = _fly(est, BIAS_M_S, 0.5, 60.0)
    assert np.median(err_today) > 0.03
    assert np.median(err_est) < 0.01 and max(err_est) < 0.5 * max(err_today)
    assert np.linalg.norm(np.subtract(est.delta_hat, BIAS_M_S)) < 0.012
    assert today.delta_hat == (0.0, 0.0, 0.0)


def test_a_still_pair_learns_the_bias_its_odometry_reads_and_keeps_its_distance() -> None:
    """Truly at rest, the odometry reads 5 cm/s across the bearing (a formation controller
    flying against its bias, delta = -bias): the estimate takes the reading back out and the
    inverse depth holds."""
    edge = SfmEdge(chi_hat=1.0 / D0_M, bias_speed_m_s=0.1, bias_gain=5.0)
    u_odom = (0.0, 0.05, 0.0)
    beta = (1.0, 0.0, 0.0)
    dt = 0.002
    for k in range(round(20.0 / dt)):
        t = k * dt
        if k % 10 == 0:
            edge.new_bearing(beta, t, t, u_odom, 0.0)
        edge.step(t, dt, u_odom, 0.0)
    assert edge.delta_hat[1] == pytest.approx(-0.05, abs=0.002)
    assert edge.chi_hat * D0_M == pytest.approx(1.0, abs=0.005)


def test_off_it_is_the_observer_without_it() -> None:
    a = SfmEdge(chi_hat=0.7 / D0_M, bias_speed_m_s=0.1)
    b = SfmEdge(chi_hat=0.7 / D0_M, bias_speed_m_s=0.1, bias_gain=0.0)
    _fly(a, BIAS_M_S, 0.5, 3.0)
    _fly(b, BIAS_M_S, 0.5, 3.0)
    assert a.chi_hat == b.chi_hat and a.beta_hat == b.beta_hat and a.e_folds == b.e_folds
