"""Headless SE(3) runner: paper 001's experiment (sec. V) for the centralized EKF.

Agents with full 3-D attitude and angular velocity (``pdot = R v``, ``Rdot = R hat(w)``, paper
001 eq. 1), body-frame bearings on every directed edge (eq. 3), per-step odometry (each agent's
body-frame displacement and rotation over the step, divided by the step: the inputs of eq. 34)
with seeded Gaussian noise, and the filter of :mod:`onboard.estimation.se3_ekf`.

The experiment (``bearingflock scenario ekf-se3``), in the 6.5 m x 6.5 m x 3 m arena (NED,
origin at the centre of the floor, so ``|x|, |y| <= 3.25``, ``-3 <= z <= 0``):

* agent 1 (index 0) static at the origin, level: the reference (paper 001: a virtual agent at
  the origin of the motion-capture frame);
* agent 2 back and forth along ``x``: ``x = 2.5 sin(2 pi t / 12)``, ``y = 1.5``, ``z = -1.5``;
* agent 3 on an ellipse: ``(2.5 cos(2 pi t / 20), -1.2 + 1.5 sin(2 pi t / 20), -2 + 0.3 sin(..))``;
* agents 2 and 3 turn with full 3-D angular velocities (bounded sinusoids in roll, pitch, yaw);
* every agent measures every other (6 bearings), 1 deg noise by default; odometry noise
  0.05 m/s and 0.01 rad/s (agent 1 is known static: no noise);
* the estimate starts far from the truth: about 2 m off in position and 60 deg in orientation
  per agent, prior standard deviations 2 m and 1 rad.

Paper 001's experiment uses real quadrotors and a joystick, and its text gives neither the
duration nor the noise levels; these values are this runner's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from onboard.estimation.se3_ekf import (
    initial_state,
    predict,
    relative_poses,
    rotation_error,
    update,
)
from onboard.geometry import FloatArray, so3_exp, so3_log
from onboard.rigidity.bearing import se3_rigidity_matrix
from onboard.rigidity.observability import bearing_rate_gradient, dbom_fields_matrix

ARENA_HALF_XY_M = 3.25
ARENA_HEIGHT_M = 3.0
EDGES = np.array([(0, 1), (1, 0), (0, 2), (2, 0), (1, 2), (2, 1)])
SCALE_TOLERANCE = 0.02
"""``time_to_scale_s``: first time after which the scale error stays below 2%."""


@dataclass(frozen=True)
class Se3RunConfig:
    """Parameters of one run (defaults: the ``ekf-se3`` scenario)."""

    duration_s: float = 60.0
    dt_s: float = 0.02
    substeps: int = 10
    seed: int = 0
    bearing_noise_rad: float = math.radians(1.0)
    velocity_noise_m_s: float = 0.05
    rate_noise_rad_s: float = 0.01
    prior_position_error_m: float = 2.0
    prior_rotation_error_rad: float = math.radians(60.0)
    prior_sigma_p_m: float = 2.0
    prior_sigma_theta_rad: float = 1.0
    iterations: int = 1
    singular_values_every: int = 10


@dataclass
class Se3Recording:
    """Time series of a run; ``M = N - 1`` estimated agents, ``T`` samples."""

    t_s: FloatArray  # (T,)
    p_true_ref: FloatArray  # (T, M, 3) truth in agent 1's frame
    p_est_ref: FloatArray  # (T, M, 3)
    var_p_m2: FloatArray  # (T, M, 3) position variances per axis
    rotation_error: FloatArray  # (T, M) paper 001 eq. 44
    d23_true_m: FloatArray  # (T,)
    d23_est_m: FloatArray  # (T,)
    p_world: FloatArray  # (T, N, 3) true world positions
    sv_t_s: FloatArray = field(default_factory=lambda: np.zeros(0))
    sv_rigidity: FloatArray = field(default_factory=lambda: np.zeros((0, 8)))  # last 8 of R_A
    sv_dbom: FloatArray = field(default_factory=lambda: np.zeros((0, 8)))  # last 8, motion DBOM
    sv_fields: FloatArray = field(default_factory=lambda: np.zeros((0, 8)))  # last 8, field DBOM
    config: Se3RunConfig = field(default_factory=Se3RunConfig)

    @property
    def scale_error(self) -> FloatArray:
        """Relative error of the estimated distance between agents 2 and 3 (paper 001 fig. 2c)."""
        return np.abs(self.d23_est_m / self.d23_true_m - 1.0)

    def summary(self) -> dict[str, object]:
        """The ``--json`` numbers: final scale and rotation errors, time to 2% scale error."""
        err = self.scale_error
        bad = np.flatnonzero(err >= SCALE_TOLERANCE)
        if len(bad) == 0:
            t_scale: float | None = float(self.t_s[0])
        elif bad[-1] == len(err) - 1:
            t_scale = None
        else:
            t_scale = float(self.t_s[bad[-1] + 1])
        return {
            "final_scale_error": float(err[-1]),
            "final_rotation_error": float(self.rotation_error[-1].max()),
            "time_to_scale_s": t_scale,
            "initial_scale_error": float(err[0]),
            "initial_rotation_error": float(self.rotation_error[0].max()),
            "final_position_error_m": float(
                np.linalg.norm(self.p_est_ref[-1] - self.p_true_ref[-1], axis=1).max()
            ),
            "final_position_std_m": [[float(x) for x in np.sqrt(v)] for v in self.var_p_m2[-1]],
            "bearing_noise_deg": math.degrees(self.config.bearing_noise_rad),
            "velocity_noise_m_s": self.config.velocity_noise_m_s,
            "rate_noise_rad_s": self.config.rate_noise_rad_s,
            "dt_s": self.config.dt_s,
            "iterations": self.config.iterations,
        }


def true_positions(t_s: float) -> tuple[FloatArray, FloatArray]:
    """World positions ``(3, 3)`` and velocities ``(3, 3)`` of the experiment at ``t_s``."""
    w2 = 2.0 * math.pi / 12.0
    w3 = 2.0 * math.pi / 20.0
    p = np.array(
        [
            [0.0, 0.0, 0.0],
            [2.5 * math.sin(w2 * t_s), 1.5, -1.5],
            [
                2.5 * math.cos(w3 * t_s),
                -1.2 + 1.5 * math.sin(w3 * t_s),
                -2.0 + 0.3 * math.sin(2 * w3 * t_s),
            ],
        ]
    )
    v = np.array(
        [
            [0.0, 0.0, 0.0],
            [2.5 * w2 * math.cos(w2 * t_s), 0.0, 0.0],
            [
                -2.5 * w3 * math.sin(w3 * t_s),
                1.5 * w3 * math.cos(w3 * t_s),
                0.6 * w3 * math.cos(2 * w3 * t_s),
            ],
        ]
    )
    return p, v


def true_angular_velocity(t_s: float) -> FloatArray:
    """Body angular velocities ``(3, 3)`` (rad/s): agent 1 still, 2 and 3 turn about all axes."""
    return np.array(
        [
            [0.0, 0.0, 0.0],
            [0.3 * math.sin(0.5 * t_s), 0.25 * math.cos(0.7 * t_s), 0.4 * math.sin(0.3 * t_s)],
            [
                0.2 * math.cos(0.6 * t_s + 1.0),
                0.3 * math.sin(0.4 * t_s),
                -0.35 * math.cos(0.25 * t_s),
            ],
        ]
    )


def _noisy_bearings(
    p: FloatArray, rot: FloatArray, sigma_rad: float, rng: np.random.Generator
) -> FloatArray:
    """Body bearings on :data:`EDGES` rotated by an isotropic tangent-plane angle error."""
    r = p[EDGES[:, 1]] - p[EDGES[:, 0]]
    beta = np.einsum("eki,ek->ei", rot[EDGES[:, 0]], r) / np.linalg.norm(r, axis=1)[:, None]
    if sigma_rad <= 0.0:
        return beta
    # rotate each bearing about a random axis orthogonal to it by a Gaussian 2-D angle
    noise = rng.normal(scale=sigma_rad, size=(len(beta), 3))
    noise -= np.sum(noise * beta, axis=1, keepdims=True) * beta
    return np.einsum("ekl,el->ek", so3_exp(np.cross(beta, noise)), beta)


def _last_singular_values(matrix: FloatArray, count: int = 8) -> FloatArray:
    sv = np.linalg.svd(matrix / np.linalg.norm(matrix, 2), compute_uv=False)
    return sv[-count:]


def _unit_blocks(static: FloatArray, dynamic: FloatArray) -> FloatArray:
    """Stack the two row blocks, each scaled to unit spectral norm (as the rank tests do)."""
    return np.vstack([static / np.linalg.norm(static, 2), dynamic / np.linalg.norm(dynamic, 2)])


def _prior(
    p_true: FloatArray, rot_true: FloatArray, cfg: Se3RunConfig, rng: np.random.Generator
) -> tuple[FloatArray, FloatArray]:
    """Far start: each position off by ``prior_position_error_m`` in a random direction, each
    rotation by ``prior_rotation_error_rad`` about a random axis."""
    m = len(p_true)
    dirs = rng.normal(size=(m, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    axes = rng.normal(size=(m, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    return (
        p_true + cfg.prior_position_error_m * dirs,
        rot_true @ so3_exp(cfg.prior_rotation_error_rad * axes),
    )


def run_se3(cfg: Se3RunConfig = Se3RunConfig(), progress=None) -> Se3Recording:
    """Fly the experiment and run the filter; ``progress(fraction)`` is called now and then."""
    if not (cfg.duration_s > 0 and cfg.dt_s > 0 and cfg.substeps >= 1):
        raise ValueError("duration_s, dt_s must be positive and substeps >= 1")
    rng = np.random.default_rng([cfg.seed, 26])
    n = 3
    steps = round(cfg.duration_s / cfg.dt_s)
    h = cfg.dt_s / cfg.substeps
    rot_w = np.stack([np.eye(3), so3_exp([0.1, -0.2, 0.8]), so3_exp([-0.15, 0.1, -1.2])])
    p_w, _ = true_positions(0.0)
    p_rel, rot_rel = relative_poses(p_w, rot_w)
    p0, r0 = _prior(p_rel, rot_rel, cfg, rng)
    state = initial_state(p0, r0, cfg.prior_sigma_p_m, cfg.prior_sigma_theta_rad)
    input_std = np.array([[0.0, 0.0]] + [[cfg.velocity_noise_m_s, cfg.rate_noise_rad_s]] * (n - 1))
    rows: dict[str, list] = {k: [] for k in ("t", "pt", "pe", "var", "rerr", "pw")}
    sv_t, sv_a, sv_d, sv_f = [], [], [], []

    def record(t: float) -> None:
        p_rel, rot_rel = relative_poses(p_w, rot_w)
        rows["t"].append(t)
        rows["pt"].append(p_rel)
        rows["pe"].append(state.p_ref.copy())
        m = n - 1
        rows["var"].append(np.diag(state.cov)[: 3 * m].reshape(m, 3).copy())
        rows["rerr"].append(rotation_error(state.rot_ref_body, rot_rel))
        rows["pw"].append(p_w.copy())

    record(0.0)
    for k in range(steps):
        t0 = k * cfg.dt_s
        p_start, rot_start = p_w.copy(), rot_w.copy()
        mid = t0 + (np.arange(cfg.substeps) + 0.5) * h
        increments = so3_exp(h * np.stack([true_angular_velocity(t) for t in mid]))
        for inc in increments:  # midpoint rule, one exponential per substep and agent
            rot_w = rot_w @ inc
        t1 = t0 + cfg.dt_s
        p_w, v_w = true_positions(t1)
        # odometry: body-frame displacement and rotation over the step, per second, plus noise
        v_odo = np.einsum("nki,nk->ni", rot_start, p_w - p_start) / cfg.dt_s
        w_odo = so3_log(np.swapaxes(rot_start, 1, 2) @ rot_w) / cfg.dt_s
        v_meas = v_odo + rng.normal(size=(n, 3)) * input_std[:, :1]
        w_meas = w_odo + rng.normal(size=(n, 3)) * input_std[:, 1:]
        state = predict(state, v_meas, w_meas, cfg.dt_s, input_std)
        beta = _noisy_bearings(p_w, rot_w, cfg.bearing_noise_rad, rng)
        sigma = max(cfg.bearing_noise_rad, math.radians(0.05))
        state, _ = update(state, EDGES, beta, sigma, cfg.iterations)
        record(t1)
        if cfg.singular_values_every and k % cfg.singular_values_every == 0:
            v_body = np.einsum("nki,nk->ni", rot_w, v_w)
            static = se3_rigidity_matrix(p_w, rot_w, EDGES)
            dyn = bearing_rate_gradient(p_w, rot_w, v_body, EDGES, true_angular_velocity(t1))
            fields = dbom_fields_matrix(p_w, rot_w, EDGES)[len(static) :]
            sv_f.append(_last_singular_values(_unit_blocks(static, fields)))
            sv_t.append(t1)
            sv_a.append(_last_singular_values(static))
            sv_d.append(_last_singular_values(_unit_blocks(static, dyn)))
        if progress is not None and k % 100 == 0:
            progress(k / steps)
    if progress is not None:
        progress(1.0)
    pt = np.array(rows["pt"])
    pe = np.array(rows["pe"])
    return Se3Recording(
        t_s=np.array(rows["t"]),
        p_true_ref=pt,
        p_est_ref=pe,
        var_p_m2=np.array(rows["var"]),
        rotation_error=np.array(rows["rerr"]),
        d23_true_m=np.linalg.norm(pt[:, 1] - pt[:, 0], axis=1),
        d23_est_m=np.linalg.norm(pe[:, 1] - pe[:, 0], axis=1),
        p_world=np.array(rows["pw"]),
        sv_t_s=np.array(sv_t),
        sv_rigidity=np.array(sv_a),
        sv_dbom=np.array(sv_d),
        sv_fields=np.array(sv_f),
        config=cfg,
    )


__all__ = ["Se3Recording", "Se3RunConfig", "run_se3", "true_angular_velocity", "true_positions"]


SE3_SCENARIOS: dict[str, str] = {
    "ekf-se3": "paper 001 sec. V: centralized EKF on SE(3)^N, 3 agents, far start"
}
"""Scenarios this runner serves (``bearingflock scenario``)."""
