"""Figures like paper 003's figures 2-5 from a :class:`sim.rigidity_scenarios.RigidityRecording`.

matplotlib (Agg backend) is imported lazily, so importing this module costs nothing.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from sim.rigidity_scenarios import RigidityRecording


def plot_rigidity(rr: RigidityRecording, out_dir: str | Path) -> list[Path]:
    """Write ``<name>_metrics.png`` (fig. 3 / 5 panels) and ``<name>_paths.png`` (fig. 2 / 4).

    Metrics panels: (a) weighted rigidity eigenvalue of the true configuration, each agent's
    distributed estimate, the unweighted eigenvalue of the true sensing graph (scaled by the
    mean squared edge length) and the barrier's minimum level; (b) angle between each tracking
    robot's camera axis and its target, against half the field of view; (c) localization error
    after the best rotation and translation. Paths: 3-D trajectories of robots and targets.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t = rr.rec.t_s
    fig, axes = plt.subplots(3, 1, figsize=(8, 10), sharex=True)
    ax = axes[0]
    ax.plot(t, rr.lambda_true, "k", lw=2, label=r"$\lambda_w$ (true)")
    ax.plot(t, rr.lambda_hat, lw=0.8, alpha=0.7)
    ax.plot([], [], lw=0.8, label=r"$\hat\lambda_w$ (each agent)")
    ax.plot(
        t, rr.lambda_unweighted, "--", color="tab:gray", label=r"$\lambda$ (unweighted, scaled)"
    )
    ax.axhline(rr.lambda_min, color="r", ls=":", label=r"$\lambda_{min}$")
    ax.axvline(rr.warmup_s, color="0.6", ls="-.", lw=0.8)
    ax.set_ylabel("rigidity eigenvalue")
    ax.set_yscale("symlog", linthresh=1e-3)
    ax.set_ylim(bottom=0.0)
    ax.legend(loc="best", fontsize=8)
    ax = axes[1]
    ang = rr.target_angle_deg
    for i, m in enumerate(rr.track_target):
        if m >= 0:
            ax.plot(t, ang[:, i, m], label=f"robot {i} -> target {m}")
    ax.axhline(rr.model.fov_deg / 2.0, color="r", ls=":", label="fov / 2")
    ax.set_ylabel("camera-target angle [deg]")
    ax.legend(loc="best", fontsize=8, ncol=2)
    ax = axes[2]
    ax.semilogy(t, np.maximum(rr.localization_error, 1e-6))
    ax.set_ylabel("localization error [m]")
    ax.set_xlabel("t [s]")
    fig.suptitle(f"{rr.name} (seed {rr.seed})")
    fig.tight_layout()
    metrics = out / f"{rr.name}_metrics.png"
    fig.savefig(metrics, dpi=110)
    plt.close(fig)

    fig = plt.figure(figsize=(7, 7))
    ax3 = fig.add_subplot(projection="3d")
    p = rr.rec.p_ned
    for i in range(p.shape[1]):
        ax3.plot(p[:, i, 0], p[:, i, 1], -p[:, i, 2], lw=1.2, label=f"robot {i}")
        ax3.scatter(p[0, i, 0], p[0, i, 1], -p[0, i, 2], marker="o", s=12)
        c = np.array([np.cos(rr.rec.yaw_rad[-1, i]), np.sin(rr.rec.yaw_rad[-1, i]), 0.0])
        ax3.quiver(p[-1, i, 0], p[-1, i, 1], -p[-1, i, 2], c[0], c[1], c[2], length=1.5, color="k")
    tg = rr.targets_ned
    for m in range(tg.shape[1]):
        ax3.plot(tg[:, m, 0], tg[:, m, 1], -tg[:, m, 2], "k:", lw=1.0)
        ax3.scatter(tg[-1, m, 0], tg[-1, m, 1], -tg[-1, m, 2], marker="*", s=60, color="k")
    ax3.set_xlabel("north [m]")
    ax3.set_ylabel("east [m]")
    ax3.set_zlabel("up [m]")
    ax3.legend(loc="upper left", fontsize=7)
    fig.tight_layout()
    paths = out / f"{rr.name}_paths.png"
    fig.savefig(paths, dpi=110)
    plt.close(fig)
    return [metrics, paths]
