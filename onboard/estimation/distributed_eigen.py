"""Distributed estimation of the weighted angle-rigidity eigenvalue and eigenvector, by a
subspace power iteration with Rayleigh-Ritz, counted in message rounds.

No agent sees the whole framework, yet the rigidity controller of paper 003 (eq. 21-23) needs
the rigidity eigenvalue ``lambda`` (the 8th smallest of ``M_w = R_A^T W R_A`` in 3-D, eq. 16)
and each agent's 3-vector of its eigenvector. The decentralized power iteration of Yang et al.
2010 (Laplacian), extended to rigidity matrices by Zelazo et al. 2015 (distances) and Schiano
et al. 2017 (bearings), tracks *one* vector. When the two smallest non-trivial eigenvalues
come close and then cross (a robot turning away takes a different mode of the framework down)
one vector needs many rounds to turn into the new eigenvector, and its Rayleigh quotient stays
at the old, higher value meanwhile: the controller misses the drop. Here every agent holds a
block ``V_i`` ``(3, k)`` of ``k`` vectors (default 3) and the network runs, per message round,

    ``V+ = V - alpha M_w V - k_t P_T V - (k_n / 2) V (Gbar - I)``,

* ``alpha = step / sbar``, ``sbar`` the network maximum of the weighted degrees
  (:func:`onboard.estimation.star_rigidity.weighted_degree`), an upper bound on
  ``lambda_max(M_w)``: ``I - alpha M_w`` has its eigenvalues in ``[1 - step, 1]`` whatever the
  size of the team, so the smallest non-trivial modes win and the step scales with the graph;
* ``P_T`` the orthogonal projector on the 7 trivial motions (eq. 4: 3 translations,
  3 rotations, 1 scaling; their eigenvalue 0 would otherwise win), ``k_t`` per round;
* ``Gbar = V^T V / N``: the last term keeps the ``k`` columns near-orthonormal (they would
  otherwise all turn into the dominant one), ``k_n`` per round.

The span of ``V`` converges to the ``k`` smallest non-trivial modes at the rate
``alpha (lambda_{8+k} - lambda_8)`` per round (the gap to the first mode *not* tracked, not to
the next one), and the estimate is the smallest **Ritz value** of that span: with
``H = V^T M_w V / N`` and ``G' = V^T (I - P_T) V / N`` (trivial parts removed, so they cannot
fake a small eigenvalue), ``lambda_hat = min theta``, ``H c = theta G' c``. A mode crossing
inside the span moves the Ritz value at once. Its Ritz vector ``y = (I - P_T) V c`` (scaled so
``|y|^2 = N``) gives the gradient ``d lambda/dx = y^T (dM_w/dx) y / N`` (paper 003 eq. 21);
the other Ritz pairs give the same for the next modes, which the rigidity layer blends into the
gradient of a smooth minimum (:mod:`onboard.core.rigidity`).

**What is local.** ``M_w = sum_a W_a r_a r_a^T`` and an angle ``a = (i, j, k)`` involves only
``i`` and the two neighbours it sees: agent ``i`` evaluates its angles' part of ``M_w V``
(:func:`onboard.estimation.star_rigidity.weighted_matvec`) from its neighbours' ``V_j``, keeps
its block and sends the blocks of ``j, k`` to them. ``T_i = [I, -hat(p_i), p_i]`` (``3 x 7``)
is agent ``i``'s rows of the trivial basis. The network averages ``T^T V / N`` (``7 k``),
``T^T T / N`` (28), ``V^T V / N`` and ``V^T M_w V / N`` (``k (k + 1) / 2`` each) come from PI
average consensus with Metropolis weights, counted in rounds
(:mod:`onboard.estimation.round_consensus`); ``sbar`` from a forgetting max consensus. Agent
``i`` computes its neighbours' Ritz blocks ``y_j = (V_j - T_j T^+ V) c`` itself from their
``V_j`` and estimated positions.

Everything here works in the team's estimated frame (angle localization): positions, yaws and
the trivial motions are the estimated ones.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache

import numpy as np
from numpy.typing import ArrayLike

from onboard.estimation.round_consensus import (
    RoundGains,
    max_round,
    metropolis_weights,
    pi_round,
)
from onboard.estimation.star_rigidity import Star, star, weighted_degree, weighted_matvec
from onboard.geometry import FloatArray, IntArray
from onboard.rigidity.weights import SensingModel
from onboard.seeded import eigen_restart_block, eigen_start_block

N_TRIVIAL = 7
_TRIU_T = np.triu_indices(N_TRIVIAL)
_N_TRIU_T = len(_TRIU_T[0])
MAX_BLOCK_NORM2 = 1e4
"""An agent's ``|V_i|^2`` above this (the equilibrium is about ``k``) means divergence."""
TT_RCOND = 1e-9
"""``T^T T / N`` (symmetric, positive semi-definite) whose eigenvalues span more than this ratio
is singular: fewer than three agents
are in the average yet (an agent's first round averages its own ``T_i^T T_i``, of rank 3), and
the trivial coefficients are not defined. Solved anyway, its round-off-sized pivots gave
coefficients of any size, which kicked ``V`` by ``k_t T_i coef`` (and made the first rounds
depend on the last bit of ``T_i``)."""
RITZ_RCOND = 1e-6
"""Directions of ``G'`` below this fraction of its largest eigenvalue are left out of the Ritz
problem (the columns of ``V`` have (nearly) collapsed onto each other or onto trivial motions)."""


