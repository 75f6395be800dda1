"""The demo's figures from a synthetic series file (what ``Evaluator`` saves)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from groundstation.demo_plots import plot_demo


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
    )


@pytest.mark.parametrize("flying", [True, False])
def test_both_figures_are_written(tmp_path: Path, flying: bool) -> None:
    _series(tmp_path, flying)
    paths = plot_demo(tmp_path)
    assert [p.name for p in paths] == ["demo_errors.png", "demo_trajectories.png"]
    assert all(p.stat().st_size > 10_000 for p in paths)


def test_no_series_no_figures(tmp_path: Path) -> None:
    assert plot_demo(tmp_path) == []
