"""Paper 002's yaw-only rotation estimation, measured (issue 25; docs/distributed.md).

The flight stack's case of eq. 13-15: relative yaws from reciprocal levelled bearings
(:func:`onboard.distributed.yaw.relative_yaw_from_reciprocal`, paper 002 fig. 6), then the
gradient flow on the yaws (:func:`onboard.distributed.solvers.estimate_yaws`, SO(2) with eq. 15's
``f_R``, ``b = 2``, against the plain ``x^2 / 2``). ``--runs`` (default 200) random instances,
all solved at once as one disjoint graph (the flow is per edge):

* N = 10 agents, ring graph with hops 1 and 3 as reciprocal pairs (20 pairs, one relative yaw
  each), true yaws and initial estimates uniform on the circle;
* two layouts: ``cube``, positions uniform in a 10 m cube (the other paper 002 benchmarks'), and
  ``flat``, a 10 m square with 2 m of altitude spread (a formation at one flight level);
* bearings in the levelled frames, optionally with isotropic noise of RMS angle 1 or 2 degrees
  (``sigma / sqrt 2`` per tangent axis); pairs with a bearing within ``min_horizontal`` of the
  vertical are dropped (counted);
* error: largest yaw error after the best global yaw; reached = below 0.1 degree (noiseless).

Run as ``python benchmarks/bench_paper002_yaw.py [--runs 200] [--rounds 3000] [--quick]``; prints a
markdown table. Not a timing benchmark.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from onboard.distributed.reshaping import F_R, F_R_PLAIN, ReshapeR
from onboard.distributed.solvers import estimate_yaws
from onboard.distributed.yaw import relative_yaw_from_reciprocal, relative_yaw_std_rad
from onboard.geometry import rot_z, wrap_angle

N = 10
HOPS = (1, 3)


def pairs(n: int = N) -> np.ndarray:
    """Reciprocal pairs ``(i, j)``, ``i < j``, of the ring with hops 1 and 3: ``(20, 2)``."""
    und = {tuple(sorted((i, (i + h) % n))) for h in HOPS for i in range(n)}
    return np.array(sorted(und), dtype=np.int64)


def _noisy(b: np.ndarray, sigma_rad: float, rng: np.random.Generator) -> np.ndarray:
    if sigma_rad <= 0:
        return b
    nz = rng.normal(0, sigma_rad / math.sqrt(2), b.shape)
    nz -= np.sum(nz * b, axis=1)[:, None] * b
    out = b + nz
    return out / np.linalg.norm(out, axis=1)[:, None]


def _connected(n: int, e: np.ndarray) -> bool:
    seen, stack = {0}, [0]
    adj: dict[int, list[int]] = {k: [] for k in range(n)}
    for i, j in e.tolist():
        adj[i].append(j)
        adj[j].append(i)
    while stack:
        for j in adj[stack.pop()]:
            if j not in seen:
                seen.add(j)
                stack.append(j)
    return len(seen) == n


def instance_set(runs: int, layout: str, noise_deg: float, seed: int) -> dict[str, np.ndarray]:
    """Truth, levelled bearings and relative yaws of ``runs`` instances (one disjoint graph)."""
    rng = np.random.default_rng(seed)
    e1 = pairs()
    e = np.concatenate([e1 + k * N for k in range(runs)])
    if layout == "cube":
        p = rng.uniform(-5, 5, (runs * N, 3))
    else:
        p = np.c_[rng.uniform(-5, 5, (runs * N, 2)), rng.uniform(-1, 1, runs * N)]
    psi = rng.uniform(-np.pi, np.pi, runs * N)
    b = p[e[:, 1]] - p[e[:, 0]]
    b /= np.linalg.norm(b, axis=1)[:, None]
    sig = math.radians(noise_deg)
    bij = _noisy(np.einsum("eba,eb->ea", rot_z(psi[e[:, 0]]), b), sig, rng)
    bji = _noisy(np.einsum("eba,eb->ea", rot_z(psi[e[:, 1]]), -b), sig, rng)
    ry = relative_yaw_from_reciprocal(bij, bji)
    truth = wrap_angle(psi[e[:, 1]] - psi[e[:, 0]])
    return {
        "edges": e,
        "psi": psi,
        "psi0": rng.uniform(-np.pi, np.pi, runs * N),
        "meas": ry.psi_rad,
        "usable": ry.usable,
        "rel_err": wrap_angle(ry.psi_rad - truth),
        "pred_std": relative_yaw_std_rad(bij, bji, sig),
    }


def solve(inst: dict[str, np.ndarray], runs: int, f: ReshapeR, rounds: int) -> np.ndarray:
    """Largest yaw error (deg) per instance after the global alignment (nan: disconnected)."""
    ok = inst["usable"]
    e = inst["edges"][ok]
    res = estimate_yaws(e, inst["meas"][ok], inst["psi0"], rounds, f)
    out = np.empty(runs)
    for k in range(runs):
        s = slice(k * N, (k + 1) * N)
        ek = e[(e[:, 0] >= k * N) & (e[:, 0] < (k + 1) * N)] - k * N
        if not _connected(N, ek):
            out[k] = np.nan
            continue
        d = inst["psi"][s] - res.psi_rad[s]
        g = math.atan2(np.sin(d).sum(), np.cos(d).sum())
        out[k] = np.degrees(np.abs(wrap_angle(res.psi_rad[s] + g - inst["psi"][s])).max())
    return out


def _stats(x: np.ndarray) -> str:
    x = x[np.isfinite(x)]
    q = np.percentile(x, [50, 95])
    return f"median {q[0]:.3g}, p95 {q[1]:.3g}, max {x.max():.3g}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--rounds", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="20 runs, 500 rounds")
    args = ap.parse_args()
    runs, rounds = (20, 500) if args.quick else (args.runs, args.rounds)
    t0 = time.perf_counter()
    print(f"{runs} random instances per row, N = {N}, 20 reciprocal pairs, {rounds} rounds\n")
    print(
        "| layout | cost | noiseless: reached (< 0.1 deg) | 1 deg bearing noise: "
        "yaw error (deg) | 2 deg bearing noise: yaw error (deg) |"
    )
    print("|---|---|---|---|---|")
    notes = []
    for layout in ("cube", "flat"):
        clean = instance_set(runs, layout, 0.0, args.seed)
        noisy = {nd: instance_set(runs, layout, nd, args.seed + 1) for nd in (1.0, 2.0)}
        dropped = int(np.sum(~clean["usable"]))
        for f, label in ((F_R, "f_R (eq. 15, b = 2)"), (F_R_PLAIN, "plain x^2/2")):
            r0 = solve(clean, runs, f, rounds)
            valid = np.isfinite(r0)
            cells = [_stats(solve(noisy[nd], runs, f, rounds)) for nd in (1.0, 2.0)]
            reached = f"{np.mean(r0[valid] < 0.1):.3f} (max {np.nanmax(r0):.2g} deg)"
            if not valid.all():
                reached += f", {int(np.sum(~valid))} disconnected left out"
            print(f"| {layout} | {label} | {reached} | {cells[0]} | {cells[1]} |")
        for nd, inst in noisy.items():
            u = inst["usable"]
            rms = math.degrees(float(np.sqrt(np.mean(inst["rel_err"][u] ** 2))))
            pred = math.degrees(float(np.sqrt(np.mean(inst["pred_std"][u] ** 2))))
            notes.append(
                f"{layout}, {nd:g} deg: relative yaw RMS error {rms:.3g} deg "
                f"(first-order prediction {pred:.3g} deg), max "
                f"{math.degrees(float(np.abs(inst['rel_err'][u]).max())):.3g} deg"
            )
        notes.append(f"{layout}: {dropped} of {len(clean['usable'])} pairs near vertical, dropped")
    print()
    for n in notes:
        print(f"- {n}")
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
