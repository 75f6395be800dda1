"""Figures like paper 001's figures 1-3 from a :class:`sim.se3_runner.Se3Recording`.

matplotlib (Agg backend) is imported lazily, so importing this module costs nothing.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from sim.se3_runner import Se3Recording

AXES = ("x", "y", "z")


def plot_se3(rec: Se3Recording, out_dir: str | Path, name: str = "ekf-se3") -> list[Path]:
    """Write ``<name>_fig2.png`` (a, b: position variance per axis of agents 2 and 3, log scale;
    c: true and estimated distance d23), ``<name>_fig3.png`` (orientation error of paper 001
    eq. 44 per agent) and ``<name>_fig1.png`` (the 8 smallest singular values of the rigidity
    matrix, of the motion DBOM and of the paper's field DBOM along the trajectory, each normalized by its largest)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t = rec.t_s
    paths = []
    fig, axes = plt.subplots(3, 1, figsize=(8, 10), sharex=True)
    for a, ax in enumerate(axes[:2]):
        for k, label in enumerate(AXES):
            ax.semilogy(t, rec.var_p_m2[:, a, k], label=f"{label}")
        ax.set_ylabel(f"agent {a + 2} position variance (m$^2$)")
        ax.set_title(f"({'ab'[a]}) agent {a + 2}", loc="left", fontsize=9)
        ax.legend(loc="upper right", fontsize=8)
    ax = axes[2]
    ax.plot(t, rec.d23_true_m, "k", lw=2, label="$d_{23}$ true")
    ax.plot(t, rec.d23_est_m, "tab:red", label=r"$\hat d_{23}$ EKF")
    ax.set_ylabel("distance (m)")
    ax.set_xlabel("time (s)")
    ax.set_title("(c) scale: distance between agents 2 and 3", loc="left", fontsize=9)
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    paths.append(out / f"{name}_fig2.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(8, 4))
    for a in range(rec.rotation_error.shape[1]):
        ax.plot(t, rec.rotation_error[:, a], label=f"agent {a + 2}")
    ax.set_ylabel(r"$\frac{1}{2}\mathrm{tr}(I - \hat R_i^T R_i)$")
    ax.set_xlabel("time (s)")
    ax.set_yscale("symlog", linthresh=1e-4)
    ax.legend(fontsize=8)
    ax.set_title("orientation error (paper 001 eq. 44)", loc="left", fontsize=9)
    fig.tight_layout()
    paths.append(out / f"{name}_fig3.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    if len(rec.sv_t_s):
        fig, axes = plt.subplots(1, 3, figsize=(14, 4), sharey=True)
        for ax, sv, title in (
            (axes[0], rec.sv_rigidity, "rigidity matrix $R_A$"),
            (axes[1], rec.sv_dbom, "motion DBOM (flown inputs)"),
            (axes[2], rec.sv_fields, "paper's DBOM (every input field)"),
        ):
            ax.semilogy(rec.sv_t_s, sv)
            ax.set_title(f"8 smallest singular values:\n{title}", fontsize=9)
            ax.set_xlabel("time (s)")
        axes[0].set_ylabel("singular value / largest")
        fig.tight_layout()
        paths.append(out / f"{name}_fig1.png")
        fig.savefig(paths[-1], dpi=110)
        plt.close(fig)
    return paths
