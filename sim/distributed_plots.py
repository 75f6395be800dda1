"""Figures like paper 002's fig. 11 (and a localization figure) from the paper-002 scenarios.

Formation panels (fig. 11): top, the agents' paths (gray) with the desired formation (blue dashed
lines and squares, placed at the final formation's centroid and, without a range, its scale),
the initial configuration (red crosses) and the final formation (red lines and circles); middle,
the angle between measured and desired bearings of every edge (log scale); bottom, the absolute
difference between actual and desired distances of every edge (most are not used by the law).
matplotlib (Agg backend) is imported lazily.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from onboard.distributed.metrics import align_similarity
from sim.distributed_scenarios import FormationResult, LocalizationOutcome


def _edges_once(e: np.ndarray) -> list[tuple[int, int]]:
    return sorted({(min(i, j), max(i, j)) for i, j in e.tolist()})


def plot_formation(res: FormationResult, out_dir: str | Path) -> list[Path]:
    """Write ``<name>.png`` (three panels) and return its path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    run, prob = res.run, res.problem
    p_fin = run.p[-1]
    if prob.ranged.any():
        p_des = prob.p_des - prob.p_des.mean(axis=0) + p_fin.mean(axis=0)
    else:
        p_des = align_similarity(prob.p_des, p_fin, rotate=False)
    three_d = prob.dim == 3
    fig = plt.figure(figsize=(7, 11))
    ax = fig.add_subplot(3, 1, 1, projection="3d" if three_d else None)
    cols = slice(0, 3) if three_d else slice(0, 2)
    for i in range(run.p.shape[1]):
        ax.plot(*run.p[:, i, cols].T, color="0.6", lw=0.8)
    for i, j in _edges_once(prob.edges):
        ax.plot(*np.stack([p_des[i], p_des[j]])[:, cols].T, "b--", lw=1.0)
        ax.plot(*np.stack([p_fin[i], p_fin[j]])[:, cols].T, "r-", lw=1.0)
    ax.plot(*p_des[:, cols].T, "bs", ms=6, mfc="none", ls="none", label="desired")
    ax.plot(*run.p[0][:, cols].T, "rx", ls="none", label="initial")
    ax.plot(*p_fin[:, cols].T, "ro", ms=5, mfc="none", ls="none", label="final")
    ax.set_title(f"{res.name}, seed {res.seed} (paper 002 fig. 11)")
    ax.legend(loc="best", fontsize=8)
    if not three_d:
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    ax2 = fig.add_subplot(3, 1, 2)
    ax2.semilogy(run.t_s, np.maximum(run.bearing_error_deg, 1e-6), lw=0.8)
    ax2.set_ylabel("bearing error (deg)")
    ax3 = fig.add_subplot(3, 1, 3, sharex=ax2)
    ax3.plot(run.t_s, run.distance_error_m, lw=0.8)
    ax3.set_ylabel("|d - d*| (m)")
    ax3.set_xlabel("t (s)")
    fig.tight_layout()
    path = out / f"{res.name}.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]


def plot_localization(res: LocalizationOutcome, out_dir: str | Path) -> list[Path]:
    """Write ``<name>.png``: aligned estimates against the truth and the cost per round."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    est = align_similarity(res.p_est, res.p_true, rotate=res.rotation_cost is not None)
    fig = plt.figure(figsize=(7, 9))
    ax = fig.add_subplot(2, 1, 1, projection="3d")
    for i, j in _edges_once(res.edges):
        ax.plot(*np.stack([res.p_true[i], res.p_true[j]]).T, "b--", lw=0.6)
    ax.plot(*res.p_true.T, "bs", mfc="none", ls="none", label="true")
    ax.plot(*est.T, "ro", ms=4, ls="none", label="estimate (aligned)")
    ax.legend(fontsize=8)
    ax.set_title(f"{res.name}, seed {res.seed}")
    ax2 = fig.add_subplot(2, 1, 2)
    if res.rotation_cost is not None:
        ax2.semilogy(np.maximum(res.rotation_cost, 1e-30), label="rotations (eq. 13)")
    ax2.semilogy(np.maximum(res.cost, 1e-30), label="translations (eq. 16)")
    ax2.set_xlabel("round")
    ax2.set_ylabel("cost phi")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    path = out / f"{res.name}.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]
