"""Consistency of paper 001's EKF against the prior's distance (issue 26, README paper 001).

Mean NEES of 20 seeded runs of the exciting three-agent team of ``sim/se3_montecarlo.py`` (as in the filter's tests)
(20 Hz, prior error drawn from the prior covariance) against the two-sided 95% chi-square
bounds, for priors from the test's close one to the ``ekf-se3`` scenario's far one (2 m, 60
degrees), plain and iterated updates.

    python benchmarks/ekf_nees_prior.py [--steps 300] [--runs 20]
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.stats import chi2

from sim.se3_montecarlo import monte_carlo_run

PRIORS = ((0.1, 0.05, 1), (0.5, 0.2, 1), (1.0, 0.5, 1), (2.0, 1.05, 1), (2.0, 1.05, 3))
"""``(sigma_p_m, sigma_theta_rad, iterations)``."""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--runs", type=int, default=20)
    args = ap.parse_args(argv)
    dof = 12
    lo, hi = chi2.ppf([0.025, 0.975], args.runs * dof) / args.runs
    print(f"bounds of the mean NEES: [{lo:.2f}, {hi:.2f}]")
    for sig_p, sig_t, it in PRIORS:
        nees = np.array(
            [
                monte_carlo_run("exciting", s, args.steps, sig_p, sig_t, iterations=it)[0]
                for s in range(args.runs)
            ]
        )
        mean = nees.mean(axis=0)
        outside = np.flatnonzero((mean < lo) | (mean > hi))
        since = (
            "never"
            if len(outside) and outside[-1] == args.steps - 1
            else (f"step {1 if len(outside) == 0 else outside[-1] + 2}")
        )
        print(
            f"prior {sig_p} m / {sig_t} rad, iterations {it}: mean NEES step 1 {mean[0]:.0f}, "
            f"step {args.steps // 6} {mean[args.steps // 6 - 1]:.1f}, last {mean[-1]:.1f} "
            f"(median {np.median(nees[:, -1]):.1f}, max {nees[:, -1].max():.0f}); inside from {since}",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
