"""benchmarks/localization_compare.py: the shared work is seeded, the metrics measure what
they say, and every method runs on the same work (issue 26)."""

from __future__ import annotations

import numpy as np

from benchmarks.localization_compare import (
    METHODS,
    evaluate,
    make_work,
    rigid_error_m,
    scale_error,
)
from onboard.geometry import so3_exp


def test_the_work_is_seeded_and_its_bearings_are_unit_body_bearings():
    a, b = make_work(3, 4, 1.0, 0.1, 2.0), make_work(3, 4, 1.0, 0.1, 2.0)
    assert np.array_equal(a.beta, b.beta) and np.array_equal(a.delivered, b.delivered)
    assert not np.array_equal(a.beta, make_work(3, 5, 1.0, 0.1, 2.0).beta)
    off = ~np.eye(3, dtype=bool)
    assert np.allclose(np.linalg.norm(a.beta[:, off], axis=-1), 1.0)
    exact = make_work(3, 4, 0.0, 0.0, 2.0)
    r = exact.p_ned[0, 1] - exact.p_ned[0, 0]
    c, s = np.cos(exact.yaw_rad[0, 0]), np.sin(exact.yaw_rad[0, 0])
    body = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]) @ r  # R_z(yaw)^T r
    assert np.allclose(exact.beta[0, 0, 1], body / np.linalg.norm(body))
    assert exact.delivered.all() and 0.8 < a.delivered.mean() < 1.0
    team = make_work(6, 5, 0.0, 0.0, 0.1).p_ned[0]  # this seed's first centres left no room
    gaps = np.linalg.norm(team[:, None] - team[None], axis=-1)[~np.eye(6, dtype=bool)]
    assert gaps.min() > 4.5 - 2 * np.sqrt(2 + 0.09)  # centres 4.5 m apart, amplitudes <= 1 m


def test_rigid_error_ignores_a_rigid_motion_and_scale_error_sees_the_size():
    rng = np.random.default_rng(0)
    p = rng.normal(size=(5, 3))
    moved = p @ so3_exp(np.array([0.3, -0.2, 1.0])).T + [1.0, 2.0, 3.0]
    assert rigid_error_m(moved, p) < 1e-12 and abs(scale_error(moved, p)) < 1e-12
    big = 1.1 * p
    assert abs(scale_error(big, p) - 0.1) < 1e-12 and rigid_error_m(big, p) > 0.05


def test_every_method_runs_on_the_same_work_and_the_ekf_recovers_the_scale():
    short = make_work(3, 0, 0.0, 0.1, 2.0)
    for m in METHODS.values():
        row = evaluate(short, m)
        assert np.isfinite(row["position_error_m"]) and row["bytes_per_s"] > 0.0
    ekf = evaluate(make_work(3, 0, 0.0, 0.0, 10.0), METHODS["paper 001 (centralized EKF)"])
    assert ekf["scale_error"] < 0.02 and ekf["position_error_m"] < 0.1  # prior: 30% off
