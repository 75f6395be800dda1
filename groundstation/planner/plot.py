"""Figure of a landmark placement: setpoints, landmarks and 1-sigma uncertainty ellipses.

Two panels: a top view (east right, north up) and a side view (north right, height up), each
with the marginal 1-sigma ellipse of ``Sigma_delta(x_i; z)`` (paper 004 eq. 7) at every
setpoint, drawn to scale. With a field of view, each setpoint's heading is an arrow.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from groundstation.planner.problem import PlacementProblem, PlacementResult
from onboard.rigidity.information import bearing_information


def ellipse_axes(cov_2x2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Semi-axis lengths (1 sigma) and angle (rad from the first axis) of ``(K, 2, 2)`` covs."""
    eigval, eigvec = np.linalg.eigh(cov_2x2)
    angles = np.arctan2(eigvec[..., 1, 1], eigvec[..., 0, 1])
    return np.sqrt(np.maximum(eigval, 0.0)), angles


def plot_placement(problem: PlacementProblem, result: PlacementResult, path: str | Path) -> Path:
    """Write the figure to ``path`` (format from the suffix) with the Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Ellipse

    x = problem.setpoints_ned
    z = result.landmarks_ned
    cov = np.linalg.inv(
        bearing_information(x, z, problem.sigma_m, problem.prior_cov, problem.delta)
    )
    # (horizontal index, vertical index, sign of vertical) per panel: top E/N, side N/-D
    panels = [
        ("top view", 1, 0, 1.0, "east [m]", "north [m]"),
        ("side view", 0, 2, -1.0, "north [m]", "height [m]"),
    ]
    fig, axes = plt.subplots(1, 2, figsize=(12, 6))
    for ax, (title, h, v, sign, xlabel, ylabel) in zip(axes, panels, strict=True):
        block = cov[:, [h, v]][:, :, [h, v]] * np.array([[1.0, sign], [sign, 1.0]])
        semi, angle = ellipse_axes(block)
        for i in range(x.shape[0]):
            ax.add_patch(
                Ellipse(
                    (x[i, h], sign * x[i, v]),
                    2.0 * semi[i, 1],
                    2.0 * semi[i, 0],
                    angle=float(np.degrees(angle[i])),
                    facecolor="tab:blue",
                    alpha=0.25,
                    edgecolor="tab:blue",
                )
            )
        ax.plot(x[:, h], sign * x[:, v], "o", color="tab:blue", ms=4, label="setpoints")
        ax.plot(z[:, h], sign * z[:, v], "*", color="tab:red", ms=14, label="landmarks")
        if result.headings_rad is not None and v == 0:
            length = 0.1 * problem.r_max_m
            ax.quiver(
                x[:, h],
                x[:, v],
                length * np.sin(result.headings_rad),
                length * np.cos(result.headings_rad),
                angles="xy",
                scale_units="xy",
                scale=1.0,
                color="tab:green",
                width=0.004,
                label="camera heading",
            )
        ax.set_title(title)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc="best", fontsize=8)
    fig.suptitle(
        f"{result.method}: worst trace {result.objective:.3g} m^2 "
        f"(1-sigma radius {np.sqrt(result.objective):.3g} m), ellipses 1 sigma to scale"
    )
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
