"""Paper 001's EKF on tilted multicopters: levelled, un-levelled + attitude, native (issue 26).

For each seed, one tilted team of :func:`sim.se3_runner.tilted_team` (4 vehicles, roll and
pitch up to 15 degrees, 1 degree bearings, ATTITUDE at 100 Hz 3 ms off the frames) run along
the three paths of :func:`sim.se3_runner.run_tilted_team`: final scale error, position error,
relative rotation error (deg) and time to 2% scale error per path, and how far the
un-levelled path's positions and scale stay from the levelled path's after 10 s.

    python benchmarks/ekf_tilted.py [--seeds 5] [--attitude-noise-deg 0.3] [--duration-s 30]
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from sim.se3_runner import TILTED_PATHS, TiltedTeamConfig, run_tilted_team, tilted_team


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--attitude-noise-deg", type=float, default=0.3)
    ap.add_argument("--duration-s", type=float, default=30.0)
    args = ap.parse_args(argv)
    print("| seed | path | scale error | position error m | rotation error deg | time to 2% s |")
    print("|---|---|---|---|---|---|")
    gaps = []
    for seed in range(args.seeds):
        cfg = TiltedTeamConfig(
            seed=seed,
            duration_s=args.duration_s,
            attitude_noise_rad=math.radians(args.attitude_noise_deg),
        )
        team = tilted_team(cfg)
        recs = {p: run_tilted_team(team, cfg, p) for p in TILTED_PATHS}
        for p, r in recs.items():
            s = r.summary()
            rot_deg = math.degrees(math.acos(1.0 - float(s["final_rotation_error"])))
            t2 = s["time_to_scale_s"]
            t2_text = "never" if t2 is None else f"{t2:.2f}"
            print(
                f"| {seed} | {p} | {s['final_scale_error']:+.4f} | "
                f"{s['final_position_error_m']:.3f} | {rot_deg:.2f} | {t2_text} |",
                flush=True,
            )
        a, b = recs["levelled"], recs["unlevelled"]
        late = a.t_s >= 10.0
        dp = np.linalg.norm(a.p_est_heading - b.p_est_heading, axis=2)[late].max()
        ds = np.abs(a.scale_error - b.scale_error)[late].max()
        gaps.append((dp, ds))
    dp, ds = np.array(gaps).T
    print(
        f"un-levelled vs levelled after 10 s: positions {dp.min():.4f}-{dp.max():.4f} m, "
        f"scale {ds.min():.5f}-{ds.max():.5f}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
