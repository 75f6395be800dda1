"""Monte Carlo runs of paper 001's EKF on its own model (docs/equations.md, "Centralized EKF on
``SE(3)^N``"): three agents whose truth follows the filter's process model exactly, noisy inputs
and tangent-plane bearing noise, the prior error drawn from the prior covariance.

The filter's consistency tests (tests/onboard/test_se3_ekf.py) and the prior study
(benchmarks/ekf_nees_prior.py) fly the same runs; ``bearingflock scenario ekf-se3``
(:mod:`sim.se3_runner`) is paper 001's experiment itself.
"""

from __future__ import annotations

from typing import Literal, NamedTuple

import numpy as np

from onboard.estimation.se3_ekf import (
    Se3EkfState,
    initial_state,
    local_difference,
    predict,
    predicted_bearings,
    propagate,
    relative_poses,
    retract,
    tangent_basis,
    update,
)

Motion = Literal["exciting", "static", "translation"]
"""``exciting``: agents 2 and 3 translate and turn about all axes, agent 1 static;
``static``: nobody moves; ``translation``: everyone (agent 1 too) flies one world velocity."""

EDGES = np.array([(0, 1), (1, 0), (0, 2), (2, 0), (1, 2), (2, 1)])
"""Every agent sees every other one."""
DT_S = 0.05
SIGMA_V_M_S = 0.05
SIGMA_W_RAD_S = 0.02
SIGMA_BEARING = 0.01
"""Bearing noise per tangent component of the unit bearing."""
P0_WORLD = np.array([[0.0, 0.0, 0.0], [2.0, 0.5, -1.0], [-0.5, 2.5, -1.5]])
"""Initial true positions, m; attitudes start at identity."""


def team_motion(kind: Motion, t_s: float) -> tuple[np.ndarray, np.ndarray]:
    """True body velocities ``(3, 3)`` m/s and angular rates ``(3, 3)`` rad/s at ``t_s``."""
    v_body = np.zeros((3, 3))
    w_body = np.zeros((3, 3))
    t = t_s
    if kind == "exciting":
        v_body[1] = [0.8 * np.cos(1.3 * t), 0.3 * np.sin(0.7 * t), 0.2 * np.cos(0.9 * t)]
        v_body[2] = [0.6 * np.sin(1.1 * t), 0.7 * np.cos(0.8 * t), -0.2 * np.sin(0.5 * t)]
        w_body[1] = [0.1 * np.sin(0.6 * t), 0.1 * np.cos(0.4 * t), 0.3]
        w_body[2] = [0.05, -0.1 * np.sin(0.3 * t), -0.2]
    elif kind == "translation":
        # attitudes stay identity, so the body velocity is the world velocity
        v_body[:] = [0.7 * np.cos(0.9 * t), 0.5, 0.2 * np.sin(1.2 * t)]
    return v_body, w_body


class Run(NamedTuple):
    """One Monte Carlo run's result."""

    nees: list[float]
    """Normalized estimation error squared after each step (12 degrees of freedom)."""
    state: Se3EkfState
    """The filter's last state."""
    p_true: np.ndarray
    """The last true positions relative to agent 1 ``(3, 3)``."""


def monte_carlo_run(
    kind: Motion,
    seed: int,
    steps: int,
    sigma_p_m: float = 0.5,
    sigma_theta_rad: float = 0.2,
    scale0: float = 1.0,
    iterations: int = 1,
) -> Run:
    """One run of ``steps`` steps of ``DT_S``: truth from the filter's model, noisy inputs and
    bearings, prior error drawn from the prior covariance (``sigma_p_m``, ``sigma_theta_rad``).
    ``scale0`` scales the prior's positions about the reference (bearings cannot tell);
    ``iterations`` > 1 runs the iterated update."""
    rng = np.random.default_rng([seed, 26])
    p_w = P0_WORLD.copy()
    rot_w = np.tile(np.eye(3), (3, 1, 1))
    p_true, rot_true = relative_poses(p_w, rot_w)
    std = np.array([[SIGMA_V_M_S, SIGMA_W_RAD_S]] * 3)
    if kind != "translation":
        std[0] = 0.0  # static reference: its zero velocity is known exactly
    dx0 = np.concatenate(
        [rng.normal(scale=sigma_p_m, size=6), rng.normal(scale=sigma_theta_rad, size=6)]
    )
    p0, r0 = retract(scale0 * p_true, rot_true, dx0)
    st = initial_state(p0, r0, sigma_p_m, sigma_theta_rad)
    nees = []
    for k in range(steps):
        v, w = team_motion(kind, k * DT_S)
        p_true, rot_true = propagate(p_true, rot_true, v, w, DT_S)
        noise_v = rng.normal(size=(3, 3)) * std[:, :1]
        noise_w = rng.normal(size=(3, 3)) * std[:, 1:]
        st = predict(st, v - noise_v, w - noise_w, DT_S, std)
        beta = predicted_bearings(p_true, rot_true, EDGES)
        t = tangent_basis(beta)
        beta = beta + np.einsum("eka,ea->ek", t, rng.normal(scale=SIGMA_BEARING, size=(6, 2)))
        beta /= np.linalg.norm(beta, axis=1, keepdims=True)
        st, _ = update(st, EDGES, beta, SIGMA_BEARING, iterations)
        err = local_difference(st.p_ref, st.rot_ref_body, p_true, rot_true)
        nees.append(float(err @ np.linalg.solve(st.cov, err)))
    return Run(nees, st, p_true)
