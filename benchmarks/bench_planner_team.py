"""Paper 004 Fig. 9: a team of 10 camera vehicles (UAVs) and 10 ground landmarks (UGVs).

Protocol (``groundstation/planner/team.py``; paper 004 Section VII, Fig. 9):

- Missions: a 250 m x 100 m area cut into 10 cells of 50 m; each UAV flies a jittered closed
  loop of 6 waypoints (radius about 19 m) in its own cell, at its own height (8-17 m), 3 rounds
  at 6 m/s (about 300-380 m each; paper: median 359 m, 4.17 km in all). Seeded (``--seed``).
- Planning: one problem whose setpoints are all 60 waypoints, M = 10 ground landmarks
  (down = 0), IPOPT (``--starts`` seeded starts), prior 30 I, sigma_m 0.1, R_min 5 m, R_max
  140 m (the area fits in that ball).
- Evaluation, ``--runs`` runs: every UAV fuses its velocity odometry (the single-UAV
  benchmark's drifting bias, ``--odometry-noise K`` scales its white noise and bias walk) with
  bearings to every landmark at each waypoint, in the EKF of
  ``groundstation/planner/validation.py``; with planned landmarks, with random ones (uniform in
  the hull of all waypoints' ground projection, a new draw per run) and with none. Same noise
  for the three. ``--detection-range M``: landmarks farther than M go unseen.
- Metric (the paper's): per UAV, drift = final position error averaged over the runs; drift
  reduction = 1 - drift / odometry-only drift; mean and standard deviation over the UAVs
  (paper: 71.50% and 9.85%). Also printed: the reduction against random landmarks (the paper
  gives none for Fig. 9) and what the planner's one-update model predicts for it.

Usage: ``python benchmarks/bench_planner_team.py [--runs R] [--seed S] [--starts K]
[--odometry-noise K] [--detection-range M] [--plot FILE]`` (about 40 s at the defaults).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from groundstation.planner import make_problem
from groundstation.planner.ipopt import IpoptPlacer
from groundstation.planner.problem import landmark_traces
from groundstation.planner.team import (
    TeamLayout,
    drift_reduction,
    mission_length_m,
    team_drifts,
    team_missions,
    team_setpoints,
)
from groundstation.planner.validation import (
    OdometryNoise,
    predicted_reductions,
    random_landmarks_in_hull,
)

N_LANDMARKS, SIGMA_M, PRIOR_COV, R_MIN_M, R_MAX_M = 10, 0.1, 30.0, 5.0, 140.0
PAPER_REDUCTION, PAPER_STD = 0.7150, 0.0985


def team_experiment(
    runs: int,
    seed: int,
    starts: int,
    odometry_scale: float,
    detection_range_m: float | None,
    progress: bool = True,
) -> dict[str, object]:
    """Plan once for the team, then fly ``runs`` seeded runs; returns the drifts and the plan."""
    from rich.progress import Progress

    layout = TeamLayout()
    missions = team_missions(layout, seed)
    setpoints = team_setpoints(missions)
    problem = make_problem(
        setpoints, N_LANDMARKS, SIGMA_M, PRIOR_COV, R_MIN_M, R_MAX_M, ground_down_m=0.0
    )
    t0 = time.perf_counter()
    plan = IpoptPlacer().solve(problem, seed=seed, starts=starts)
    plan_s = time.perf_counter() - t0
    base = OdometryNoise()
    noise = replace(
        base,
        white_m_s=base.white_m_s * odometry_scale,
        bias_walk_mps_per_sqrt_s=base.bias_walk_mps_per_sqrt_s * odometry_scale,
    )
    drifts: dict[str, list[np.ndarray]] = {"planned": [], "random": [], "none": []}
    random_draws, random_traces = [], []
    with Progress(transient=True, disable=not progress) as bar:
        task = bar.add_task("runs", total=runs)
        for run in range(runs):
            rl = random_landmarks_in_hull(
                setpoints, N_LANDMARKS, 0.0, R_MIN_M, np.random.default_rng([seed, 7, run])
            )
            random_draws.append(rl)
            random_traces.append(landmark_traces(problem, rl))
            cases = {"planned": plan.landmarks_ned, "random": rl, "none": np.zeros((0, 3))}
            for key, landmarks in cases.items():
                drifts[key].append(
                    team_drifts(missions, landmarks, SIGMA_M, noise, (seed, run), detection_range_m)
                )
            bar.advance(task)
    return {
        "missions": missions,
        "lengths_m": np.array([mission_length_m(m) for m in missions]),
        "plan": plan,
        "plan_s": plan_s,
        "random_draws": np.asarray(random_draws),
        "predicted": predicted_reductions(
            landmark_traces(problem, plan.landmarks_ned), random_traces
        ),
        "objective_random": float(np.mean(np.max(random_traces, axis=1))),
        "drifts": {k: np.asarray(v) for k, v in drifts.items()},  # (runs, n_vehicles)
    }


def summarize(out: dict[str, object]) -> dict[str, float]:
    """The paper's statistics: per-UAV mean drift over the runs, then mean / std over UAVs."""
    d = {k: v.mean(axis=0) for k, v in out["drifts"].items()}  # type: ignore[union-attr]
    vs_odo = drift_reduction(d["planned"], d["none"])
    vs_odo_random = drift_reduction(d["random"], d["none"])
    vs_random = drift_reduction(d["planned"], d["random"])
    return {
        "reduction_vs_odometry": float(vs_odo.mean()),
        "reduction_vs_odometry_std": float(vs_odo.std(ddof=1)),
        "random_vs_odometry": float(vs_odo_random.mean()),
        "reduction_vs_random": float(vs_random.mean()),
        "reduction_vs_random_std": float(vs_random.std(ddof=1)),
        "drift_planned_m": float(d["planned"].mean()),
        "drift_random_m": float(d["random"].mean()),
        "drift_odometry_m": float(d["none"].mean()),
    }


