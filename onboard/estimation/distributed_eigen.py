"""Distributed estimation of the weighted angle-rigidity eigenvalue and eigenvector.

No agent sees the whole framework, yet the rigidity controller of paper 003 (eq. 21-23) needs
the rigidity eigenvalue ``lambda`` (the 8th smallest of ``M_w = R_A^T W R_A`` in 3-D, eq. 16)
and each agent's 3-vector ``v_i`` of its unit eigenvector. This module estimates both with
neighbour messages only, following the decentralized power iteration of Yang et al. 2010
("Decentralized estimation and control of graph connectivity", for the Laplacian) as extended
to rigidity matrices by Zelazo et al. 2015 ("Decentralized rigidity maintenance control with
range measurements") and Schiano et al. 2017 (bearing rigidity):

    ``v' = -k_m M_w v - k_t P_T v - k_n (|v|^2 / N - 1) v``,

where ``P_T`` is the orthogonal projector on the known trivial motions (eq. 4: 3 translations,
3 rotations, 1 scaling). On the complement of the trivial space the slowest mode of
``-k_m M_w`` is the rigidity eigenvector; the ``k_t`` term deflates the 7 trivial modes (their
eigenvalue 0 would otherwise win) and the ``k_n`` term keeps ``v`` from vanishing. At the
equilibrium ``v`` is a rigidity eigenvector with ``|v|^2 / N = 1 - k_m lambda / k_n`` (needs
``k_n > k_m lambda`` and ``k_t > k_m lambda``).

**What is local.** ``M_w = sum_a W_a r_a r_a^T`` and an angle ``a = (i, j, k)`` involves only
``i`` and the two neighbours it sees, so agent ``i`` computes ``M_i v`` over its own angles
(:func:`local_weighted_gram`) from its neighbours' ``v_j``, keeps its block and sends the blocks
of ``j, k`` to them: ``(M_w v)_i`` = own block + received blocks. The trivial basis of agent
``i`` is a ``3 x 7`` block ``T_i = [I, -hat(p_i), p_i]`` (:func:`trivial_motion_block`), so
``P_T v = T (T^T T)^{-1} T^T v`` needs the two network sums ``sum_i T_i^T v_i`` (7) and
``sum_i T_i^T T_i`` (28 distinct entries): both come from PI average consensus (Freeman, Yang,
Lynch 2006; :mod:`onboard.estimation.consensus`), and their ratio needs no ``N``. So does the
Rayleigh quotient ``lambda = (v^T M_w v) / (v^T v)`` from the averages of ``v_i . (M_w v)_i`` and
``|v_i|^2``: it is second-order accurate in the eigenvector error, and a mixture of
near-degenerate eigenvectors gives a value between them.

**Gradient.** With ``v`` fixed, ``d lambda/dx = v^T (dM_w/dx) v / |v|^2`` (paper 003 eq. 21);
each agent evaluates the derivative of its own angles' part of ``v^T M_w v``
(:func:`local_gram_and_form_gradient`), keeps the blocks of ``p_i, psi_i`` and
sends those of ``p_j, p_k``.

Everything here works in the team's estimated frame (angle localization): positions,
yaws and the trivial motions are the estimated ones.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from onboard.estimation.consensus import PIConsensus
from onboard.geometry import FloatArray, IntArray, hat
from onboard.rigidity.angle import (
    weighted_angle_rigidity_matrix,
    weighted_gram_and_form_gradient,
)
from onboard.rigidity.weights import SensingModel

N_TRIVIAL = 7
_TRIU = np.triu_indices(N_TRIVIAL)
MAX_BLOCK_NORM2 = 1e4
"""An agent's ``|v_i|^2`` above this (the equilibrium is below 1 on average) means divergence."""
N_CONSENSUS = N_TRIVIAL + len(_TRIU[0]) + 2
"""Averaged quantities: ``T_i^T v_i`` (7), ``T_i^T T_i`` (28), ``|v_i|^2``, ``v_i . (M v)_i``."""


def trivial_motion_block(p_ned: ArrayLike) -> FloatArray:
    """Agent ``i``'s rows ``T_i = [I_3, -hat(p_i), p_i]`` of the trivial-motion basis ``(3, 7)``.

    Columns: translations along ``e_m``, rotations about ``e_m`` (``e_m x p_i = -hat(p_i) e_m``)
    and scaling (paper 003 eq. 4). The span does not depend on the origin of ``p``.
    """
    p = np.asarray(p_ned, dtype=float)
    return np.hstack([np.eye(3), -hat(p), p[:, None]])


def trivial_motion_basis(p_ned: ArrayLike) -> FloatArray:
    """Stacked ``T`` ``(3N, 7)`` for a whole framework (agent-major rows)."""
    p = np.asarray(p_ned, dtype=float).reshape(-1, 3)
    return np.vstack([trivial_motion_block(q) for q in p])