def trivial_motion_block(p_ned: ArrayLike) -> FloatArray:
    """Agent ``i``'s rows ``T_i = [I_3, -hat(p_i), p_i]`` of the trivial-motion basis ``(3, 7)``.

    Columns: translations along ``e_m``, rotations about ``e_m`` (``e_m x p_i = -hat(p_i) e_m``)
    and scaling (paper 003 eq. 4). The span does not depend on the origin of ``p``.
    """
    return trivial_motion_blocks(np.asarray(p_ned, dtype=float).reshape(1, 3))[0]


def trivial_motion_blocks(p_ned: ArrayLike) -> FloatArray:
    """:func:`trivial_motion_block` of every row of ``p_ned`` ``(K, 3)``: ``(K, 3, 7)``."""
    p = np.asarray(p_ned, dtype=float).reshape(-1, 3)
    # entries 0, 1, x, y, z, -x, -y, -z of each row, placed by _T_LAYOUT:
    # [I_3 | -hat(p) | p] with -hat(p) = [[0, z, -y], [-z, 0, x], [y, -x, 0]]
    values = np.zeros((len(p), 8))
    values[:, 1] = 1.0
    values[:, 2:5] = p
    values[:, 5:] = -p
    return values[:, _T_LAYOUT]


_T_LAYOUT = np.array(
    [
        [1, 0, 0, 0, 4, 6, 2],
        [0, 1, 0, 7, 0, 2, 3],
        [0, 0, 1, 3, 5, 0, 4],
    ]
)
"""Where :func:`trivial_motion_blocks` reads each entry of ``T_i`` from ``(0, 1, p, -p)``."""


def trivial_motion_basis(p_ned: ArrayLike) -> FloatArray:
    """Stacked ``T`` ``(3N, 7)`` for a whole framework (agent-major rows)."""
    return trivial_motion_blocks(p_ned).reshape(-1, N_TRIVIAL)


def n_consensus(k: int) -> int:
    """Length of the averaged vector for ``k`` columns: ``T^T V`` (``7 k``), ``T^T T`` (28),
    ``V^T V`` and ``V^T M V`` (``k (k + 1) / 2`` each)."""
    return N_TRIVIAL * k + _N_TRIU_T + k * (k + 1)


@cache
def _triu(k: int) -> tuple[IntArray, IntArray]:
    """Upper-triangle rows and columns (the packed order of the averaged matrices)."""
    r, c = np.triu_indices(k)
    return r, c


@cache
def _sym_index(k: int) -> IntArray:
    """``(k, k)`` positions in the packed upper triangle of every entry of the symmetric matrix."""
    r, c = _triu(k)
    out = np.zeros((k, k), dtype=np.int64)
    out[r, c] = np.arange(len(r))
    out[c, r] = np.arange(len(r))
    return out


def _sym(triu: FloatArray, k: int) -> FloatArray:
    """The symmetric ``(k, k)`` matrix from its packed upper triangle (row-major)."""
    return triu[_sym_index(k)]


@cache
def _eye(k: int) -> FloatArray:
    """``I_k`` (read-only, shared by every round)."""
    eye = np.eye(k)
    eye.flags.writeable = False
    return eye


