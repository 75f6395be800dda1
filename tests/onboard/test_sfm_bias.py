"""The SfM observer's safeguards against a biased odometry (issue 22): the excitation gate and
the wander watch (onboard/estimation/sfm_observer.py). Paper 000's observer is the case with
both off, and must be unchanged by them."""

from __future__ import annotations

import math

import numpy as np
import pytest

from onboard.estimation.sfm_observer import SfmEdge, WindowAverage, excitation_gate

D0_M = 5.0


def _fly(edge: SfmEdge, u_true: tuple[float, float, float], u_odom: tuple[float, float, float],
         duration_s: float, dt: float = 0.002) -> None:  # fmt: skip
    """Agent ``j`` starts ``D0_M`` ahead of ``i`` (both at constant velocity, no rotation) and
    moves relative to it at ``u_true``; the observer is told ``u_odom``. Frames at 50 Hz."""
    r0 = np.array([D0_M, 0.0, 0.0])
    for k in range(round(duration_s / dt)):
        t = k * dt
        if k % 10 == 0:
            r = r0 + np.array(u_true) * t
            beta = tuple(float(x) for x in r / np.linalg.norm(r))
            edge.new_bearing(beta, t, t, u_odom, 0.0)  # type: ignore[arg-type]
        edge.step(t, dt, u_odom, 0.0)


def test_gate_is_closed_below_the_bias_and_open_above_twice_it() -> None:
    assert excitation_gate(0.05**2, 0.1) == 0.0
    assert excitation_gate(0.1**2, 0.1) == 0.0
    assert excitation_gate(0.15**2, 0.1) == pytest.approx(0.5)
    assert excitation_gate(0.2**2, 0.1) == 1.0
    assert excitation_gate(4.0, 0.1) == 1.0
    assert excitation_gate(0.0, 0.0) == 1.0  # off: paper 000


def test_a_hovering_pair_whose_odometry_reads_its_bias_keeps_its_estimate() -> None:
    """Truly at rest, the odometry says 5 cm/s across the bearing (a formation controller
    flying against a bias): paper 000's observer attributes the still bearing to a far target
    and walks away; the gated one holds."""
    bias = (0.0, 0.05, 0.0)
    paper = SfmEdge(chi_hat=1.0 / D0_M)
    _fly(paper, (0.0, 0.0, 0.0), bias, 30.0)
    gated = SfmEdge(chi_hat=1.0 / D0_M, bias_speed_m_s=0.1)
    _fly(gated, (0.0, 0.0, 0.0), bias, 30.0)
    assert abs(paper.chi_hat * D0_M - 1.0) > 0.2
    assert gated.chi_hat * D0_M == pytest.approx(1.0, abs=0.005)
    assert gated.gate == 0.0 and gated.e_folds == 0.0  # no excitation counted either


def test_with_an_open_gate_the_observer_is_paper_000s() -> None:
    """Well excited (1 m/s across the bearing, twice the gate's full-open speed and more), the
    gated observer converges exactly like the paper's from a 30 % wrong start."""
    u = (0.0, 1.0, 0.0)
    paper = SfmEdge(chi_hat=0.7 / D0_M)
    gated = SfmEdge(chi_hat=0.7 / D0_M, bias_speed_m_s=0.1)
    _fly(paper, u, u, 4.0)
    _fly(gated, u, u, 4.0)
    assert gated.chi_hat == paper.chi_hat
    assert gated.e_folds == paper.e_folds
    d = math.hypot(D0_M, 4.0)
    assert 1.0 / gated.chi_hat == pytest.approx(d, rel=0.01)


def _watched(chi0: float) -> SfmEdge:
    return SfmEdge(chi_hat=chi0, wander_window=WindowAverage(2.0), wander_max=0.02, folds_cap=4.5)


def test_an_estimate_that_keeps_being_corrected_is_not_counted_converged() -> None:
    """The odometry reads 0.3 m/s of closing speed that is not there: the observer's
    corrections keep fighting its own model, the estimate is as good as that bias allows but
    the edge's e-foldings stay below the convergence threshold (5); with exact odometry they
    pass it."""
    u_true = (0.0, 1.0, 0.0)
    biased = _watched(1.0 / D0_M)
    _fly(biased, u_true, (-0.3, 1.0, 0.0), 6.0)
    exact = _watched(1.0 / D0_M)
    _fly(exact, u_true, u_true, 6.0)
    assert biased.wander > 0.02 and biased.e_folds <= 4.5
    assert exact.wander < 0.005 and exact.e_folds > 10.0
