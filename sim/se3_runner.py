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

The same filter on today's ``R^3 x S^1`` multicopters, which roll and pitch
(:func:`tilted_team`, :func:`run_tilted_team`, ``python benchmarks/ekf_tilted.py``): their
camera bearings are in the tilted body frame and the autopilot reports the attitude; the
``unlevelled`` path levels them with it (:mod:`onboard.estimation.se3_inputs`,
docs/equations.md "Tilted multicopters") and is compared with heading-frame inputs computed
from the truth and with the filter run natively on the tilted frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from onboard.estimation import se3_inputs as si
from onboard.estimation.se3_ekf import (
    initial_state,
    predict,
    relative_poses,
    rotation_error,
    update,
)
from onboard.geometry import FloatArray, rot_z, so3_exp, so3_log
from onboard.rigidity.bearing import se3_rigidity_matrix
from onboard.rigidity.observability import bearing_rate_gradient, dbom_fields_matrix
from onboard.vision.levelling import tilt_matrix

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


# ---------------------------------------------------------------------------------------------
# Tilted multicopters: un-levelled body bearings plus the autopilot's attitude (issue 26)
# ---------------------------------------------------------------------------------------------

TILTED_PATHS = ("levelled", "unlevelled", "native")
"""How :func:`run_tilted_team` feeds the filter (module :mod:`onboard.estimation.se3_inputs`):
``levelled``: heading-frame bearings, velocities and yaw rates computed from the truth (what
the simulator's virtual camera and the daemons' messages give); ``unlevelled``: the tilted-body
bearings, body velocities and gyro rates levelled with the autopilot's attitude samples;
``native``: the tilted-body inputs straight into the filter (full ``(p, q, r)``, no attitude
but the first sample, which initializes the tilts)."""


@dataclass(frozen=True)
class TiltedTeamConfig:
    """A team of ``R^3 x S^1`` multicopters that roll and pitch (defaults: 4 vehicles, 30 s)."""

    n: int = 4
    duration_s: float = 30.0
    frame_dt_s: float = 0.02
    """Camera frames and odometry, 50 Hz."""
    attitude_dt_s: float = 0.01
    """The autopilot's ATTITUDE, 100 Hz ..."""
    attitude_offset_s: float = 0.003
    """... its samples this far after a frame's instant (interpolated at the frame)."""
    max_tilt_rad: float = math.radians(15.0)
    seed: int = 0
    bearing_noise_rad: float = math.radians(1.0)
    velocity_noise_m_s: float = 0.05
    rate_noise_rad_s: float = 0.01
    attitude_noise_rad: float = 0.0
    """White noise on the autopilot's roll and pitch, each (rad); its yaw is not used."""
    bearing_sigma_floor_rad: float = math.radians(0.1)
    prior_scale: float = 1.3
    prior_position_std_m: float = 0.3
    prior_yaw_error_rad: float = math.radians(10.0)
    prior_sigma_p_m: float = 1.5
    prior_sigma_theta_rad: float = 0.5


@dataclass(frozen=True)
class TiltedTeam:
    """Truth and measurements of a tilted team; ``K`` frames, ``A`` attitude samples,
    ``E = N (N - 1)`` directed edges :attr:`edges`."""

    t_s: FloatArray  # (K,)
    edges: FloatArray  # (E, 2) int
    p_ned: FloatArray  # (K, N, 3)
    rot_ned_body: FloatArray  # (K, N, 3, 3)
    yaw_rad: FloatArray  # (K, N)
    beta_level: FloatArray  # (K, E, 3) heading-frame bearings (noisy)
    v_heading_m_s: FloatArray  # (K, N, 3)
    yaw_rate_rad_s: FloatArray  # (K, N) Euler yaw rate (noisy)
    beta_body: FloatArray  # (K, E, 3) the same bearings in the tilted body frame
    v_body_m_s: FloatArray  # (K, N, 3)
    w_body_rad_s: FloatArray  # (K, N, 3) gyro (p, q, r)
    attitude_t_s: FloatArray  # (A,)
    attitude_rot: FloatArray  # (A, N, 3, 3) the autopilot's attitude (noisy roll, pitch)