def consensus_input(t_i: FloatArray, v_i: FloatArray, mv_i: FloatArray) -> FloatArray:
    """Agent ``i``'s terms of the averaged quantities (:func:`n_consensus`), from ``T_i``
    ``(3, 7)``, ``V_i`` and ``(M_w V)_i`` ``(3, k)``."""
    iu = _triu(v_i.shape[1])
    vmv = v_i.T @ mv_i
    return np.concatenate(
        [
            (t_i.T @ v_i).ravel(),
            (t_i.T @ t_i)[_TRIU_T],
            (v_i.T @ v_i)[iu],
            (0.5 * (vmv + vmv.T))[iu],
        ]
    )


@dataclass(frozen=True)
class Averages:
    """The network averages one agent's consensus holds, unpacked (module docstring)."""

    tv: FloatArray  # T^T V / N (7, k)
    tt: FloatArray  # T^T T / N (7, 7)
    vv: FloatArray  # V^T V / N (k, k)
    vmv: FloatArray  # V^T M V / N (k, k)

    @classmethod
    def unpack(cls, x: FloatArray, k: int) -> Averages:
        a = N_TRIVIAL * k
        b = a + _N_TRIU_T
        c = b + k * (k + 1) // 2
        return cls(
            x[:a].reshape(N_TRIVIAL, k), _sym(x[a:b], N_TRIVIAL), _sym(x[b:c], k), _sym(x[c:], k)
        )


