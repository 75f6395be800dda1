"""PNG figures of a recording (``gcs plot IN.mcap --out DIR``); matplotlib (Agg) is imported lazily.

Five files, each always written (a panel without data says so):

* ``scale_error.png`` — ``|chihat_ij - 1/d_ij|`` per agent and neighbour, log scale, with the
  0.01 1/m threshold of paper 000 (needs truth; without it the estimated distances ``1/chihat``);
* ``sfm_convergence.png`` — the convergence index ``E`` (eq. 10) and observability index
  ``lambdabar`` (eq. 11) each agent reports;
* ``rigidity.png`` — the rigidity eigenvalue each agent reports;
* ``bearing_errors.png`` — angle between measured and estimate-predicted bearings per camera
  (and, with truth, between measured and true ones: the camera noise);
* ``trajectories.png`` — horizontal tracks: truth, and the estimates mapped onto it by the
  best similarity (:func:`~groundstation.gcs.similarity.similarity_2d`) when truth is recorded.

``gcs estimate --replay IN.mcap --plot DIR`` writes paper 001's EKF on the same recording
(:func:`plot_ekf_replay`): ``ekf_distances.png`` (every pair's estimated distance, and the true
one dashed), ``ekf_scale_error.png`` (each pair's relative distance error with the 2% line;
needs truth) and ``ekf_sigma.png`` (each vehicle's 1-sigma position radius).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from groundstation.gcs.analysis import (
    Series,
    bearing_errors_rad,
    inverse_distance_error,
    rows_at,
)
from groundstation.gcs.ekf_replay import ReplayResult
from groundstation.gcs.similarity import similarity_2d

SCALE_THRESHOLD_INV_M = 0.01
EKF_SCALE_THRESHOLD = 0.02
"""Relative distance error the EKF's scale is judged by (``time_to_scale_s`` of ``ekf-se3``)."""


def _figure(title: str) -> tuple[Any, Any]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5), constrained_layout=True)
    ax.set_title(title)
    ax.set_xlabel("time since recording start (s)")
    ax.grid(True, alpha=0.3)
    return fig, ax


def _save(fig: Any, ax: Any, path: Path, empty: bool, what: str) -> Path:
    import matplotlib.pyplot as plt

    if empty:
        ax.text(0.5, 0.5, f"no {what} in this recording", ha="center", va="center",
                transform=ax.transAxes)  # fmt: skip
    elif ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize="small", ncol=2)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_scale_error(s: Series, out: Path) -> Path:
    with_truth = bool(s.truth)
    fig, ax = _figure("SfM scale error" if with_truth else "estimated distances 1/chihat")
    drawn = False
    for i, a in sorted(s.agents.items()):
        for j in np.unique(a.chi_j):
            m = a.chi_j == j
            t, chi = a.chi_t_s[m], a.chi_inv_m[m]
            if with_truth:
                if i not in s.truth or j not in s.truth:
                    continue
                ok_i, p_i = rows_at(t, s.truth[i].t_s, s.truth[i].p_ned)
                ok_j, p_j = rows_at(t, s.truth[j].t_s, s.truth[j].p_ned)
                ok = ok_i & ok_j
                err = inverse_distance_error(t[ok], chi[ok], p_i[ok], p_j[ok])
                ax.semilogy(t[ok], np.maximum(err, 1e-6), label=f"{i}->{j}")
            else:
                ok = chi > 0
                ax.plot(t[ok], 1.0 / chi[ok], label=f"{i}->{j}")
            drawn = True
    if with_truth:
        ax.axhline(SCALE_THRESHOLD_INV_M, color="k", ls="--", lw=0.8, label="0.01 1/m")
        ax.set_ylabel("|chihat - 1/d| (1/m)")
    else:
        ax.set_ylabel("1/chihat (m)")
    return _save(fig, ax, out / "scale_error.png", not drawn, "inverse-distance estimates")