def _star(
    p_own_ned: ArrayLike, yaw_own_rad: float, p_seen_ned: ArrayLike
) -> tuple[FloatArray, FloatArray, IntArray]:
    """Positions, yaws and edges of agent ``i``'s star: ``i`` is vertex 0, candidate ``m`` is
    vertex ``m + 1``; edges ``(0, m + 1)``. Only vertex 0's yaw matters."""
    p_loc = np.vstack([np.asarray(p_own_ned, dtype=float), np.asarray(p_seen_ned, dtype=float)])
    m = len(p_loc) - 1
    edges = np.stack([np.zeros(m, dtype=np.int64), np.arange(1, m + 1)], axis=1)
    yaw = np.zeros(m + 1)
    yaw[0] = yaw_own_rad
    return p_loc, yaw, edges


def local_weighted_gram(
    p_own_ned: ArrayLike, yaw_own_rad: float, p_seen_ned: ArrayLike, model: SensingModel
) -> FloatArray:
    """``sum_{a at i} W_a r_a r_a^T`` over the angles agent ``i`` forms with ``M`` candidates.

    Indices: agent ``i`` is block 0, candidate ``m`` is block ``m + 1``; shape
    ``(3 (M + 1), 3 (M + 1))``. Candidates outside range or view get weight 0 (eq. 16-18).
    """
    p_loc, yaw, edges = _star(p_own_ned, yaw_own_rad, p_seen_ned)
    if len(edges) < 2:
        return np.zeros((3 * len(p_loc), 3 * len(p_loc)))
    return weighted_angle_rigidity_matrix(p_loc, yaw, edges, model)


def local_gram_and_form_gradient(
    p_own_ned: ArrayLike,
    yaw_own_rad: float,
    p_seen_ned: ArrayLike,
    v_loc: ArrayLike,
    model: SensingModel,
) -> tuple[FloatArray, float, FloatArray, float]:
    """Agent ``i``'s local gram (:func:`local_weighted_gram`), its angles' part of ``v^T M_w v``
    and that part's gradient (eq. 21 with ``v`` fixed), from one evaluation.

    ``v_loc`` is ``(M + 1, 3)`` (own block first). Returns ``(gram, value, grad_p (M + 1, 3),
    d/dpsi_i)``: row 0 of ``grad_p`` is ``i``'s own block, row ``m + 1`` goes to candidate ``m``.
    """
    p_loc, yaw, edges = _star(p_own_ned, yaw_own_rad, p_seen_ned)
    if len(edges) < 2:
        k = len(p_loc)
        return np.zeros((3 * k, 3 * k)), 0.0, np.zeros((k, 3)), 0.0
    gram, value, grad_p, grad_yaw = weighted_gram_and_form_gradient(p_loc, yaw, edges, model, v_loc)
    return gram, value, grad_p, float(grad_yaw[0])


def consensus_input(t_i: FloatArray, v_i: FloatArray, mv_i: FloatArray) -> list[float]:
    """Agent ``i``'s terms of the averaged quantities (see :data:`N_CONSENSUS`)."""
    gram = t_i.T @ t_i
    return [*(t_i.T @ v_i).tolist(), *gram[_TRIU].tolist(), float(v_i @ v_i), float(v_i @ mv_i)]


@dataclass(frozen=True)
class EigenGains:
    """Gains of the estimator (module docstring). Euler is stable for
    ``dt (k_m lambda_max + k_t) < 2``; the consensus needs ``dt (gamma + k_p mu_max) < 1``."""

    k_m: float = 8.0
    k_t: float = 10.0
    k_n: float = 10.0
    gamma: float = 20.0
    k_p: float = 8.0
    k_i: float = 8.0
    momentum: float = 0.0
    """Heavy-ball term ``momentum (v_k - v_{k-1})`` added to each Euler step (Polyak): speeds up
    the slow mode ``k_m (lambda_9 - lambda_8)`` when the two smallest eigenvalues are close.
    Experimental, off by default: 0.5 sped up a fixed network 5x but destabilized the agent
    core's closed loop on some starts."""


