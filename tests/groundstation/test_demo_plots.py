"""The demo's figures from a synthetic series file (what ``Evaluator`` saves)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from groundstation.demo_plots import planned_on_final, plot_demo


def _series(out: Path, flying: bool) -> None:
    t = np.linspace(0.0, 10.0, 101)
    n = 3
    p = np.stack([np.stack([np.cos(t + k), np.sin(t + k), -5 + 0 * t], -1) for k in range(n)], 1)
    np.savez(
        out / "demo_series.npz",
        t_s=t,
        p_ned=p,
        scale_error=np.abs(np.exp(-t))[:, None] * np.ones((1, 1)),
        bearing_error_deg=10 * np.exp(-t),
        rigidity_eigenvalue=np.full_like(t, 1e-3),
        angle_eigenvalue=np.full_like(t, 0.5),
        angle_eigenvalue_hat=np.full((len(t), n), 0.5),
        p_hat_ned=p,
        yaw_hat_rad=np.zeros((len(t), n)),
        flying=(t > 2.0) if flying else np.zeros_like(t, dtype=bool),
        pairs=np.array([[0, 1]]),
        p_desired_ned=p[-1],
        lambda_safe=0.2,
    )


@pytest.mark.parametrize("flying", [True, False])
def test_both_figures_are_written(tmp_path: Path, flying: bool) -> None:
    _series(tmp_path, flying)
    paths = plot_demo(tmp_path)
    assert [p.name for p in paths] == ["demo_errors.png", "demo_trajectories.png"]
    assert all(p.stat().st_size > 10_000 for p in paths)


def test_no_series_no_figures(tmp_path: Path) -> None:
    assert plot_demo(tmp_path) == []


def test_the_plan_is_drawn_after_the_best_similarity_onto_the_final_formation() -> None:
    """A team that ends in the plan's shape, 1.56x larger and turned -120 degrees (what bearings
    leave free), is drawn exactly on the plan: shape error 0."""
    plan = np.array([[0.0, 0.0, -5.0], [10.0, 0.0, -5.0], [0.0, 6.0, -6.0], [4.0, 4.0, -5.0]])
    a = np.radians(-120.0)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    final = plan.copy()
    final[:, :2] = 1.56 * plan[:, :2] @ rot.T + np.array([3.0, -7.0])
    fit = planned_on_final(plan, final)
    assert np.allclose(fit["xy"], final[:, :2]) and fit["shape_rms_m"] < 1e-9
    assert np.isclose(fit["scale"], 1.56) and np.isclose(fit["rotation_deg"], -120.0)
    final[0, 0] += 1.0  # one vehicle 1 m off: the fit says so
    assert 0.3 < planned_on_final(plan, final)["shape_rms_m"] < 1.0
