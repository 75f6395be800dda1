"""Figures of a demo run (``demo_series.npz``): errors over time and the trajectories.

* ``demo_errors.png``: one quantity per axis: the SfM distance errors with the 2% metric-scale
  threshold, the formation's bearing error, the bearing rigidity eigenvalue (R^3 x S^1) of the
  true formation, and the weighted angle rigidity eigenvalue (paper 003; truth and each
  agent's estimate) with the maintenance's safe level ``lambda_safe``. The time before the
  mission starts (connect, arm, take-off) is shaded and named.
* ``demo_trajectories.png``: the true paths, and the planned formation drawn after the best
  similarity that maps it onto the final positions (Umeyama 1991, ``similarity.similarity_2d``):
  bearings fix a formation only up to translation, scale and heading, so that fit, and the
  shape error left after it, is what says whether the team reached the plan.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from groundstation.demo_verdict import SCALE_CRITERION
from groundstation.gcs.similarity import similarity_2d

PRE_MISSION = "before mission start: connect, arm, take off"


def planned_on_final(p_desired_ned: np.ndarray, p_final_ned: np.ndarray) -> dict[str, Any]:
    """The planned horizontal positions mapped onto the final ones by the best similarity:
    ``xy`` (N, 2, north-east), ``scale``, ``rotation_deg`` and ``shape_rms_m`` (RMS distance
    left between the fitted plan and the final positions)."""
    src = np.asarray(p_desired_ned, dtype=float)[:, :2]
    dst = np.asarray(p_final_ned, dtype=float)[:, :2]
    s, r, t = similarity_2d(src, dst)
    xy = (s * (r @ src.T)).T + t
    rms = float(np.sqrt(np.mean(np.sum((xy - dst) ** 2, axis=1))))
    return {
        "xy": xy,
        "scale": s,
        "rotation_deg": math.degrees(math.atan2(r[1, 0], r[0, 0])),
        "shape_rms_m": rms,
    }


def plot_demo(out: Path) -> list[Path]:
    """Write PNGs next to the series file; returns their paths (none without data)."""
    data_path = out / "demo_series.npz"
    if not data_path.exists():
        return []
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = np.load(data_path)
    return [_errors(plt, d, out / "demo_errors.png"), _trajectories(plt, d, out)]


def _errors(plt: Any, d: Any, path: Path) -> Path:
    t = d["t_s"]
    fig, axes = plt.subplots(4, 1, figsize=(8, 11), sharex=True)
    for m, (i, j) in enumerate(d["pairs"]):
        axes[0].semilogy(t, 100 * d["scale_error"][:, m], label=f"d_{i}{j}")
    axes[0].axhline(100 * SCALE_CRITERION, color="k", ls="--", lw=0.8,
                    label=f"{100 * SCALE_CRITERION:g}%: metric scale")  # fmt: skip
    axes[0].set_ylabel("SfM distance error (%)")
    axes[0].legend(loc="upper right", fontsize=8, ncol=2)
    axes[1].plot(t, d["bearing_error_deg"], "k")
    axes[1].set_ylabel("formation bearing\nerror (deg)")
    axes[2].semilogy(t, np.maximum(d["rigidity_eigenvalue"], 1e-12), "k")
    axes[2].set_ylabel("bearing rigidity\neigenvalue (R^3 x S^1)")
    ax = axes[3]
    ax.semilogy(t, d["angle_eigenvalue"], "b", lw=2, label="truth")
    if "angle_eigenvalue_hat" in d and np.isfinite(d["angle_eigenvalue_hat"]).any():
        ax.semilogy(t, d["angle_eigenvalue_hat"], "c", lw=0.7, alpha=0.7)
        ax.plot([], [], "c", label="each agent's estimate")
        if "lambda_safe" in d:
            ax.axhline(float(d["lambda_safe"]), color="r", ls="--", lw=0.8,
                       label=f"lambda_safe = {float(d['lambda_safe']):.3g} (maintenance acts below)")  # fmt: skip
    ax.set_ylabel("weighted angle rigidity\neigenvalue (paper 003)")
    ax.legend(loc="lower right", fontsize=8)
    ax.set_xlabel("simulation time (s)")
    flying = d["flying"].astype(bool)
    if flying.any():  # the mission starts when every vehicle flies it (the summary's start)
        start = t[np.argmax(flying)]
        for a in axes:
            a.axvspan(t[0], start, color="0.85", alpha=0.6, lw=0)
            a.axvline(start, color="0.5", lw=0.8, ls=":")
        axes[0].text(start, 0.98, " mission start", transform=axes[0].get_xaxis_transform(),
                     va="top", fontsize=8, color="0.3")  # fmt: skip
        axes[0].text(t[0], 0.02, f" {PRE_MISSION}", transform=axes[0].get_xaxis_transform(),
                     va="bottom", fontsize=7, color="0.3")  # fmt: skip
    for a in axes:
        a.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _trajectories(plt: Any, d: Any, out: Path) -> Path:
    fig, ax = plt.subplots(figsize=(7, 7))
    p = d["p_ned"]
    fit = planned_on_final(d["p_desired_ned"], p[-1])
    for k in range(p.shape[1]):  # one colour per vehicle: its path, where it ended, its place
        color = f"C{k % 10}"
        ax.plot(p[:, k, 1], p[:, k, 0], lw=1, color=color, label=f"vehicle {k}")
        ax.plot(p[-1, k, 1], p[-1, k, 0], "o", color=color)
        ax.plot(fit["xy"][k, 1], fit["xy"][k, 0], "x", color="k", ms=9, mew=1.5)
    ax.plot([], [], "ko", mfc="none", label="end")
    ax.plot([], [], "kx", label="planned formation, fitted to the end")
    ax.legend(fontsize="small", loc="best")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_aspect("equal")
    ax.set_title(
        "trajectories; the plan after the best similarity onto the final positions\n"
        f"(scale {fit['scale']:.2f}, rotation {fit['rotation_deg']:.0f} deg: bearings fix "
        f"neither): shape error {fit['shape_rms_m']:.2f} m RMS",
        fontsize=9,
    )
    ax.grid(True, alpha=0.3)
    path = out / "demo_trajectories.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