def plot_sfm_convergence(s: Series, out: Path) -> Path:
    fig, ax = _figure("SfM convergence index E (solid) and observability lambdabar (dotted)")
    for i, a in sorted(s.agents.items()):
        (line,) = ax.semilogy(a.t_s, np.maximum(a.e_index, 1e-9), label=f"E agent {i}")
        ax.semilogy(a.t_s, np.maximum(a.lambda_bar, 1e-9), ls=":", color=line.get_color())
    ax.set_ylabel("E, lambdabar")
    return _save(fig, ax, out / "sfm_convergence.png", not s.agents, "agent statuses")


def plot_rigidity(s: Series, out: Path) -> Path:
    fig, ax = _figure("rigidity eigenvalue")
    drawn = False
    for i, a in sorted(s.agents.items()):
        ok = np.isfinite(a.rigidity)
        if ok.any():
            ax.plot(a.t_s[ok], a.rigidity[ok], label=f"agent {i}")
            drawn = True
    ax.set_ylabel("eigenvalue")
    return _save(fig, ax, out / "rigidity.png", not drawn, "rigidity eigenvalues")


def plot_bearing_errors(s: Series, out: Path) -> Path:
    fig, ax = _figure("bearing errors: measured vs estimated (o), vs true (x)")
    drawn = False
    for i, cam in sorted(s.bearings.items()):
        color = None
        if i in s.agents:
            err = _bearing_error(cam, s.agents, i, "estimate")
            if err is not None:
                pts = ax.plot(
                    err[0], np.degrees(err[1]), "o", ms=2, label=f"camera {i} vs estimate"
                )
                color = pts[0].get_color()
                drawn = True
        if i in s.truth:
            err = _bearing_error(cam, s.truth, i, "truth")
            if err is not None:
                ax.plot(
                    err[0], np.degrees(err[1]), "x", ms=2, color=color, label=f"camera {i} vs truth"
                )
                drawn = True
    ax.set_ylabel("angle (deg)")
    return _save(fig, ax, out / "bearing_errors.png", not drawn, "camera bearings")


