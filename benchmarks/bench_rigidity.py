"""Timing of the angle-rigidity core (paper 003): R_A, the rigidity eigenvalue, the weighted gradient.

Scenes: N agents uniform in a cube whose side grows like N^(1/3) (constant density), each camera
yawed toward the barycenter, each agent measuring its 8 nearest neighbours (about 8 * 7 / 2 = 28
angles per agent). Reports median times over repeats and the growth ratio against N = 10,
measured in the same run. Run as ``python benchmarks/bench_rigidity.py``.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np

from onboard.geometry import FloatArray, IntArray
from onboard.graph import angle_set_with_rows, normalize_edges
from onboard.rigidity.angle import (
    angle_rigidity_eigenvalue,
    angle_rigidity_matrix,
    weighted_eigenvalue_gradient,
)
from onboard.rigidity.weights import SensingModel

OUT_DEGREE = 8
SIZES = (10, 50, 200)
TARGET_MS = 20.0  # eigenvalue + gradient at N = 50


def scene(n: int, seed: int) -> tuple[FloatArray, FloatArray, IntArray]:
    """Seeded positions, yaws toward the barycenter and 8-nearest-neighbour out-edges."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(0.0, 4.0 * n ** (1.0 / 3.0), size=(n, 3))
    to_center = p.mean(axis=0) - p
    yaw = np.arctan2(to_center[:, 1], to_center[:, 0])
    dist = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=-1)
    np.fill_diagonal(dist, np.inf)
    nearest = np.argsort(dist, axis=1)[:, : min(OUT_DEGREE, n - 1)]
    edges = np.stack([np.repeat(np.arange(n), nearest.shape[1]), nearest.ravel()], axis=1)
    return p, yaw, normalize_edges(edges)


def median_ms(fun: Callable[[], object], repeats: int) -> float:
    fun()  # warm-up
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        fun()
        samples.append(time.perf_counter() - start)
    return 1e3 * float(np.median(samples))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=21)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    model = SensingModel(fov_deg=150.0, range_m=20.0)

    rows = []
    for n in SIZES:
        p, yaw, edges = scene(n, args.seed)
        angles, _, _ = angle_set_with_rows(edges)
        t_angles = median_ms(lambda e=edges: angle_set_with_rows(e), args.repeats)
        t_matrix = median_ms(lambda p=p, a=angles: angle_rigidity_matrix(p, a), args.repeats)
        t_eig = median_ms(lambda p=p, a=angles: angle_rigidity_eigenvalue(p, a), args.repeats)
        t_grad = median_ms(
            lambda p=p, y=yaw, e=edges: weighted_eigenvalue_gradient(p, y, e, model), args.repeats
        )
        rows.append((n, len(edges), len(angles), t_angles, t_matrix, t_eig, t_grad))

    header = "   N     E      A   angle set ms   R_A ms   eigenvalue ms   weighted eig+grad ms"
    print(header)
    base = rows[0]
    for n, e, a, *times in rows:
        cells = [f"{t:8.3f} (x{t / b:5.1f})" for t, b in zip(times, base[3:], strict=True)]
        print(f"{n:4d} {e:5d} {a:6d}  " + "  ".join(cells))
    t50 = next(r[-1] for r in rows if r[0] == 50)
    verdict = "meets" if t50 < TARGET_MS else "misses"
    print(
        f"weighted eigenvalue + gradient at N = 50: {t50:.2f} ms ({verdict} the {TARGET_MS} ms target)"
    )
    print("ratios are against N = 10 in this run; A grows like N (28 angles per agent), the")
    print("dense eigen-solve like (3N)^3 times the fraction of eigenpairs kept.")


if __name__ == "__main__":
    main()
