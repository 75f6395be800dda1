"""Figures like paper 000's figures 3 and 4 from a :class:`sim.runner.Recording`.

matplotlib (Agg backend) is imported lazily, so importing this module costs nothing.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sim.runner import Recording, converged_time, localization_error


def plot_recording(rec: Recording, out_dir: str | Path, name: str) -> list[Path]:
    """Write ``<name>_scale.png`` (fig. 3/4 style panels) and return the written paths.

    Panels: (a) observability index ``lambdabar`` (true, and as agent 0 estimates it) and the
    smallest excitation ``lambda_1``; (b) SfM errors ``chihat - chi`` with the 0.01 1/m band
    and the convergence time; (c) localization error after aligning yaw and translation;
    (d) formation bearing error (formation cases) or the bearing localization error;
    (e) convergence index ``E`` and the gain ``k_E`` (formation-active case).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t = rec.t_s
    lam = rec.excitation_true
    err = rec.chi_error
    conv = converged_time(t, err)
    loc = np.array(
        [localization_error(ph, p) for ph, p in zip(rec.p_hat_ned, rec.p_ned, strict=True)]
    )

    fig, axes = plt.subplots(5, 1, figsize=(8, 13), sharex=True)
    ax = axes[0]
    ax.semilogy(t, np.maximum(rec.lambda_bar_true(), 1e-6), label=r"$\bar\lambda$ (true)")
    ax.semilogy(
        t, np.maximum(rec.lambda_bar_est[:, 0], 1e-6), "--", label=r"$\bar\lambda$ (agent 0)"
    )
    ax.semilogy(t, np.maximum(lam.min(axis=1), 1e-6), ":", label=r"$\lambda_1$")
    ax.set_ylabel("observability")
    ax.legend(loc="best", fontsize=8)
    ax = axes[1]
    for k, (i, j) in enumerate(rec.pairs):
        ax.plot(t, err[:, k], label=f"({i},{j})")
    ax.axhspan(-0.01, 0.01, color="0.9")
    if conv is not None:
        ax.axvline(conv, ls="--", color="k")
        ax.set_title(f"converged at {conv:.2f} s", fontsize=9)
    ax.set_ylabel(r"$\tilde\chi$ [1/m]")
    ax.legend(loc="best", fontsize=8, ncol=2)
    ax = axes[2]
    ax.semilogy(t, np.maximum(loc, 1e-6))
    ax.set_ylabel("localization error [m]")
    ax = axes[3]
    beta = rec.beta_body()
    if rec.desired_beta_body is not None:
        c = np.clip(np.sum(beta * rec.desired_beta_body, axis=-1), -1, 1)
        ax.plot(t, np.degrees(np.arccos(c)).max(axis=1))
        ax.set_ylabel("formation bearing\nerror max [deg]")
    else:
        c = np.clip(np.sum(beta * rec.beta_hat_body(), axis=-1), -1, 1)
        ax.semilogy(t, np.maximum(np.degrees(np.arccos(c)).max(axis=1), 1e-6))
        ax.set_ylabel("bearing localization\nerror max [deg]")
    ax = axes[4]
    ax.semilogy(t, np.maximum(rec.e_index_est[:, 0], 1e-9), label="E (agent 0)")
    ax.set_ylabel("E")
    ax2 = ax.twinx()
    ax2.plot(t, rec.k_e[:, 0], "r", label="k_E")
    ax2.plot(t, rec.w_l[:, 0], "g", label="w_l [rad/s]")
    ax2.legend(loc="upper right", fontsize=8)
    ax.set_xlabel("t [s]")
    fig.suptitle(name)
    fig.tight_layout()
    path = out / f"{name}_scale.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]
