"""Acceptance study of issue 4 (paper 003 reproduced): 10 seeds of each rigidity scenario.

Runs ``rigidity-tracking`` (distributed eigen-estimate), the same with the centralized
eigenpair (every agent computes it from all shared estimates), ``rigidity-tracking-off`` and
``rigidity-sphere`` (``--variants``; ``*-100hz`` variants run a 10 ms loop), and reports per
run and in aggregate:

* with maintenance: the weighted eigenvalue of the true configuration stays above
  ``lambda_min`` for the whole mission, and every target is in some camera's view at the end;
* without: in how many seeds rigidity is lost (eigenvalue below 1e-4);
* localization error at the start, its maximum during the mission and at the end;
* the distributed eigenvalue's error against the centralized value on the same estimates.

Usage: ``python benchmarks/rigidity_study.py [--seeds 10] [--duration 60] [--jobs 2]
[--out results.json]``. Each run is one process; results are deterministic per seed.
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

VARIANTS: dict[str, tuple[str, dict[str, object], dict[str, object]]] = {
    # name: (scenario, agent config overrides, runner overrides); default loop 2 ms
    "tracking": ("rigidity-tracking", {}, {}),
    "tracking-centralized": ("rigidity-tracking", {"rigidity_eigen": "centralized"}, {}),
    "tracking-off": ("rigidity-tracking-off", {}, {}),
    "sphere": ("rigidity-sphere", {}, {}),
    # the same at a 10 ms loop / message period (5x cheaper; 5x fewer message rounds per second)
    "tracking-100hz": ("rigidity-tracking", {}, {"dt_s": 0.01, "record_every": 10}),
    "tracking-centralized-100hz": (
        "rigidity-tracking",
        {"rigidity_eigen": "centralized"},
        {"dt_s": 0.01, "record_every": 10},
    ),
    "tracking-off-100hz": ("rigidity-tracking-off", {}, {"dt_s": 0.01, "record_every": 10}),
}


def _one(job: tuple[str, int, float]) -> dict[str, object]:
    from sim.rigidity_scenarios import run_rigidity_scenario

    variant, seed, duration = job
    name, overrides, runner = VARIANTS[variant]
    t0 = time.perf_counter()
    rr = run_rigidity_scenario(name, seed, duration, config_overrides=overrides, **runner)
    out = {"variant": variant, **rr.summary(), "wall_s": time.perf_counter() - t0}
    return out


def _aggregate(rows: list[dict[str, object]], variant: str) -> str:
    r = [x for x in rows if x["variant"] == variant]
    if not r:
        return f"{variant}: no runs"
    above = sum(bool(x["stayed_above_lambda_min"]) for x in r)
    lost = sum(bool(x["rigidity_lost"]) for x in r)
    all_tracked = sum(x["targets_tracked"] == x["n_targets"] for x in r)
    lam = np.array([x["min_rigidity_eigenvalue"] for x in r])
    frac = np.array([x["fraction_time_rigid"] for x in r])
    loc0 = np.array([x["initial_localization_error"] for x in r])
    locm = np.array([x["max_localization_error_after_warmup"] for x in r])
    locf = np.array([x["final_localization_error"] for x in r])
    eig = np.array([x["distributed_eigen_error_max"] or np.nan for x in r])
    eig95 = np.array([x["distributed_eigen_error_p95"] or np.nan for x in r])
    return (
        f"{variant} ({len(r)} seeds): above lambda_min {above}/{len(r)}, rigidity lost {lost}/{len(r)}, "
        f"all targets in view at the end {all_tracked}/{len(r)}\n"
        f"  min eigenvalue: median {np.median(lam):.4f}, min {lam.min():.4f}; "
        f"fraction of time IAR: median {np.median(frac):.3f}, min {frac.min():.3f}\n"
        f"  localization error [m]: start median {np.median(loc0):.3f}, mission max median "
        f"{np.median(locm):.3f} (worst {locm.max():.3f}), final median {np.median(locf):.3f} "
        f"(worst {locf.max():.3f})\n"
        f"  distributed eigenvalue error vs centralized: max median {np.nanmedian(eig):.3f} "
        f"(worst {np.nanmax(eig):.3f}), p95 median {np.nanmedian(eig95):.3f}"
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--variants", default="tracking,tracking-centralized,tracking-off,sphere")
    ap.add_argument("--out", default=None, help="write every run's summary to this JSON file")
    args = ap.parse_args()
    jobs = [(v, s, args.duration) for v in args.variants.split(",") for s in range(args.seeds)]
    rows: list[dict[str, object]] = []
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        for row in pool.map(_one, jobs):
            rows.append(row)
            print(json.dumps(row), flush=True)
    print()
    for v in args.variants.split(","):
        print(_aggregate(rows, v))
    if args.out:
        with open(args.out, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
