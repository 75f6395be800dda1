"""Paper 002's bearing-only localization with neighbour states that arrive late (issue 25).

The solver of :func:`onboard.distributed.solvers.localize` runs synchronous rounds. In flight a
neighbour's state is some rounds old, so here agent ``i`` reads its own ``T_i`` and its
out-edges' ``lambda_ij`` of this round and its neighbours' (extrapolated) states of ``delay``
rounds ago: edge ``(i, j)`` has two residuals, ``i``'s (``T_j`` late) for ``grad_{T_i}`` and
``grad_{lambda_ij}``, and ``j``'s (``T_i`` and ``lambda_ij`` late) for ``grad_{T_j}``. The same
instances as the convergence benchmark (N = 10, ring with hops 1 and 3, random truth and start,
noiseless); reached = below 1e-3 of the extent after the best scale + translation.

Run as ``python benchmarks/bench_paper002_delay.py [--runs 100] [--rounds 10000]``; prints a
markdown table (docs/distributed.md). Not a timing benchmark.
"""

from __future__ import annotations

import argparse
from collections import deque

import numpy as np

from onboard.distributed.flow import momentum_weight, project_lower
from onboard.distributed.formation import bearings_from_positions
from onboard.distributed.localization import LAMBDA_MIN, localization_steps
from onboard.distributed.metrics import align_similarity
from sim.distributed_scenarios import ring_graph

N_LOC = 10


def delayed_localization(
    runs: int, rounds: int, delay: int, accelerated: bool, step_scale: float, seed: int
) -> np.ndarray:
    """Relative position errors (error / extent) of ``runs`` instances, one per run."""
    rng = np.random.default_rng(seed)
    e1 = ring_graph(N_LOC)
    e = np.concatenate([e1 + k * N_LOC for k in range(runs)])
    p = rng.uniform(-5, 5, (runs * N_LOC, 3))
    u, _ = bearings_from_positions(p, e)
    t = rng.normal(0, 5, p.shape)
    lam = project_lower(rng.uniform(1, 4, len(e)), LAMBDA_MIN)
    h_t, h_l = localization_steps(e, len(t))
    h_t, h_l = step_scale * h_t[:, None], step_scale * h_l
    sent = deque([(t, lam)] * max(delay, 1), maxlen=max(delay, 1))
    t_prev, lam_prev = t, lam
    src, dst = e[:, 0], e[:, 1]
    with np.errstate(all="ignore"):  # a diverging run is reported, not raised
        for k in range(rounds):
            w = momentum_weight(k) if accelerated else 0.0
            yt, yl = t + w * (t - t_prev), lam + w * (lam - lam_prev)
            old_t, old_l = (yt, yl) if delay == 0 else sent[0]
            r_src = old_t[dst] - yt[src] - yl[:, None] * u
            r_dst = yt[dst] - old_t[src] - old_l[:, None] * u
            g_t = np.zeros_like(t)
            np.add.at(g_t, src, -2.0 * r_src)
            np.add.at(g_t, dst, 2.0 * r_dst)
            g_l = -2.0 * np.sum(r_src * u, axis=1)
            t_prev, lam_prev = t, lam
            t = yt - h_t * g_t
            lam = project_lower(yl - h_l * g_l, LAMBDA_MIN)
            sent.append((yt, yl))
        out = np.empty(runs)
        for k in range(runs):
            s = slice(k * N_LOC, (k + 1) * N_LOC)
            al = align_similarity(t[s], p[s], rotate=False)
            out[k] = np.max(np.linalg.norm(al - p[s], axis=1)) / np.ptp(p[s])
    return np.where(np.isfinite(out), out, np.inf)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--rounds", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    cases = [(False, 1.0, d) for d in (0, 1, 3, 10)]
    cases += [(True, 1.0, d) for d in (0, 1, 2)]
    cases += [(True, 0.5, 1), (True, 0.25, 3)]
    print(f"{args.runs} random instances, {args.rounds} rounds, seed {args.seed}\n")
    print("| step | delay (rounds) | reached | worst error / extent |")
    print("|---|---|---|---|")
    for acc, scale, delay in cases:
        r = delayed_localization(args.runs, args.rounds, delay, acc, scale, args.seed)
        name = ("accelerated" if acc else "plain") + ("" if scale == 1.0 else f", steps x {scale}")
        worst = "diverged" if not np.all(np.isfinite(r)) else f"{r.max():.3g}"
        print(f"| {name} | {delay} | {np.mean(r < 1e-3):.2f} | {worst} |", flush=True)


if __name__ == "__main__":
    main()
