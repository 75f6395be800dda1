"""Rounds the distributed eigen estimator needs from its start block, over many start streams.

Issue 27 (onboard footprint): the estimator's start block was drawn with ``numpy.random``
(6.8 MB resident for nine numbers per agent). Its first replacement (``random.Random`` draws
of the same unit size) failed tests that expect the estimate within 2% after 150 rounds:
whether an estimate gets there in time depends on the start. This runs the synchronous
reference network (:func:`onboard.estimation.distributed_eigen.run_rounds`) on the 4-agent
framework of ``tests/onboard/test_rigidity_layer.py`` from each start of ``--streams`` seeds
and prints, per kind of start, the round after which every agent's ``lambda_hat`` stays within
2% of the centralized ``lambda_8`` (paper 003 eq. 16):

* ``numpy-unit``: the ``numpy.random`` start of before (``default_rng([seed, i, 31])``);
* ``random-unit``: the same size from :func:`onboard.seeded.standard_normal` (the backed-out
  attempt, 7a50414);
* ``seeded``: today's :func:`onboard.seeded.eigen_start_block` (small, no ``numpy.random``).

``--exact`` also prints the exact Rayleigh-Ritz value of the iterated block (the whole
``M_w`` and trivial basis, no consensus) at a few rounds of the first stream: it is at
``lambda_8`` long before the consensus-averaged estimate (module docstring of
:mod:`onboard.seeded`).

Usage: ``python benchmarks/bench_eigen_start.py [--streams 20] [--rounds 400] [--exact]``.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import numpy as np

from onboard.core.config import build_config
from onboard.estimation import distributed_eigen as de
from onboard.graph import complete_graph
from onboard.rigidity.angle import weighted_angle_rigidity_eigenvalue
from onboard.rigidity.weights import SensingModel
from onboard.seeded import eigen_start_block, standard_normal

N = 4
P = np.array([[0.0, 0.0, -5.0], [3.0, 1.0, -5.5], [2.5, -2.0, -6.0], [4.0, 0.5, -4.0]])
YAW = np.arctan2(P.mean(axis=0)[1] - P[:, 1], P.mean(axis=0)[0] - P[:, 0])
TOLERANCE = 0.02
WITHIN = 150


def _setup() -> tuple[SensingModel, de.EigenGains, float]:
    edges = tuple((int(i), int(j)) for i, j in complete_graph(N))
    r = build_config(agent_id=0, n_agents=N, edges=edges, mode="rigidity-tracking").rigidity
    model = SensingModel(r.fov_deg, r.range_m)
    gains = de.EigenGains(
        columns=r.eigen_columns, step=r.eigen_step, k_t=r.eigen_k_t, k_n=r.eigen_k_n
    )
    lam = weighted_angle_rigidity_eigenvalue(P, YAW, complete_graph(N), model)[0]
    return model, gains, float(lam)


def _numpy_unit(seed: int, i: int, k: int) -> np.ndarray:
    return np.random.default_rng([seed, i, 31]).standard_normal((3, k))


def _random_unit(seed: int, i: int, k: int) -> np.ndarray:
    return standard_normal((seed, i, 31), (3, k))


STARTS: dict[str, Callable[[int, int, int], np.ndarray]] = {
    "numpy-unit": _numpy_unit,
    "random-unit": _random_unit,
    "seeded": eigen_start_block,
}


def rounds_to_converge(v0: np.ndarray, n_rounds: int) -> int | None:
    """First round after which every agent's estimate stays within :data:`TOLERANCE` of
    ``lambda_8`` (``None``: not within ``n_rounds``, or the iteration restarted)."""
    model, gains, lam = _setup()
    cand = [[j for j in range(N) if j != i] for i in range(N)]
    try:
        out, _ = de.run_rounds(P, YAW, cand, model, n_rounds, gains=gains, v0=v0)
    except ValueError:  # a restart: run_rounds cannot stack an empty consensus state
        return None
    bad = np.flatnonzero(~np.all(np.abs(out - lam) < TOLERANCE * lam, axis=1))
    first = 0 if len(bad) == 0 else int(bad[-1]) + 1
    return first if first < n_rounds else None


def exact_ritz(v0: np.ndarray, rounds: list[int]) -> None:
    """Print the exact smallest Ritz value of the block at ``rounds`` next to the estimates."""
    from onboard.rigidity.angle import weighted_angle_rigidity_matrix

    model, gains, lam = _setup()
    m_w = weighted_angle_rigidity_matrix(P, YAW, complete_graph(N), model)
    t = de.trivial_motion_basis(P)
    q_free = np.eye(3 * N) - t @ np.linalg.pinv(t)
    blocks: list[np.ndarray] = []
    step = de.DistributedEigenEstimator.step

    def recording(self: de.DistributedEigenEstimator, *args: object) -> None:
        blocks.append(self.v.copy())
        step(self, *args)  # type: ignore[arg-type]

    de.DistributedEigenEstimator.step = recording  # type: ignore[method-assign]
    try:
        cand = [[j for j in range(N) if j != i] for i in range(N)]
        out, _ = de.run_rounds(P, YAW, cand, model, max(rounds) + 1, gains=gains, v0=v0)
    finally:
        de.DistributedEigenEstimator.step = step  # type: ignore[method-assign]
    print(f"lambda_8 = {lam:.4f}; round: exact Ritz of V | consensus estimates of the agents")
    for r in rounds:
        v = np.concatenate(blocks[N * r : N * r + N])
        g = v.T @ q_free @ v
        w, u = np.linalg.eigh(g)
        half = u[:, w > 1e-12 * w[-1]] / np.sqrt(w[w > 1e-12 * w[-1]])
        theta = np.linalg.eigvalsh(half.T @ v.T @ m_w @ v @ half)
        print(f"{r:4d}: {theta[0]:.4f} | " + " ".join(f"{x:.4f}" for x in out[r]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--streams", type=int, default=20)
    ap.add_argument("--rounds", type=int, default=400)
    ap.add_argument("--exact", action="store_true")
    args = ap.parse_args()
    _, gains, lam = _setup()
    k = gains.columns
    print(f"{N} agents, lambda_8 = {lam:.4f}, k = {k}; rounds to {TOLERANCE:.0%} per stream")
    for name, draw in STARTS.items():
        got = [
            rounds_to_converge(np.stack([draw(s, i, k) for i in range(N)]), args.rounds)
            for s in range(args.streams)
        ]
        within = sum(r is not None and r <= WITHIN for r in got)
        done = [r for r in got if r is not None]
        print(
            f"{name:12s} within {WITHIN}: {within}/{args.streams}  "
            f"median {np.median(done) if done else float('nan'):.0f}  "
            f"max {max(done) if done else None}  not in {args.rounds}: {len(got) - len(done)}"
        )
        print("             " + " ".join("-" if r is None else str(r) for r in got))
    if args.exact:
        exact_ritz(np.stack([_numpy_unit(1, i, k) for i in range(N)]), [5, 20, 40, 80, 140, 160])


if __name__ == "__main__":
    main()