@dataclass(slots=True)
class DistributedEigenEstimator:
    """Agent ``i``'s share of the distributed power iteration (module docstring)."""

    v: FloatArray
    gains: EigenGains = field(default_factory=EigenGains)
    consensus: PIConsensus | None = None
    lambda_hat: float = 0.0
    norm2_avg: float = 1.0
    """Estimate of ``|v|^2 / N`` (the network average of ``|v_i|^2``)."""
    v_prev: FloatArray = field(default_factory=lambda: np.zeros(3))
    restarts: int = 0
    """Times the iteration diverged and was restarted (see :data:`MAX_BLOCK_NORM2`)."""

    @classmethod
    def start(
        cls, seed: int, agent_id: int, gains: EigenGains | None = None
    ) -> DistributedEigenEstimator:
        """A random unit-size start (seeded per agent)."""
        rng = np.random.default_rng([seed, agent_id, 31])
        v = rng.standard_normal(3)
        return cls(v=v, gains=gains or EigenGains(), v_prev=v.copy())

    def step(
        self,
        dt: float,
        t_i: FloatArray,
        mv_i: FloatArray,
        neighbours: Sequence[tuple[Sequence[float], Sequence[float]]],
    ) -> list[float]:
        """Advance by ``dt`` given ``T_i``, the assembled ``(M_w v)_i`` and the neighbours'
        consensus states ``(x_j, z_j)``; returns the new consensus state ``x`` to share."""
        g = self.gains
        phi = consensus_input(t_i, self.v, mv_i)
        if self.consensus is None:
            self.consensus = PIConsensus(list(phi), gamma=g.gamma, k_p=g.k_p, k_i=g.k_i)
        nbrs = [(x, z) for x, z in neighbours if len(x) == len(z) == N_CONSENSUS]
        x = np.asarray(self.consensus.step(dt, phi, nbrs))
        if not np.all(np.isfinite(x)):
            x = np.asarray(phi)
            self.consensus = None
        c = x[:N_TRIVIAL]
        gram = np.zeros((N_TRIVIAL, N_TRIVIAL))
        gram[_TRIU] = x[N_TRIVIAL : N_CONSENSUS - 2]
        gram = gram + np.triu(gram, 1).T
        norm2, quad = x[-2], x[-1]
        try:
            coef = np.linalg.solve(gram, c)
            trivial = t_i @ coef
        except np.linalg.LinAlgError:
            trivial = np.zeros(3)
        if norm2 > 1e-9:
            self.lambda_hat = float(max(quad / norm2, 0.0))
            self.norm2_avg = float(norm2)
        dv = -g.k_m * mv_i - g.k_t * trivial - g.k_n * (norm2 - 1.0) * self.v
        v_new = self.v + dt * dv + g.momentum * (self.v - self.v_prev)
        self.v_prev = self.v
        if not np.all(np.isfinite(v_new)) or float(v_new @ v_new) > MAX_BLOCK_NORM2:
            # diverging (a step too large for the current spectrum): restart from a fresh
            # direction rather than feed the controller garbage
            self.restarts += 1
            v_new = np.random.default_rng(self.restarts).standard_normal(3)
            self.v_prev = v_new
            self.consensus = None
        self.v = v_new
        return x.tolist()

    @property
    def z(self) -> list[float]:
        """Integral state of the consensus (shared with neighbours)."""
        return [] if self.consensus is None else self.consensus.z


def run_rounds(
    p_ned: ArrayLike,
    yaw_rad: ArrayLike,
    candidates: Sequence[Sequence[int]],
    model: SensingModel,
    n_rounds: int,
    dt: float = 0.01,
    gains: EigenGains | None = None,
    seed: int = 0,
    v0: ArrayLike | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Synchronous reference network: every agent runs :class:`DistributedEigenEstimator`,
    exchanging one message per round with its communication neighbours (``candidates[i]``:
    whom ``i`` may see; communication runs both ways). Messages computed in round ``k`` are
    used in round ``k + 1``. Returns ``(lambda_hat (rounds, N), v (N, 3))``. For tests and
    benchmarks: the agent core runs the same estimator with real payloads."""
    p = np.asarray(p_ned, dtype=float)
    yaw = np.asarray(yaw_rad, dtype=float)
    n = len(p)
    comm = [set(c) for c in candidates]
    for i in range(n):
        for j in candidates[i]:
            comm[j].add(i)
    est = [DistributedEigenEstimator.start(seed, i, gains) for i in range(n)]
    if v0 is not None:
        for i, e in enumerate(est):
            e.v = np.asarray(v0, dtype=float).reshape(n, 3)[i].copy()
            e.v_prev = e.v.copy()
    grams = [local_weighted_gram(p[i], yaw[i], p[list(candidates[i])], model) for i in range(n)]
    blocks = [trivial_motion_block(p[i]) for i in range(n)]
    v_shared = [e.v.copy() for e in est]
    contrib: dict[tuple[int, int], FloatArray] = {}
    states: list[tuple[list[float], list[float]] | None] = [None] * n
    out = np.zeros((n_rounds, n))
    for k in range(n_rounds):
        new_contrib: dict[tuple[int, int], FloatArray] = {}
        new_states: list[tuple[list[float], list[float]] | None] = [None] * n
        for i, e in enumerate(est):
            cand = list(candidates[i])
            v_loc = np.concatenate([e.v, *[v_shared[j] for j in cand]])
            mv = (grams[i] @ v_loc).reshape(-1, 3)
            for m, j in enumerate(cand):
                new_contrib[(i, j)] = mv[m + 1]
            mv_i = mv[0] + sum((contrib[(j, i)] for j in comm[i] if (j, i) in contrib), np.zeros(3))
            nbrs = [s for j in comm[i] if (s := states[j]) is not None]
            x = e.step(dt, blocks[i], mv_i, nbrs)
            new_states[i] = (x, list(e.z))
            out[k, i] = e.lambda_hat
        contrib = new_contrib
        states = new_states
        v_shared = [e.v.copy() for e in est]
    return out, np.array([e.v for e in est])