def _bearing_error(
    cam: Any, source: dict, i: int, kind: str
) -> tuple[np.ndarray, np.ndarray] | None:
    """Times and errors of the camera rows whose two vehicles are in ``source``."""

    def pose(k: int, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        s = source[k]
        p = s.p_hat_ned if kind == "estimate" else s.p_ned
        yaw = s.yaw_hat_rad if kind == "estimate" else s.yaw_rad
        ok, pk = rows_at(t, s.t_s, p)
        _, yk = rows_at(t, s.t_s, yaw)
        return ok, pk, yk

    ok_i, p_i, yaw_i = pose(i, cam.t_s)
    p_j = np.zeros_like(cam.beta_body)
    ok_j = np.zeros(len(cam.t_s), dtype=bool)
    for j in np.unique(cam.target):
        if j not in source:
            continue
        m = cam.target == j
        ok, pj, _ = pose(int(j), cam.t_s[m])
        ok_j[m], p_j[m] = ok, pj
    ok = ok_i & ok_j & (np.linalg.norm(p_j - p_i, axis=1) > 0)
    if not ok.any():
        return None
    sub = type(cam)(cam.t_s[ok], cam.target[ok], cam.beta_body[ok])
    return cam.t_s[ok], bearing_errors_rad(sub, p_i[ok], yaw_i[ok], p_j[ok])


def plot_trajectories(s: Series, out: Path) -> Path:
    import matplotlib.pyplot as plt

    fig, ax = _figure("horizontal trajectories (truth solid, estimates dashed)")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_aspect("equal", adjustable="datalim")
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    align = _estimate_alignment(s)
    drawn = False
    for k, i in enumerate(s.vehicles):
        c = colors[k % len(colors)]
        if i in s.truth:
            p = s.truth[i].p_ned
            ax.plot(p[:, 1], p[:, 0], color=c, label=f"{i} truth")
            drawn = True
        if i in s.agents:
            p = s.agents[i].p_hat_ned[:, :2]
            if align is not None:
                scale, r, t = align
                p = scale * p @ r.T + t
            label = f"{i} estimate{' (aligned)' if align is not None else ''}"
            ax.plot(p[:, 1], p[:, 0], ls="--", color=c, label=label)
            ax.plot(p[-1, 1], p[-1, 0], "o", mfc="none", color=c)  # where the estimate ends
            drawn = True
    return _save(fig, ax, out / "trajectories.png", not drawn, "positions")


def _estimate_alignment(s: Series) -> tuple[float, np.ndarray, np.ndarray] | None:
    """Similarity from the estimated frame to the truth, fitted on every status sample."""
    src, dst = [], []
    for i, a in s.agents.items():
        if i not in s.truth:
            continue
        ok, p = rows_at(a.t_s, s.truth[i].t_s, s.truth[i].p_ned)
        src.append(a.p_hat_ned[ok, :2])
        dst.append(p[ok, :2])
    if not src:
        return None
    src_a, dst_a = np.concatenate(src), np.concatenate(dst)
    if len(src_a) < 2 or np.ptp(src_a, axis=0).max() <= 0:
        return None
    return similarity_2d(src_a, dst_a)


def plot_all(s: Series, out: Path) -> list[Path]:
    """Write every figure into ``out``; returns the paths."""
    out = Path(out)
    return [
        plot_scale_error(s, out),
        plot_sfm_convergence(s, out),
        plot_rigidity(s, out),
        plot_bearing_errors(s, out),
        plot_trajectories(s, out),
    ]


def plot_ekf_replay(r: ReplayResult, out: Path) -> list[Path]:
    """Paper 001's EKF over a recording (module doc); returns the three paths."""
    out = Path(out)
    h = r.history
    t = np.array([x.t_s for x in h])
    t0 = t[0] if len(t) else 0.0
    pairs = r.pairs()
    d_est = np.array(
        [[np.linalg.norm(x.p_ref_m[a] - x.p_ref_m[b]) for a, b in pairs] for x in h]
    ).reshape(len(h), len(pairs))
    truth = [r.true_distances(x.t_s) for x in h]
    with_truth = bool(h) and all(d is not None for d in truth)
    d_true = np.array(truth, dtype=float).reshape(len(h), len(pairs)) if with_truth else None

    fig, ax = _figure("EKF (paper 001): pairwise distances, estimated (solid) and true (dashed)")
    for k, (a, b) in enumerate(pairs):
        (line,) = ax.plot(t - t0, d_est[:, k], label=f"{r.ids[a]}-{r.ids[b]}")
        if d_true is not None:
            ax.plot(t - t0, d_true[:, k], ls="--", color=line.get_color())
    ax.set_ylabel("distance (m)")
    paths = [_save(fig, ax, out / "ekf_distances.png", not h, "EKF updates")]

    fig, ax = _figure("EKF (paper 001): relative distance error per pair")
    if d_true is not None:
        for k, (a, b) in enumerate(pairs):
            err = np.abs(d_est[:, k] / d_true[:, k] - 1.0)
            ax.semilogy(t - t0, np.maximum(err, 1e-6), label=f"{r.ids[a]}-{r.ids[b]}")
        ax.axhline(EKF_SCALE_THRESHOLD, color="k", ls="--", lw=0.8, label="2%: metric scale")
    ax.set_ylabel("|d_est / d_true - 1|")
    paths.append(_save(fig, ax, out / "ekf_scale_error.png", d_true is None, "truth"))

    fig, ax = _figure("EKF (paper 001): 1-sigma position radius (reference fixed at 0)")
    for k, i in enumerate(r.ids[1:], start=1):
        ax.semilogy(t - t0, np.maximum([x.sigma_p_m[k] for x in h], 1e-6), label=f"vehicle {i}")
    ax.set_ylabel("sqrt(trace P_p) (m)")
    paths.append(_save(fig, ax, out / "ekf_sigma.png", not h, "EKF updates"))
    return paths