def plot_team(out: dict[str, object], title: str, path: Path) -> None:
    """Left: the 10 loops, the planned landmarks and the random draws (top view). Right: each
    UAV's drift with planned, random and no landmarks (mean over the runs)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (top, bars) = plt.subplots(1, 2, figsize=(13, 4.6), width_ratios=[1.6, 1])
    for i, m in enumerate(out["missions"]):  # type: ignore[arg-type]
        w = np.vstack([m.waypoints_ned, m.waypoints_ned[:1]])
        top.plot(w[:, 1], w[:, 0], "-o", ms=2, lw=1, label=None)
        top.annotate(str(i + 1), w[:-1, 1::-1].mean(axis=0), ha="center", va="center", fontsize=8)
    r = out["random_draws"].reshape(-1, 3)  # type: ignore[union-attr]
    top.scatter(r[:, 1], r[:, 0], s=5, c="tab:orange", alpha=0.3, lw=0, label="random draws")
    z = out["plan"].landmarks_ned  # type: ignore[union-attr]
    top.scatter(z[:, 1], z[:, 0], s=90, marker="*", c="tab:blue", edgecolors="k", label="planned")
    top.set_aspect("equal")
    top.set_xlabel("east (m)")
    top.set_ylabel("north (m)")
    top.legend(fontsize=8, loc="lower right")
    d = {k: v.mean(axis=0) for k, v in out["drifts"].items()}  # type: ignore[union-attr]
    idx = np.arange(len(d["none"])) + 1
    for k, (key, colour, label) in enumerate(
        [("planned", "tab:blue", "planned"), ("random", "tab:orange", "random in the hull"),
         ("none", "0.5", "odometry only")]
    ):  # fmt: skip
        bars.bar(idx + (k - 1) * 0.27, d[key], width=0.27, color=colour, label=label)
    bars.set_xticks(idx)
    bars.set_xlabel("UAV")
    bars.set_ylabel("drift (final position error, m)")
    bars.legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--starts", type=int, default=3, help="IPOPT multi-start")
    ap.add_argument("--odometry-noise", type=float, default=1.0, metavar="K")
    ap.add_argument("--detection-range", type=float, default=None, metavar="M")
    ap.add_argument("--plot", type=Path, default=None, metavar="FILE")
    args = ap.parse_args(argv)
    if args.runs < 2 or args.starts < 1 or args.odometry_noise <= 0:
        ap.error("--runs must be at least 2, --starts at least 1, --odometry-noise positive")
    if args.detection_range is not None and not args.detection_range > 0:
        ap.error("--detection-range must be positive")
    if args.plot is not None and not args.plot.parent.is_dir():
        ap.error(f"--plot: no directory {args.plot.parent}")
    t0 = time.perf_counter()
    out = team_experiment(
        args.runs, args.seed, args.starts, args.odometry_noise, args.detection_range
    )
    s = summarize(out)
    lengths = out["lengths_m"]
    p = out["predicted"]
    print(
        f"team: 10 UAVs, {N_LANDMARKS} ground landmarks, seed {args.seed}, {args.runs} runs,"
        f" odometry noise x{args.odometry_noise:g}, detection range"
        f" {'none' if args.detection_range is None else f'{args.detection_range:g} m'}"
    )
    print(
        f"trajectories: median {np.median(lengths):.0f} m, sum {lengths.sum() / 1e3:.2f} km"
        f" (paper 359 m, 4.17 km); plan {out['plan_s']:.1f} s, objective"
        f" {out['plan'].objective:.1f} m^2 (random draws: {out['objective_random']:.1f})"
    )
    print(
        f"drift (mean over UAVs): planned {s['drift_planned_m']:.2f} m, random"
        f" {s['drift_random_m']:.2f} m, odometry only {s['drift_odometry_m']:.2f} m"
    )
    print(
        f"drift reduction vs odometry (paper's metric): {100 * s['reduction_vs_odometry']:.1f}%"
        f" +- {100 * s['reduction_vs_odometry_std']:.1f}% over the UAVs (paper"
        f" {100 * PAPER_REDUCTION:.2f}% +- {100 * PAPER_STD:.2f}%); random landmarks:"
        f" {100 * s['random_vs_odometry']:.1f}%"
    )
    print(
        f"drift reduction vs random: {100 * s['reduction_vs_random']:.1f}%"
        f" +- {100 * s['reduction_vs_random_std']:.1f}%; one-update model predicts: worst trace"
        f" {100 * p.worst_trace:.0f}%, mean radius {100 * p.mean_radius:.0f}%"
    )
    if args.plot is not None:
        title = (
            f"paper 004 Fig. 9 scenario, {args.runs} runs: drift"
            f" {100 * s['reduction_vs_odometry']:.0f}% below odometry (paper 71.5%),"
            f" {100 * s['reduction_vs_random']:.0f}% below random landmarks"
        )
        plot_team(out, title, args.plot)
        print(f"figure: {args.plot}")
    print(f"total {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