def _symmetric_eigh(m: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Eigenvalues ascending and eigenvectors of a finite symmetric ``m`` (LAPACK ``?syevd``).

    numpy's own gufunc when this numpy has it: these are 3x3 and 7x7 problems, where the checks
    of ``numpy.linalg.eigh`` cost three times the work (1.4 against 4.2 us on this machine).
    """
    return _EIGH_LO(m)


def _public_eigh(m: FloatArray) -> tuple[FloatArray, FloatArray]:
    vals, vecs = np.linalg.eigh(m)
    return vals, vecs


try:  # numpy's private gufunc behind numpy.linalg.eigh (numpy >= 1.8); the public call otherwise
    from numpy.linalg._umath_linalg import eigh_lo as _EIGH_LO
except ImportError:  # pragma: no cover - a numpy without it
    _EIGH_LO = _public_eigh


def ritz(avg: Averages) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Rayleigh-Ritz on the span of ``V`` with trivial motions removed.

    Returns ``(theta (r,), c (k, r), coef (7, k))``: Ritz values ascending, coefficient vectors
    with ``c^T G' c = I`` and the trivial coefficients ``coef = (T^T T)^{-1} T^T V`` (so
    ``P_T V`` has blocks ``T_i coef``). ``r <= k`` drops ill-conditioned directions.

    numpy only (no SciPy on the daemon's import path, issue 27): ``T^T T`` is symmetric
    positive semi-definite, so its eigendecomposition both tests its conditioning
    (:data:`TT_RCOND`) and solves for ``coef``.
    """
    k = avg.vv.shape[0]
    empty = np.zeros(0), np.zeros((k, 0))
    coef = np.zeros((N_TRIVIAL, k))
    if np.isfinite(avg.tt).all() and np.isfinite(avg.tv).all():
        ev_t, u_t = _symmetric_eigh(avg.tt)
        if ev_t[0] > TT_RCOND * ev_t[-1]:
            coef = (u_t / ev_t) @ (u_t.T @ avg.tv)
    g_prime = avg.vv - avg.tv.T @ coef  # G' (symmetric)
    if not (np.isfinite(g_prime).all() and np.isfinite(avg.vmv).all()):
        return *empty, coef
    ev, u = _symmetric_eigh(g_prime)
    top = float(ev[-1])
    if not top > 0.0:
        return *empty, coef
    keep = ev > RITZ_RCOND * top
    w_half = u[:, keep] / np.sqrt(ev[keep])  # G'^{-1/2} on the kept directions
    theta, s = _symmetric_eigh(w_half.T @ avg.vmv @ w_half)
    return theta, w_half @ s, coef


@dataclass(frozen=True)
class EigenGains:
    """Per-round gains of the estimator (module docstring). Rate-independent: the same values
    serve a 2 ms and a 10 ms message period, 5 agents and 30."""

    columns: int = 3
    """``k``, the number of vectors each agent holds (1 is the classic single-vector scheme)."""
    step: float = 1.5
    """``alpha sbar``; below 2 since ``sbar >= lambda_max``."""
    k_t: float = 0.3
    k_n: float = 0.2
    forget: float = 0.998
    """Per-round forgetting of the max consensus on ``sbar`` (0.999^500: 0.6 per second)."""
    consensus: RoundGains = field(default_factory=RoundGains)

    def __post_init__(self) -> None:
        if self.columns < 1:
            raise ValueError("need at least one column")
        if not (0.0 < self.step < 2.0 and 0.0 < self.k_t <= 1.0 and 0.0 < self.k_n <= 1.0):
            raise ValueError(f"unstable eigen-estimator gains {self!r}")
        if not 0.0 < self.forget <= 1.0:
            raise ValueError("forget must be in (0, 1]")


@dataclass(frozen=True)
class Neighbours:
    """What agent ``i`` uses of its ``K`` neighbours' last messages: their consensus states
    ``x, z`` ``(K, n_c)``, their degrees (how many neighbours each heard) and their
    max-consensus states ``(K,)``."""

    x: FloatArray
    z: FloatArray
    degree: FloatArray
    s_bar: FloatArray

    @classmethod
    def none(cls, n_c: int) -> Neighbours:
        return cls(np.zeros((0, n_c)), np.zeros((0, n_c)), np.zeros(0), np.zeros(0))


@dataclass(slots=True)
class DistributedEigenEstimator:
    """Agent ``i``'s share of the distributed subspace iteration (module docstring)."""

    v: FloatArray  # V_i (3, k)
    gains: EigenGains = field(default_factory=EigenGains)
    x: FloatArray | None = None
    z: FloatArray | None = None
    s_bar: float = 0.0
    lambda_hat: float = 0.0
    theta: FloatArray = field(default_factory=lambda: np.zeros(0))
    c_ritz: FloatArray | None = None
    """Coefficients ``(k, r)`` of the Ritz vectors, ascending (``y_m = (V - P_T V) c_m``), matching
    :attr:`theta`; ``None`` until known."""
    coef: FloatArray | None = None
    degree: int = 0
    restarts: int = 0
    """Times the iteration diverged and was restarted (see :data:`MAX_BLOCK_NORM2`)."""
    seed: int = 0

    @classmethod
    def start(
        cls, seed: int, agent_id: int, gains: EigenGains | None = None
    ) -> DistributedEigenEstimator:
        """A small random start, seeded per agent (:func:`onboard.seeded.eigen_start_block`:
        no ``numpy.random``, and why small)."""
        g = gains or EigenGains()
        v = eigen_start_block(seed, agent_id, g.columns)
        return cls(v=v, gains=g, seed=seed * 7919 + agent_id)

    def share(self) -> tuple[FloatArray, FloatArray]:
        """The consensus state ``(x, z)`` to send (empty before the first round)."""
        if self.x is None or self.z is None:
            return np.zeros(0), np.zeros(0)
        return self.x, self.z

    def step(
        self,
        t_i: FloatArray,
        mv_i: FloatArray,
        s_own: float,
        neighbours: Neighbours,
    ) -> None:
        """One message round, given ``T_i``, the assembled ``(M_w V)_i`` ``(3, k)``, this
        agent's weighted degree ``s_i`` (own star plus what neighbours sent) and the
        neighbours' states."""
        g = self.gains
        k = g.columns
        n_c = n_consensus(k)
        phi = consensus_input(t_i, self.v, mv_i)
        nb = neighbours
        if nb.x.shape[1:] != (n_c,) or nb.z.shape != nb.x.shape:
            nb = Neighbours.none(n_c)
        self.degree = len(nb.x)
        if self.x is None or self.z is None or not np.isfinite(self.x).all():
            self.x, self.z = phi.copy(), np.zeros(n_c)
        a = metropolis_weights(self.degree, nb.degree)
        self.x, self.z = pi_round(self.x, self.z, phi, nb.x, nb.z, a, g.consensus)
        self.s_bar = max_round(s_own, self.s_bar, nb.s_bar, g.forget)

        avg = Averages.unpack(self.x, k)
        theta, c, coef = ritz(avg)
        self.coef = coef
        if len(theta):
            self.theta = theta
            self.lambda_hat = float(max(theta[0], 0.0))
            self.c_ritz = c
        trivial = t_i @ coef
        alpha = g.step / self.s_bar if self.s_bar > 0.0 else 0.0
        v_new = self.v - alpha * mv_i - g.k_t * trivial - 0.5 * g.k_n * self.v @ (avg.vv - _eye(k))
        if not float((v_new * v_new).sum()) <= MAX_BLOCK_NORM2:  # too large, inf or nan
            # diverging (e.g. a step too large for a spectrum that jumped): restart from a
            # fresh direction rather than feed the controller garbage
            self.restarts += 1
            v_new = eigen_restart_block(self.seed, self.restarts, k)
            self.x, self.z = None, None
        self.v = v_new

    def ritz_blocks(self, v_blocks: FloatArray, t_blocks: FloatArray) -> FloatArray | None:
        """Blocks ``y_jm = (V_j - T_j coef) c_m`` ``(K, 3, r)`` of the Ritz vectors (smallest
        first) for agents with ``V_j`` ``(K, 3, k)`` and ``T_j`` ``(K, 3, 7)`` (this agent's own
        view of ``coef`` and ``c``); ``None`` before the first Ritz value."""
        if self.c_ritz is None or self.coef is None:
            return None
        return (v_blocks - t_blocks @ self.coef) @ self.c_ritz


def run_rounds(
    p_ned: ArrayLike,
    yaw_rad: ArrayLike,
    candidates: Sequence[Sequence[int]],
    model: SensingModel,
    n_rounds: int,
    gains: EigenGains | None = None,
    seed: int = 0,
    v0: ArrayLike | None = None,
    switch: tuple[int, ArrayLike, ArrayLike] | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Synchronous reference network on a fixed framework: every agent runs
    :class:`DistributedEigenEstimator`, exchanging one message per round with its
    communication neighbours (``candidates[i]``: whom ``i`` may see; communication runs both
    ways). What a message carries in round ``k`` is used in round ``k + 1``. Returns
    ``(lambda_hat (rounds, N), y (N, 3))``, ``y`` agent 0's view of the smallest Ritz vector
    (zeros if none). ``switch = (round, p, yaw)`` replaces the framework at that round (a
    sudden change, to measure tracking). For tests and benchmarks: the agent core runs the
    same estimator through :mod:`onboard.core.rigidity`."""
    p = np.asarray(p_ned, dtype=float)
    yaw = np.asarray(yaw_rad, dtype=float)
    n = len(p)
    comm = [set(c) for c in candidates]
    for i in range(n):
        for j in candidates[i]:
            comm[j].add(i)
    est = [DistributedEigenEstimator.start(seed, i, gains) for i in range(n)]
    k = est[0].gains.columns
    if v0 is not None:
        v0a = np.asarray(v0, dtype=float).reshape(n, 3, k)
        for i, e in enumerate(est):
            e.v = v0a[i].copy()

    def frame(p: FloatArray, yaw: FloatArray) -> tuple[list[Star], FloatArray, FloatArray]:
        stars = [star(p[i], yaw[i], p[list(candidates[i])], model) for i in range(n)]
        s_in = np.zeros(n)
        for i, cand in enumerate(candidates):
            deg = weighted_degree(stars[i])
            s_in[i] += deg[0]
            s_in[list(cand)] += deg[1:]
        return stars, s_in, trivial_motion_blocks(p)

    stars, s_in, t_blocks = frame(p, yaw)
    v_shared = [e.v.copy() for e in est]
    contrib: dict[tuple[int, int], FloatArray] = {}
    states: list[tuple[FloatArray, FloatArray, int, float] | None] = [None] * n
    out = np.zeros((n_rounds, n))
    for r in range(n_rounds):
        if switch is not None and r == switch[0]:
            stars, s_in, t_blocks = frame(
                np.asarray(switch[1], dtype=float), np.asarray(switch[2], dtype=float)
            )
        new_contrib: dict[tuple[int, int], FloatArray] = {}
        new_states: list[tuple[FloatArray, FloatArray, int, float] | None] = [None] * n
        for i, e in enumerate(est):
            cand = list(candidates[i])
            mv = weighted_matvec(stars[i], e.v, np.array([v_shared[j] for j in cand]))
            for m, j in enumerate(cand):
                new_contrib[(i, j)] = mv[m + 1]
            mv_i = mv[0] + sum((contrib[(j, i)] for j in comm[i] if (j, i) in contrib), 0.0)
            heard = [s for j in comm[i] if (s := states[j]) is not None]
            nbrs = (
                Neighbours(*(np.array(col) for col in zip(*heard, strict=True)))
                if heard
                else Neighbours.none(n_consensus(k))
            )
            e.step(t_blocks[i], mv_i, float(s_in[i]), nbrs)
            x, z = e.share()
            new_states[i] = (x.copy(), z.copy(), e.degree, e.s_bar)
            out[r, i] = e.lambda_hat
        contrib = new_contrib
        states = new_states
        v_shared = [e.v.copy() for e in est]
    y = est[0].ritz_blocks(np.array([e.v for e in est]), t_blocks)
    return out, np.zeros((n, 3)) if y is None else y[:, :, 0]
