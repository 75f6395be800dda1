"""The rigidity estimate's own uncertainty (issue 30): its lag behind a fast-changing framework."""

from __future__ import annotations

import math

import numpy as np
import pytest

from messages.agent import AgentStatus
from onboard.core.rigidity import (
    UNCERTAINTY_HOLD_S,
    UNCERTAINTY_LAG_S,
    estimate_uncertain,
    lag_uncertainty,
)


def test_rate_is_the_change_per_second_and_its_peak_decays() -> None:
    assert lag_uncertainty(0.0, 0.5, 0.3, 0.1) == pytest.approx(2.0, rel=1e-12)
    held = lag_uncertainty(2.0, 0.3, 0.3, 0.1)  # no change now: the peak decays
    assert held == pytest.approx(2.0 * math.exp(-0.1 / UNCERTAINTY_HOLD_S), rel=1e-12)
    assert lag_uncertainty(0.1, 0.3, 0.35, 0.1) == pytest.approx(0.5, rel=1e-12)  # larger wins


def test_a_steady_estimate_is_trusted_and_a_falling_one_flagged() -> None:
    lam = np.concatenate([np.full(20, 0.45), np.linspace(0.45, 0.06, 5), np.full(40, 0.06)])
    rate, flags = 0.0, []
    for k in range(1, len(lam)):
        rate = lag_uncertainty(rate, lam[k - 1], lam[k], 0.1)
        flags.append(estimate_uncertain(lam[k], UNCERTAINTY_LAG_S * rate))
    assert not any(flags[:20])  # the hover
    assert all(flags[20:24])  # the 0.45 -> 0.06 drop in 0.4 s
    assert not any(flags[-20:])  # 2 s later it is trusted again


def test_the_status_carries_the_uncertainty() -> None:
    assert "rigidity_eigenvalue_uncertainty" in AgentStatus.__struct_fields__
