"""Figures of a demo run (``demo_series.npz``): scale error, formation error, trajectories."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def plot_demo(out: Path) -> list[Path]:
    """Write PNGs next to the series file; returns their paths (none without data)."""
    data_path = out / "demo_series.npz"
    if not data_path.exists():
        return []
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = np.load(data_path)
    t = d["t_s"]
    paths = []
    fig, axes = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
    for m, (i, j) in enumerate(d["pairs"]):
        axes[0].semilogy(t, 100 * d["scale_error"][:, m], label=f"d_{i}{j}")
    axes[0].axhline(2.0, color="k", ls="--", lw=0.8)
    axes[0].set_ylabel("distance error (%)")
    axes[0].legend(loc="upper right", fontsize=8)
    axes[1].plot(t, d["bearing_error_deg"])
    axes[1].set_ylabel("formation bearing error (deg)")
    axes[2].semilogy(
        t, np.maximum(d["rigidity_eigenvalue"], 1e-12), "k", label="bearing (R^3 x S^1, truth)"
    )
    if "angle_eigenvalue" in d and np.isfinite(d["angle_eigenvalue_hat"]).any():
        axes[2].semilogy(t, d["angle_eigenvalue"], "b", lw=2, label="weighted angle (truth)")
        axes[2].semilogy(t, d["angle_eigenvalue_hat"], "c", lw=0.7, alpha=0.7)
        axes[2].plot([], [], "c", label="weighted angle (each agent's estimate)")
    axes[2].set_ylabel("rigidity eigenvalue")
    axes[2].legend(loc="lower right", fontsize=8)
    axes[2].set_xlabel("simulation time (s)")
    flying = d["flying"].astype(bool)
    if flying.any():  # the mission starts when every vehicle flies it (the summary's start)
        for ax in axes:
            ax.axvline(t[np.argmax(flying)], color="0.5", lw=0.8, ls=":")
        axes[0].text(t[np.argmax(flying)], 0.98, " mission start", transform=axes[0].get_xaxis_transform(),
                     va="top", fontsize=8, color="0.4")  # fmt: skip
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    paths.append(out / "demo_errors.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 6))
    p = d["p_ned"]
    for k in range(p.shape[1]):  # one colour per vehicle: its path and where it ended
        color = f"C{k % 10}"
        ax.plot(p[:, k, 1], p[:, k, 0], lw=1, color=color, label=f"vehicle {k}")
        ax.plot(p[-1, k, 1], p[-1, k, 0], "o", color=color)
        ax.plot(d["p_desired_ned"][k, 1], d["p_desired_ned"][k, 0], "kx")
    ax.legend(fontsize="small", loc="best")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_aspect("equal")
    ax.set_title("trajectories (o: end, x: planned formation)")
    ax.grid(True, alpha=0.3)
    paths.append(out / "demo_trajectories.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    return paths
