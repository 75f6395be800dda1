"""Headless runner for paper 002's formation simulations (fig. 11), in 2-D or 3-D.

Agents are single integrators ``p_i' = u_i`` (paper 002 "Bearing-based control": "a simple
first-order integrator model") in ``R^d`` with known rotations, so bearings are world-frame unit
vectors. Every step each agent measures the bearings of its out-edges (and the range of a ranged
edge), and applies ``u_i = -k grad_{p_i} phi`` of paper 002 eq. 7 with the pairwise gradient of
eq. 20 (+ eq. 23) from :mod:`onboard.distributed.formation`. The bearings of ``(j, i)`` reach ``i``
from ``j`` (the flow needs both endpoint gradients, eq. 7). Forward Euler with ``dt`` checked
against the displacement rule of :func:`onboard.distributed.flow.displacement_step`.

Bearing noise: each measured bearing is the true one turned by a Gaussian angle (``d = 2``) or
perturbed by isotropic Gaussian tangent noise and renormalized (``d = 3``), ``sigma`` rad per
axis. Optional leader: one agent follows an external velocity instead of the gradient.

This is the project's "2-D mode" of the headless runner; :mod:`sim.runner` (the MAVLink-shaped
agent cores in 3-D NED with yaw) is untouched.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from onboard.distributed.flow import (
    apply_leaders,
    check_edges,
    displacement_step,
    euclidean_step,
    max_degree,
    node_gradient,
)
from onboard.distributed.formation import (
    bearing_error_deg,
    bearings_from_positions,
    formation_gradients,
)
from onboard.distributed.reshaping import F_C, F_D, ReshapeC, ReshapeD
from onboard.geometry import FloatArray


@dataclass(frozen=True)
class FormationProblem:
    """A desired formation and its sensing graph: ``p_des`` ``(N, d)`` (defined up to translation
    and, without ranges, scale), ``edges`` ``(E, 2)``, ``ranged`` ``(E,)`` bool (edges with a
    range measurement and a desired distance)."""

    p_des: FloatArray
    edges: np.ndarray
    ranged: np.ndarray

    @property
    def dim(self) -> int:
        return int(self.p_des.shape[1])


@dataclass(frozen=True)
class FormationRun:
    t_s: FloatArray
    """``(K,)`` sample times."""
    p: FloatArray
    """``(K, N, d)`` positions."""
    bearing_error_deg: FloatArray
    """``(K, E)`` angle between true and desired bearings."""
    distance_error_m: FloatArray
    """``(K, E)`` ``| d_ij - d*_ij |`` for every edge (desired distances of the desired formation)."""
    dropped_edges: int
    """Edge-steps whose bearing could not be measured (coincident agents)."""


def _noisy(t: FloatArray, sigma_rad: float, rng: np.random.Generator) -> FloatArray:
    if sigma_rad <= 0:
        return t
    if t.shape[1] == 2:
        a = rng.normal(0.0, sigma_rad, len(t))
        c, s = np.cos(a), np.sin(a)
        return np.stack([c * t[:, 0] - s * t[:, 1], s * t[:, 0] + c * t[:, 1]], axis=1)
    n = rng.normal(0.0, sigma_rad, t.shape)
    n -= np.sum(n * t, axis=1)[:, None] * t
    out = t + n
    return out / np.linalg.norm(out, axis=1)[:, None]


def run_formation(
    problem: FormationProblem,
    p0: ArrayLike,
    duration_s: float,
    dt_s: float = 0.01,
    k: float = 0.5,
    f_c: ReshapeC = F_C,
    f_d: ReshapeD = F_D,
    bearing_noise_rad: float = 0.0,
    seed: int = 0,
    record_every: int = 10,
    leader: int | None = None,
    leader_velocity: ArrayLike | None = None,
) -> FormationRun:
    """Fly the formation flow from ``p0`` ``(N, d)`` for ``duration_s`` seconds."""
    p = np.array(p0, dtype=float)
    e = check_edges(problem.edges, len(p))
    if p.shape != problem.p_des.shape:
        raise ValueError("p0 must have the shape of the desired formation")
    if not (np.isfinite(duration_s) and duration_s > 0 and dt_s > 0 and k > 0):
        raise ValueError("duration, dt and k must be positive")
    t_des, d_des = bearings_from_positions(problem.p_des, e)
    d_star = np.where(problem.ranged, d_des, np.nan)
    bound = displacement_step(f_c.gradient_bound(), max_degree(e, len(p)), float(d_des.min()), 0.1)
    if dt_s * k > bound:
        raise ValueError(f"dt * k = {dt_s * k:.4g} exceeds the displacement rule's {bound:.4g}")
    rng = np.random.default_rng(seed)
    mask = None
    vel = None
    if leader is not None:
        mask = np.zeros(len(p), dtype=bool)
        mask[leader] = True
        vel = np.zeros_like(p)
        vel[leader] = np.zeros(p.shape[1]) if leader_velocity is None else leader_velocity
    steps = round(duration_s / dt_s)
    ts, ps, be, de = [], [], [], []
    dropped = 0

    def record(step: int) -> None:
        t, d = bearings_from_positions(p, e)
        ts.append(step * dt_s)
        ps.append(p.copy())
        be.append(bearing_error_deg(np.nan_to_num(t), t_des))
        de.append(np.abs(d - d_des))

    for step in range(steps):
        if step % record_every == 0:
            record(step)
        t, d = bearings_from_positions(p, e)
        ok = np.all(np.isfinite(t), axis=1)
        t_meas = t.copy()
        t_meas[ok] = _noisy(t[ok], bearing_noise_rad, rng)
        rng_m = np.where(problem.ranged, d, np.nan)
        g, n_drop = formation_gradients(t_meas, t_des, rng_m, d_star, f_c, f_d)
        dropped += n_drop
        p = apply_leaders(
            euclidean_step(p, node_gradient(e, len(p), g), dt_s * k), p, mask, vel, dt_s
        )
    record(steps)
    return FormationRun(
        t_s=np.array(ts),
        p=np.array(ps),
        bearing_error_deg=np.array(be),
        distance_error_m=np.array(de),
        dropped_edges=dropped,
    )
