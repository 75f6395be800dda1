"""Global convergence of paper 002's distributed flows, measured (issue 25).

For each problem, ``--runs`` (default 200) random instances, each with its own random truth and
random initialization, are solved by the flows of :mod:`onboard.distributed` (all instances at
once as one disjoint graph: the flows are per edge, so this is the same computation). Noiseless:
the fraction that reaches the global minimizer; with 1 and 2 degrees of bearing noise (relative
rotation noise for the rotation problem): error statistics.

* bearing-only localization: N = 10 uniform in a 10 m cube, ring graph with hops 1 and 3 (both
  directions, 40 edges), rotations known, translations ``N(0, 5 m)``, scales uniform in [1, 4],
  ``lambda >= 1`` (eq. 16-17); error: largest position error after the best scale + translation,
  over the extent (``ptp``) of the truth. Reached = below 1e-3 of the extent. Solved with the
  accelerated step of ``localize`` (docs/distributed.md, "Slow scale mode"); the noiseless
  fraction of plain projected descent, same budget, is printed beside it.
* bearing + distance localization: the same plus one range (edge 0), no constraint (eq. 22);
  error after translation only (congruent). Reached = below 1e-3 of the extent.
* bearing-only / bearing + distance formation: the ``formation-2d-*`` problems (7 agents, hexagon;
  fig. 11a/b), start uniform in a 12 m square, 60 s of the flow at 5 ms; reached = every bearing
  within 0.5 degrees (and, with the range, every distance within 5 cm). ``min scale`` is the
  smallest final mean edge length over the desired one (bearing-only: the flow only shrinks).
* rotation estimation: N = 10 true attitudes uniform on SO(3), initial estimates uniform on SO(3),
  the same graph, ``f_R`` of eq. 15 (``b = 2``) against the plain ``x^2 / 2``; error: largest
  after the best global rotation; reached = below 0.1 degrees.

Run as ``python benchmarks/bench_paper002_convergence.py [--runs 200] [--quick]``. It prints a
markdown table (the one in README.md and docs/sim.md). Not a timing benchmark.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from onboard.distributed.formation import bearings_from_positions
from onboard.distributed.metrics import align_similarity, rotation_error_deg
from onboard.distributed.reshaping import F_R, F_R_PLAIN, ReshapeR
from onboard.distributed.rotation import relative_rotations
from onboard.distributed.solvers import estimate_rotations, localize
from onboard.geometry import so3_exp
from sim.distributed_scenarios import (
    DT_S,
    F_D_FORMATION,
    FORMATION_SCENARIOS,
    K_GAIN,
    _uniform_rotvec,
    ring_graph,
)
from sim.formation2d import FormationProblem, run_formation

N_LOC = 10


def _union(edges: np.ndarray, n: int, runs: int) -> np.ndarray:
    return np.concatenate([edges + k * n for k in range(runs)])


def _noisy(b: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    if sigma <= 0:
        return b
    n = rng.normal(0, sigma, b.shape)
    n -= np.sum(n * b, axis=1)[:, None] * b
    out = b + n
    return out / np.linalg.norm(out, axis=1)[:, None]


def localization(
    runs: int, noise_deg: float, ranged: bool, rounds: int, seed: int, accelerated: bool = True
) -> np.ndarray:
    """Relative position errors (error / extent), one per run."""
    rng = np.random.default_rng(seed)
    e1 = ring_graph(N_LOC)
    e = _union(e1, N_LOC, runs)
    p = rng.uniform(-5, 5, (runs * N_LOC, 3))
    b, d = bearings_from_positions(p, e)
    b = _noisy(b, math.radians(noise_deg) / math.sqrt(2), rng)  # per tangent axis
    ranges = None
    if ranged:
        ranges = np.full(len(e), np.nan)
        first = np.arange(runs) * len(e1)
        ranges[first] = d[first]
    t0 = rng.normal(0, 5, p.shape)
    lam0 = rng.uniform(1, 4, len(e))
    res = localize(e, b, t0, lam0, rounds, ranges, record_cost=False, accelerated=accelerated)
    out = np.empty(runs)
    for k in range(runs):
        s = slice(k * N_LOC, (k + 1) * N_LOC)
        pt, pe = p[s], res.t[s]
        if ranged:
            al = pe - pe.mean(axis=0) + pt.mean(axis=0)
        else:
            al = align_similarity(pe, pt, rotate=False)
        out[k] = np.max(np.linalg.norm(al - pt, axis=1)) / np.ptp(pt)
    return out


def formation(runs: int, noise_deg: float, name: str, seed: int) -> tuple[np.ndarray, ...]:
    """Final max bearing error (deg), max distance error (m), scale, one per run."""
    rng = np.random.default_rng(seed)
    prob = FORMATION_SCENARIOS[name].problem
    n = len(prob.p_des)
    ne = len(prob.edges)
    big = FormationProblem(
        p_des=np.tile(prob.p_des, (runs, 1)),
        edges=_union(prob.edges, n, runs),
        ranged=np.tile(prob.ranged, runs),
    )
    p0 = rng.uniform(-6, 6, big.p_des.shape)
    run = run_formation(
        big,
        p0,
        60.0,
        dt_s=DT_S,
        k=K_GAIN,
        f_d=F_D_FORMATION,
        bearing_noise_rad=math.radians(noise_deg),
        seed=seed,
        record_every=10**9,
    )
    be = run.bearing_error_deg[-1].reshape(runs, ne).max(axis=1)
    de = run.distance_error_m[-1].reshape(runs, ne).max(axis=1)
    p = run.p[-1]
    e = big.edges
    dd = np.linalg.norm(p[e[:, 1]] - p[e[:, 0]], axis=1).reshape(runs, ne)
    d_des = np.linalg.norm(prob.p_des[prob.edges[:, 1]] - prob.p_des[prob.edges[:, 0]], axis=1)
    return be, de, dd.mean(axis=1) / d_des.mean()


def rotations(runs: int, noise_deg: float, f: ReshapeR, rounds: int, seed: int) -> np.ndarray:
    """Largest rotation error (deg) after the global alignment, one per run."""
    rng = np.random.default_rng(seed)
    e1 = ring_graph(N_LOC)
    e = _union(e1, N_LOC, runs)
    r_true = so3_exp(_uniform_rotvec(rng, runs * N_LOC))
    meas = relative_rotations(r_true, e)
    if noise_deg > 0:
        meas = meas @ so3_exp(rng.normal(0, math.radians(noise_deg) / math.sqrt(3), (len(e), 3)))
    res = estimate_rotations(e, meas, so3_exp(_uniform_rotvec(rng, runs * N_LOC)), rounds, f)
    return np.array(
        [
            rotation_error_deg(
                res.rot[k * N_LOC : (k + 1) * N_LOC], r_true[k * N_LOC : (k + 1) * N_LOC]
            )
            for k in range(runs)
        ]
    )


def _stats(x: np.ndarray, unit: str, scale: float = 1.0) -> str:
    q = np.percentile(x * scale, [50, 95])
    return f"median {q[0]:.3g}{unit}, p95 {q[1]:.3g}{unit}, max {np.max(x) * scale:.3g}{unit}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--quick", action="store_true", help="20 runs, shorter localization budget")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    runs = 20 if args.quick else args.runs
    loc_rounds = 10000 if args.quick else 30000
    rot_rounds = 3000
    t0 = time.perf_counter()
    rows: list[tuple[str, str, str, str]] = []
    for ranged, label in (
        (False, "bearing-only localization"),
        (True, "bearing + distance localization"),
    ):
        r0 = localization(runs, 0.0, ranged, loc_rounds, args.seed)
        plain = localization(runs, 0.0, ranged, loc_rounds, args.seed, accelerated=False)
        noisy = [localization(runs, nd, ranged, loc_rounds, args.seed + 1) for nd in (1.0, 2.0)]
        rows.append(
            (
                label,
                f"{np.mean(r0 < 1e-3):.3f} (max {r0.max():.2g} of the extent; plain descent: "
                f"{np.mean(plain < 1e-3):.3f}; {loc_rounds} rounds)",
                f"error/extent {_stats(noisy[0], '%', 100)}",
                f"error/extent {_stats(noisy[1], '%', 100)}",
            )
        )
    for name, label in (
        ("formation-2d-bearing", "bearing-only formation (fig. 11a)"),
        ("formation-2d-range", "bearing + distance formation (fig. 11b)"),
    ):
        be, de, sc = formation(runs, 0.0, name, args.seed)
        ranged = name.endswith("range")
        ok = (be < 0.5) & ((de < 0.05) if ranged else True)
        extra = "" if ranged else f"; final scale min {sc.min():.2f}, median {np.median(sc):.2f}"
        cells = []
        for nd in (1.0, 2.0):
            b1, d1, _ = formation(runs, nd, name, args.seed + 1)
            cells.append(
                f"bearing {_stats(b1, ' deg')}"
                + (f"; distance {_stats(d1, ' m')}" if ranged else "")
            )
        rows.append((label, f"{np.mean(ok):.3f} (60 s{extra})", cells[0], cells[1]))
    for f, label in (
        (F_R, "rotations, f_R (eq. 15, b = 2)"),
        (F_R_PLAIN, "rotations, plain x^2/2"),
    ):
        r0 = rotations(runs, 0.0, f, rot_rounds, args.seed)
        cells = [
            f"{_stats(rotations(runs, nd, f, rot_rounds, args.seed + 1), ' deg')}"
            for nd in (1.0, 2.0)
        ]
        rows.append((label, f"{np.mean(r0 < 0.1):.3f} ({rot_rounds} rounds)", cells[0], cells[1]))
    print(f"{runs} random instances per problem, seed {args.seed}\n")
    print("| problem | noiseless: fraction at the global minimizer | 1 deg noise | 2 deg noise |")
    print("|---|---|---|---|")
    for r in rows:
        print("| " + " | ".join(r) + " |")
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
