"""The demo's evaluator scores a status against the truth at the status's own stamp."""

from __future__ import annotations

import numpy as np

from groundstation.demo import truth_at
from messages.sim import Truth


def _truth(t_s: float, x_m: float) -> Truth:
    return Truth(
        sender=0, seq=int(t_s * 100), stamp_s=t_s, p_ned=(x_m, 2.0, -5.0), v_ned=(2.0, 0.0, 0.0),
        yaw_rad=0.0, yaw_rate_rad_s=0.0,
    )  # fmt: skip


def test_the_truth_at_a_stamp_is_interpolated_between_its_neighbours() -> None:
    hist = [_truth(10.0 + 0.02 * k, 2.0 * 0.02 * k) for k in range(51)]  # 2 m/s along x
    p = truth_at(hist, 10.5)
    assert p is not None
    np.testing.assert_allclose(p, [1.0, 2.0, -5.0], atol=1e-12)
    # what the newest truth would have said: 0.5 s later, 1 m further (the 1-2 % it cost)
    assert abs(hist[-1].p_ned[0] - p[0]) > 0.99


def test_a_stamp_outside_the_history_has_no_truth() -> None:
    hist = [_truth(10.0 + 0.02 * k, 0.0) for k in range(10)]
    assert truth_at(hist, 9.99) is None  # older than the history
    assert truth_at(hist, 10.5) is None  # newer than the newest: another timeline
    assert truth_at([], 10.0) is None
