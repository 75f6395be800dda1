"""EKF validation of landmark placement: planned vs random landmarks along a mission.

Protocol (paper 004 Section VII-B, adapted; see ``groundstation/planner/validation.py``):

- Missions: three closed waypoint loops flown 4 rounds at 6 m/s (1.1-2.0 km, like the
  paper's 1.0-1.4 km): ``loop`` (8 waypoints on a 100 m x 60 m rectangle, 10 m up),
  ``lawnmower`` (6 waypoints, three 100 m passes 40 m apart), ``triangle`` (4 waypoints,
  8-20 m up). The waypoints are the planner's setpoints.
- Landmarks: M in {2, 3} ground vehicles (down = 0), as in the paper's 2- and 3-UGV runs.
  Planned: IPOPT (5 starts) on the planar problem, optionally with the field-of-view
  constraint of eq. 19-20 (``--fov``; the paper does not give its camera's angle), prior
  30 I, R_min 5 m, R_max 60 m. Random (the paper's baseline): uniform in the convex hull of the
  waypoints' ground projection, a new draw every run.
- Sensing: odometry with a drifting velocity bias (about 1.5% of the distance, the paper's VIO
  drift), bearings to every landmark at each waypoint with noise sigma_m per component (the
  vehicle yaws to see them all: the paper's Assumption 2). EKF on position and bias.
- ``--fov DEG``: plan with eq. 19-20 and give the camera that field of view (+10 deg margin,
  :data:`CAMERA_MARGIN_DEG`), pointed at the
  planned heading at each waypoint (random placements: the heading that sees the most
  landmarks; ``--random-headings planned``: at the planned headings, the same mission with
  its yaw); ``--spin`` keeps the FOV plan but lets the vehicle see every landmark.
- ``--odometry-noise K``: multiply the odometry's white noise and bias random walk by K;
  ``--detection-range M``: landmarks farther than M metres go unseen (not in the planner's
  model; both are sensitivity studies).
- Metric: final position error (the paper's "drift") and mean error over the mission,
  averaged over runs; reduction = 1 - planned / random. Same odometry noise for all.

Also printed: the planning objective (worst trace at the setpoints) of the planned and of the
random placements, and what the planner's one-update model predicts for the same random draws:
the reduction of the worst trace (what the planner minimizes) and of the mean 1-sigma radius
over the setpoints (what a mean error follows).

Usage: ``python benchmarks/bench_planner_ekf.py [--runs R] [--sigma S ...] [--fov DEG]
[--random-headings best|planned] [--spin] [--odometry-noise K] [--detection-range M]
[--plot FILE]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from groundstation.planner.ipopt import IpoptPlacer
from groundstation.planner.problem import (
    PlacementProblem,
    constraint_values,
    landmark_traces,
    make_problem,
)
from groundstation.planner.validation import (
    Mission,
    OdometryNoise,
    best_view_headings,
    fly_mission,
    predicted_reductions,
    random_landmarks_in_hull,
    run_errors,
)

PRIOR_COV, R_MIN_M, R_MAX_M, SPEED_MPS, ROUNDS = 30.0, 5.0, 60.0, 6.0, 4
CAMERA_MARGIN_DEG = 10.0
"""The camera sees this much wider than the planned cone: planned landmarks sit on the cone's
edge (the constraint is active) and the vehicle is up to 0.3 m off the waypoint at a keyframe."""
MISSIONS = {
    "loop": [
        [-50.0, -30.0, -10.0], [0.0, -30.0, -10.0], [50.0, -30.0, -10.0], [50.0, 0.0, -10.0],
        [50.0, 30.0, -10.0], [0.0, 30.0, -10.0], [-50.0, 30.0, -10.0], [-50.0, 0.0, -10.0],
    ],
    "lawnmower": [
        [-50.0, -40.0, -10.0], [50.0, -40.0, -10.0], [50.0, 0.0, -10.0],
        [-50.0, 0.0, -10.0], [-50.0, 40.0, -10.0], [50.0, 40.0, -10.0],
    ],
    "triangle": [[-40.0, -40.0, -8.0], [45.0, -20.0, -15.0], [0.0, 45.0, -20.0], [-30.0, 20.0, -12.0]],
}  # fmt: skip


def lowest_mean_radius(problem: PlacementProblem, starts: int = 30, seed: int = 0) -> float:
    """The lowest mean 1-sigma radius ``mean_i sqrt(tr J_i^-1)`` a ground placement reaches.

    An analysis tool, not a planner: SLSQP from ``starts`` seeded random starts in the
    ``R_max`` square, over the landmarks' north and east, with the planner's constraints
    (without the field of view). It estimates how much lower than a baseline's the mean radius
    can be made at all, whatever the objective (the best of local searches: an estimate of the
    global minimum, not a certificate; the plan itself never beat it).
    """
    m, down = problem.n_landmarks, problem.ground_down_m or 0.0

    def ground(x: np.ndarray) -> np.ndarray:
        return np.column_stack([x.reshape(m, 2), np.full(m, down)])

    def mean_radius(x: np.ndarray) -> float:
        return float(np.mean(np.sqrt(landmark_traces(problem, ground(x)))))

    free = replace(problem, fov_rad=None, headings_rad=None)
    feasible = {"type": "ineq", "fun": lambda x: -constraint_values(free, ground(x))}
    rng = np.random.default_rng(seed)
    best = np.inf
    for _ in range(starts):
        x0 = rng.uniform(-problem.r_max_m, problem.r_max_m, size=2 * m)
        res = minimize(mean_radius, x0, constraints=[feasible], method="SLSQP")
        if res.success and np.all(constraint_values(free, ground(res.x)) <= 1e-6):
            best = min(best, float(res.fun))
    return best


@dataclass(frozen=True)
class CellTracks:
    """What the figure shows of one cell: the placements and the errors over the mission."""

    waypoints_ned: np.ndarray  # (K, 3)
    planned_ned: np.ndarray  # (M, 3)
    random_ned: np.ndarray  # (runs, M, 3), one draw per run
    error_m: dict[str, np.ndarray]  # "planned", "random", "none": mean over runs, (T,)
    dt_s: float


def validate_cell(
    name: str,
    m: int,
    sigma_m: float,
    fov_deg: float | None,
    runs: int,
    placer: IpoptPlacer,
    camera_limited: bool = True,
    random_headings: str = "best",
    odometry_scale: float = 1.0,
    detection_range_m: float | None = None,
) -> tuple[dict[str, float], CellTracks]:
    """Mean errors of planned, random and no landmarks on one mission, over ``runs`` runs.

    With ``fov_deg`` and ``camera_limited`` the camera sees only inside its field of view:
    at the planned headings for the planned placement; for the random one at the headings that
    see the most landmarks (:func:`best_view_headings`, ``random_headings="best"``) or at the
    planned ones (``"planned"``: the same mission, yaw included). ``odometry_scale`` multiplies
    the odometry's white noise and bias random walk; ``detection_range_m`` hides landmarks
    farther than that from the camera, for every placement.

    Also returned: what the one-update model predicts (:func:`predicted_reductions`) for the
    same random draws.
    """
    waypoints = np.asarray(MISSIONS[name])
    mission = Mission(waypoints, speed_m_s=SPEED_MPS, rounds=ROUNDS)
    problem = make_problem(
        waypoints, m, sigma_m, PRIOR_COV, R_MIN_M, R_MAX_M, fov_deg=fov_deg, ground_down_m=0.0
    )
    planned = placer.solve(problem, seed=0, starts=5)
    base = OdometryNoise()
    noise = replace(
        base,
        white_m_s=base.white_m_s * odometry_scale,
        bias_walk_mps_per_sqrt_s=base.bias_walk_mps_per_sqrt_s * odometry_scale,
    )
    rows: dict[str, list[tuple[float, float]]] = {"planned": [], "random": [], "none": []}
    series: dict[str, list[np.ndarray]] = {key: [] for key in rows}
    random_traces, random_draws = [], []
    for run in range(runs):
        random_lm = random_landmarks_in_hull(
            waypoints, m, 0.0, R_MIN_M, np.random.default_rng([7, m, run])
        )
        random_traces.append(landmark_traces(problem, random_lm))
        random_draws.append(random_lm)
        cases = (
            ("planned", planned.landmarks_ned, planned.headings_rad),
            ("random", random_lm, planned.headings_rad if random_headings == "planned" else None),
            ("none", np.zeros((0, 3)), np.zeros(len(waypoints))),
        )
        for key, landmarks, headings in cases:
            view: dict[str, object] = {"detection_range_m": detection_range_m}
            if fov_deg is not None and camera_limited:
                fov = np.radians(fov_deg + CAMERA_MARGIN_DEG)
                if headings is None:
                    headings = best_view_headings(waypoints, landmarks, fov)
                view |= {"headings_rad": headings, "fov_rad": fov}
            e = run_errors(mission, landmarks, sigma_m, noise, seed=(11, run), **view)
            rows[key].append((e.final_m, e.mean_m))
            series[key].append(e.series_m)
    predicted = predicted_reductions(landmark_traces(problem, planned.landmarks_ned), random_traces)
    mean_radius_random = float(np.mean(np.sqrt(random_traces)))
    out = {
        "objective_planned": planned.objective,
        "objective_random": float(np.mean(np.max(random_traces, axis=1))),
        "predicted_worst_trace": predicted.worst_trace,
        "predicted_mean_radius": predicted.mean_radius,
        "possible_mean_radius": 1.0 - lowest_mean_radius(problem) / mean_radius_random,
    }
    for key, values in rows.items():
        arr = np.asarray(values)
        out[f"final_{key}"], out[f"mean_{key}"] = (float(v) for v in arr.mean(axis=0))
        out[f"final_{key}_se"] = float(arr[:, 0].std(ddof=1) / np.sqrt(len(arr)))
    path = fly_mission(mission).p_ned
    out["length_m"] = float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1)))
    tracks = CellTracks(
        waypoints_ned=waypoints,
        planned_ned=planned.landmarks_ned,
        random_ned=np.asarray(random_draws),
        error_m={key: np.mean(values, axis=0) for key, values in series.items()},
        dt_s=mission.dt_s,
    )
    return out, tracks


def plot_validation(tracks: dict[tuple[str, int], CellTracks], title: str, path: Path) -> None:
    """One row per mission: a top view of the waypoints, the planned landmarks and the random
    draws, then the mean position error over the mission for each M (log scale)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(dict.fromkeys(name for name, _ in tracks))
    ms = sorted({m for _, m in tracks})
    fig, axes = plt.subplots(
        len(names), 1 + len(ms), figsize=(4.2 * (1 + len(ms)), 3.4 * len(names)), squeeze=False
    )
    colours = {"planned": "tab:blue", "random": "tab:orange", "none": "0.5"}
    labels = {"planned": "planned", "random": "random in the hull", "none": "odometry only"}
    markers = {2: "^", 3: "*"}
    for row, name in enumerate(names):
        top = axes[row, 0]
        w = tracks[(name, ms[0])].waypoints_ned
        loop = np.vstack([w, w[:1]])
        top.plot(loop[:, 1], loop[:, 0], "k-o", ms=3, lw=1, label="waypoints")
        for m in ms:
            c = tracks[(name, m)]
            r = c.random_ned.reshape(-1, 3)
            top.scatter(
                r[:, 1], r[:, 0], s=6, c=colours["random"], alpha=0.35, lw=0,
                label="random draws" if m == ms[0] else None,
            )  # fmt: skip
            top.scatter(
                c.planned_ned[:, 1], c.planned_ned[:, 0], s=90, marker=markers.get(m, "s"),
                c=colours["planned"], edgecolors="k", label=f"planned, M = {m}",
            )  # fmt: skip
        top.set_aspect("equal")
        top.set_xlabel("east (m)")
        top.set_ylabel(f"{name}\nnorth (m)")
        top.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.22), ncol=2)
        for col, m in enumerate(ms, start=1):
            ax = axes[row, col]
            c = tracks[(name, m)]
            for key, err in c.error_m.items():
                t = np.arange(len(err)) * c.dt_s
                ax.semilogy(t, err, color=colours[key], lw=1, label=labels[key])
            ax.set_title(f"{name}, M = {m}", fontsize=9)
            ax.set_xlabel("time (s)")
            ax.set_ylabel("mean position error (m)")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def ekf_validation(
    runs: int,
    sigmas: list[float],
    fov_deg: float | None,
    camera_limited: bool = True,
    random_headings: str = "best",
    odometry_scale: float = 1.0,
    plot: Path | None = None,
    detection_range_m: float | None = None,
) -> dict[str, object]:
    """Print the table of every sigma; with ``plot``, draw the first sigma's cells there."""
    placer = IpoptPlacer()
    record: dict[str, object] = {}
    fov_text = "no field-of-view constraint" if fov_deg is None else f"FOV {fov_deg:g} deg"
    if fov_deg is not None:
        camera = f", camera {fov_deg + CAMERA_MARGIN_DEG:g} deg"
        camera += f" (random placements: {random_headings} headings)"
        fov_text += camera if camera_limited else ", every landmark seen"
    if detection_range_m is not None:
        fov_text += f", detection range {detection_range_m:g} m"
    print(
        f"EKF validation: {runs} runs per cell, planar landmarks, {fov_text},"
        f" odometry noise x{odometry_scale:g}"
    )
    print(
        "'1-update': reductions the one-update model predicts against the random draws: worst"
        " trace / mean 1-sigma radius of the plan / lowest mean radius of any placement"
    )
    for sigma in sigmas:
        print(f"\nsigma_m = {sigma:g}")
        print(f"{'mission':>10} {'M':>2} {'km':>5} {'obj plan/rand':>14} "
              f"{'drift planned':>14} {'random':>12} {'odometry':>9} {'drift red.':>10} "
              f"{'mean-err red.':>13} {'1-update':>13}")  # fmt: skip
        final_red, mean_red, cells = [], [], []
        tracks: dict[tuple[str, int], CellTracks] = {}
        for name in MISSIONS:
            for m in (2, 3):
                c, tracks[(name, m)] = validate_cell(
                    name, m, sigma, fov_deg, runs, placer, camera_limited, random_headings,
                    odometry_scale, detection_range_m,
                )  # fmt: skip
                fr = 1.0 - c["final_planned"] / c["final_random"]
                mr = 1.0 - c["mean_planned"] / c["mean_random"]
                final_red.append(fr)
                mean_red.append(mr)
                cells.append(c)
                record[f"{sigma},{name},{m}"] = c
                print(
                    f"{name:>10} {m:>2} {c['length_m'] / 1e3:5.2f}"
                    f" {c['objective_planned']:6.1f}/{c['objective_random']:<7.1f}"
                    f" {c['final_planned']:6.2f}+-{c['final_planned_se']:.2f}"
                    f" {c['final_random']:6.2f}+-{c['final_random_se']:.2f}"
                    f" {c['final_none']:9.2f} {100 * fr:9.0f}% {100 * mr:12.0f}%"
                    f" {100 * c['predicted_worst_trace']:4.0f}/{100 * c['predicted_mean_radius']:.0f}"
                    f"/{100 * c['possible_mean_radius']:.0f}%",
                    flush=True,
                )
        average = {key: 100 * np.mean([c[key] for c in cells]) for key in cells[0]}
        print(
            f"  average reduction vs random: drift {100 * np.mean(final_red):.0f}%,"
            f" mean error {100 * np.mean(mean_red):.0f}% (target >= 50%; paper 59% drift);"
            f" one-update model: worst trace {average['predicted_worst_trace']:.0f}%,"
            f" mean radius {average['predicted_mean_radius']:.0f}%,"
            f" at best {average['possible_mean_radius']:.0f}%"
        )
        if plot is not None and sigma == sigmas[0]:
            title = (
                f"EKF along the mission, sigma_m = {sigma:g}, {fov_text}: mean over {runs} runs;"
                f" drift {100 * np.mean(final_red):.0f}% lower with the planned landmarks"
            )
            plot_validation(tracks, title, plot)
            print(f"  figure: {plot}")
    return record


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--sigma", type=float, nargs="+", default=[0.1, 0.02])
    ap.add_argument("--fov", type=float, default=None, help="plan with this field of view (deg)")
    ap.add_argument(
        "--spin", action="store_true", help="with --fov: the camera still sees every landmark"
    )
    ap.add_argument(
        "--random-headings",
        choices=("best", "planned"),
        default="best",
        help="with --fov: random placements are seen from the headings that see most of them"
        " (best) or from the planned ones (planned: the same mission, yaw included)",
    )
    ap.add_argument(
        "--odometry-noise",
        type=float,
        default=1.0,
        metavar="K",
        help="multiply the odometry's white noise and bias random walk by K",
    )
    ap.add_argument(
        "--detection-range",
        type=float,
        default=None,
        metavar="M",
        help="landmarks farther than M metres are not detected (any placement)",
    )
    ap.add_argument(
        "--plot", type=Path, default=None, metavar="FILE", help="figure of the first sigma's runs"
    )
    args = ap.parse_args(argv)
    if args.odometry_noise <= 0 or args.runs < 2:
        ap.error("--odometry-noise must be positive and --runs at least 2")
    if args.detection_range is not None and not args.detection_range > 0:
        ap.error("--detection-range must be positive")
    if args.plot is not None and not args.plot.parent.is_dir():
        ap.error(f"--plot: no directory {args.plot.parent}")
    t0 = time.perf_counter()
    ekf_validation(
        args.runs,
        args.sigma,
        args.fov,
        camera_limited=not args.spin,
        random_headings=args.random_headings,
        odometry_scale=args.odometry_noise,
        plot=args.plot,
        detection_range_m=args.detection_range,
    )
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