def _tilted_params(cfg: TiltedTeamConfig) -> dict[str, FloatArray]:
    rng = np.random.default_rng([cfg.seed, 2626])
    n = cfg.n
    ring = 2.0 * math.pi * np.arange(n) / n
    return {
        "c": np.stack([3.0 * np.cos(ring), 3.0 * np.sin(ring), -2.0 + 0.3 * (np.arange(n) % 2)], 1),
        "a": rng.uniform(0.4, 1.0, (n, 3)) * np.array([1.0, 1.0, 0.3]),
        "f": rng.uniform(0.3, 0.9, (n, 3)),
        "ph": rng.uniform(0.0, 2.0 * math.pi, (n, 3)),
        "yaw0": rng.uniform(-math.pi, math.pi, n),
        "ya": rng.uniform(0.3, 0.8, n),
        "yf": rng.uniform(0.2, 0.5, n),
        "ta": rng.uniform(0.5, 1.0, (n, 2)) * cfg.max_tilt_rad,
        "tf": rng.uniform(1.0, 3.0, (n, 2)),
        "tp": rng.uniform(0.0, 2.0 * math.pi, (n, 2)),
    }


def tilted_truth(
    prm: dict[str, FloatArray], t_s: float
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """World positions ``(N, 3)``, velocities ``(N, 3)``, Euler angles ``(N, 3)`` (roll, pitch,
    yaw) and their rates ``(N, 3)`` at ``t_s``: every axis, the yaw and the tilts sinusoids."""
    s = np.sin(prm["f"] * t_s + prm["ph"])
    p = prm["c"] + prm["a"] * s
    v = prm["a"] * prm["f"] * np.cos(prm["f"] * t_s + prm["ph"])
    tilt = prm["ta"] * np.sin(prm["tf"] * t_s + prm["tp"])
    tilt_rate = prm["ta"] * prm["tf"] * np.cos(prm["tf"] * t_s + prm["tp"])
    yaw = prm["yaw0"] + prm["ya"] * np.sin(prm["yf"] * t_s)
    yaw_rate = prm["ya"] * prm["yf"] * np.cos(prm["yf"] * t_s)
    return (
        p,
        v,
        np.column_stack([tilt, yaw]),
        np.column_stack([tilt_rate, yaw_rate]),
    )


def body_rates(euler: FloatArray, euler_rate: FloatArray) -> FloatArray:
    """Gyro rates ``(p, q, r)`` ``(N, 3)`` of ZYX Euler angles and their rates ``(N, 3)``:
    ``p = phidot - psidot sin(theta)``, ``q = thetadot cos(phi) + psidot cos(theta) sin(phi)``,
    ``r = -thetadot sin(phi) + psidot cos(theta) cos(phi)``."""
    phi, th = euler[:, 0], euler[:, 1]
    dphi, dth, dpsi = euler_rate.T
    return np.column_stack(
        [
            dphi - dpsi * np.sin(th),
            dth * np.cos(phi) + dpsi * np.cos(th) * np.sin(phi),
            -dth * np.sin(phi) + dpsi * np.cos(th) * np.cos(phi),
        ]
    )


def _rpy(euler: FloatArray) -> FloatArray:
    return rot_z(euler[:, 2]) @ tilt_matrix(euler[:, 0], euler[:, 1])


def tilted_team(cfg: TiltedTeamConfig = TiltedTeamConfig()) -> TiltedTeam:
    """Fly the tilted team and take its measurements (class :class:`TiltedTeam`).

    One noise draw serves both representations, so the levelled and the un-levelled inputs
    differ only by the attitude's error: the bearing noise is a rotation of the world bearing
    (about a random axis normal to it, Gaussian angle), the velocity noise is added in NED, the
    gyro noise is isotropic in the body frame and the levelled path's yaw rate is the Euler yaw
    rate of the noisy gyro at the true roll and pitch
    (:func:`onboard.estimation.se3_inputs.euler_yaw_rate`).
    """
    prm = _tilted_params(cfg)
    rng = np.random.default_rng([cfg.seed, 2627])
    n = cfg.n
    edges = np.array([(i, j) for i in range(n) for j in range(n) if i != j])
    k_frames = round(cfg.duration_s / cfg.frame_dt_s) + 1
    keys = ("p", "r", "yaw", "bl", "vh", "yr", "bb", "vb", "wb")
    out: dict[str, list[FloatArray]] = {k: [] for k in keys}
    ts = np.arange(k_frames) * cfg.frame_dt_s
    for t in ts:
        p, v, eu, eu_rate = tilted_truth(prm, float(t))
        rot = _rpy(eu)
        b = p[edges[:, 1]] - p[edges[:, 0]]
        b /= np.linalg.norm(b, axis=1, keepdims=True)
        if cfg.bearing_noise_rad > 0.0:
            noise = rng.normal(scale=cfg.bearing_noise_rad, size=b.shape)
            noise -= np.sum(noise * b, axis=1, keepdims=True) * b
            b = np.einsum("ekl,el->ek", so3_exp(np.cross(b, noise)), b)
        v_meas = v + rng.normal(scale=cfg.velocity_noise_m_s, size=v.shape)
        w_meas = body_rates(eu, eu_rate) + rng.normal(scale=cfg.rate_noise_rad_s, size=(n, 3))
        rz = rot_z(eu[:, 2])
        out["p"].append(p)
        out["r"].append(rot)
        out["yaw"].append(eu[:, 2])
        out["bl"].append(np.einsum("eki,ek->ei", rz[edges[:, 0]], b))
        out["vh"].append(np.einsum("nki,nk->ni", rz, v_meas))
        out["yr"].append(
            np.array([si.euler_yaw_rate(w_meas[i], eu[i, 0], eu[i, 1]) for i in range(n)])
        )
        out["bb"].append(np.einsum("eki,ek->ei", rot[edges[:, 0]], b))
        out["vb"].append(np.einsum("nki,nk->ni", rot, v_meas))
        out["wb"].append(w_meas)
    ta = np.arange(cfg.attitude_offset_s - cfg.attitude_dt_s, ts[-1] + cfg.attitude_dt_s,
                   cfg.attitude_dt_s)  # fmt: skip
    att = []
    for t in ta:
        eu = tilted_truth(prm, float(t))[2].copy()
        eu[:, :2] += rng.normal(scale=cfg.attitude_noise_rad, size=(n, 2))
        att.append(_rpy(eu))
    a = {k: np.array(x) for k, x in out.items()}
    return TiltedTeam(
        t_s=ts,
        edges=edges,
        p_ned=a["p"],
        rot_ned_body=a["r"],
        yaw_rad=a["yaw"],
        beta_level=a["bl"],
        v_heading_m_s=a["vh"],
        yaw_rate_rad_s=a["yr"],
        beta_body=a["bb"],
        v_body_m_s=a["vb"],
        w_body_rad_s=a["wb"],
        attitude_t_s=ta,
        attitude_rot=np.array(att),
    )


@dataclass
class TiltedRecording:
    """One path's estimate against the truth, in the reference's *heading* frame (the native
    path's body-frame estimate re-levelled with the reference's true tilt, to compare)."""

    path: str
    t_s: FloatArray  # (K,)
    p_est_heading: FloatArray  # (K, M, 3)
    p_true_heading: FloatArray  # (K, M, 3)
    rotation_error: FloatArray  # (K, M) eq. 44, in the path's own frames
    scale_error: FloatArray  # (K,) RMS pairwise distance, estimate over truth, minus 1
    skipped: dict[str, int] = field(default_factory=dict)

    def summary(self) -> dict[str, object]:
        err = np.abs(self.scale_error)
        bad = np.flatnonzero(err >= SCALE_TOLERANCE)
        t_scale = (
            float(self.t_s[0]) if len(bad) == 0
            else None if bad[-1] == len(err) - 1 else float(self.t_s[bad[-1] + 1])
        )  # fmt: skip
        return {
            "path": self.path,
            "final_scale_error": float(self.scale_error[-1]),
            "final_position_error_m": float(
                np.linalg.norm(self.p_est_heading[-1] - self.p_true_heading[-1], axis=1).max()
            ),
            "final_rotation_error": float(self.rotation_error[-1].max()),
            "time_to_scale_s": t_scale,
            "skipped": dict(self.skipped),
        }


def _rms_size(p_rel: FloatArray) -> float:
    p = np.vstack([np.zeros((1, 3)), p_rel])
    d = p[:, None] - p[None]
    return float(np.sqrt(np.sum(d * d) / (len(p) * (len(p) - 1))))


def run_tilted_team(
    team: TiltedTeam, cfg: TiltedTeamConfig = TiltedTeamConfig(), path: str = "unlevelled"
) -> TiltedRecording:
    """Run the centralized EKF on a tilted team along ``path`` (:data:`TILTED_PATHS`).

    Every frame: predict from the previous frame with the previous frame's odometry (zero-order
    hold), then update with the frame's bearings. The levelled and un-levelled paths estimate
    heading-frame poses relative to agent 0 (``w = (0, 0, psidot)``); the un-levelled path
    interpolates the autopilot's attitude at each frame (:class:`AttitudeBuffer`), levels with
    it and inflates the noise by ``cfg.attitude_noise_rad`` through the Jacobians
    (:mod:`onboard.estimation.se3_inputs`); the attitude samples up to 50 ms after a frame are
    in the buffer when the frame is processed (its detection takes longer), a frame without
    one within 0.25 s is counted (``skipped["no_attitude"]``) and skipped. The native path estimates tilted-body poses from the
    raw inputs. All start from the same prior: the true relative poses 30% too large, 0.3 m
    of noise and the yaws 10 degrees off (the native path's tilts from the first attitude
    sample).
    """
    if path not in TILTED_PATHS:
        raise ValueError(f"path must be one of {TILTED_PATHS}, got {path!r}")
    n = team.p_ned.shape[1]
    m = n - 1
    edges = team.edges
    rng = np.random.default_rng([cfg.seed, 2628])
    heading = rot_z(team.yaw_rad)  # (K, N, 3, 3)
    p_rel_h, r_rel_h = relative_poses(team.p_ned[0], heading[0])
    p0 = p_rel_h * cfg.prior_scale + rng.normal(scale=cfg.prior_position_std_m, size=(m, 3))
    r0 = r_rel_h @ rot_z(rng.choice([-1.0, 1.0], m) * cfg.prior_yaw_error_rad)
    buffers = [si.AttitudeBuffer() for _ in range(n)]
    skipped: dict[str, int] = {}
    a_next = 0

    def attitudes_until(t: float) -> None:
        nonlocal a_next
        while a_next < len(team.attitude_t_s) and team.attitude_t_s[a_next] <= t + 0.05:
            for i in range(n):
                buffers[i].add(float(team.attitude_t_s[a_next]), team.attitude_rot[a_next, i])
            a_next += 1

    attitudes_until(0.0)
    tilt0 = np.array([tilt_matrix(*si.tilt_of(buffers[i].at(0.0))) for i in range(n)])
    if path == "native":
        p0 = p0 @ tilt0[0]  # T_0^T p (row vectors)
        r0 = np.swapaxes(tilt0[0], 0, 1)[None] @ r0 @ tilt0[1:]
    state = initial_state(p0, r0, cfg.prior_sigma_p_m, cfg.prior_sigma_theta_rad)
    sigma_b = max(cfg.bearing_noise_rad, cfg.bearing_sigma_floor_rad)
    base_std = np.array([cfg.velocity_noise_m_s, cfg.rate_noise_rad_s])
    rows: dict[str, list] = {k: [] for k in ("t", "pe", "pt", "rerr", "serr")}
    inputs: tuple[FloatArray, FloatArray, FloatArray] | None = None
    last_t = 0.0
    for k, t in enumerate(team.t_s):
        t = float(t)
        attitudes_until(t)
        if inputs is not None and t > last_t:
            state = predict(state, inputs[0], inputs[1], t - last_t, inputs[2])
            last_t = t
        if path == "levelled":
            beta, sig = team.beta_level[k], sigma_b
            v = team.v_heading_m_s[k]
            w = np.zeros((n, 3))
            w[:, 2] = team.yaw_rate_rad_s[k]
            std = np.tile(base_std, (n, 1))
            # the yaw rate of a noisy gyro: sd sigma_w |(0, sin phi, cos phi)| / cos theta
            std[:, 1] /= np.cos(np.arcsin(-team.rot_ned_body[k, :, 2, 0]))
        elif path == "native":
            beta, sig = team.beta_body[k], sigma_b
            v, w = team.v_body_m_s[k], team.w_body_rad_s[k]
            std = np.tile(base_std, (n, 1))
        else:
            att = [buffers[i].at(t) for i in range(n)]
            if any(a is None for a in att):
                skipped["no_attitude"] = skipped.get("no_attitude", 0) + 1
                continue
            tilt = [si.tilt_of(a) for a in att]
            beta = np.zeros_like(team.beta_body[k])
            sig = sigma_b
            for i in range(n):
                mine = edges[:, 0] == i
                beta[mine] = si.level(team.beta_body[k, mine], *tilt[i])
                sig = max(
                    sig,
                    si.levelled_bearing_sigma_rad(
                        team.beta_body[k, mine], *tilt[i], sigma_b, cfg.attitude_noise_rad
                    ),
                )
            v, w, std = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 2))
            for i in range(n):
                v[i], w[i, 2] = si.heading_motion(
                    team.v_body_m_s[k, i], team.w_body_rad_s[k, i], *tilt[i]
                )
                std[i] = si.heading_motion_sigmas(
                    team.v_body_m_s[k, i], team.w_body_rad_s[k, i], *tilt[i],
                    cfg.velocity_noise_m_s, cfg.rate_noise_rad_s, cfg.attitude_noise_rad,
                )  # fmt: skip
        inputs = (v, w, std)
        state, _ = update(state, edges, beta, sig)
        if path == "native":
            p_t, r_t = relative_poses(team.p_ned[k], team.rot_ned_body[k])
            t0 = tilt_matrix(*si.tilt_of(team.rot_ned_body[k, 0]))
            p_est_h = state.p_ref @ t0.T
        else:
            p_t, r_t = relative_poses(team.p_ned[k], heading[k])
            p_est_h = state.p_ref
        p_true_h = relative_poses(team.p_ned[k], heading[k])[0]
        rows["t"].append(t)
        rows["pe"].append(p_est_h.copy())
        rows["pt"].append(p_true_h)
        rows["rerr"].append(rotation_error(state.rot_ref_body, r_t))
        rows["serr"].append(_rms_size(state.p_ref) / _rms_size(p_t) - 1.0)
    return TiltedRecording(
        path=path,
        t_s=np.array(rows["t"]),
        p_est_heading=np.array(rows["pe"]),
        p_true_heading=np.array(rows["pt"]),
        rotation_error=np.array(rows["rerr"]),
        scale_error=np.array(rows["serr"]),
        skipped=skipped,
    )


__all__ = [
    "TILTED_PATHS",
    "Se3Recording",
    "Se3RunConfig",
    "TiltedRecording",
    "TiltedTeam",
    "TiltedTeamConfig",
    "body_rates",
    "run_se3",
    "run_tilted_team",
    "tilted_team",
    "tilted_truth",
    "true_angular_velocity",
    "true_positions",
]


SE3_SCENARIOS: dict[str, str] = {
    "ekf-se3": "paper 001 sec. V: centralized EKF on SE(3)^N, 3 agents, far start"
}
"""Scenarios this runner serves (``bearingflock scenario``)."""
