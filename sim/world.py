"""The kinematic world: N multicopters that track velocity and yaw-rate commands.

Each vehicle has a position ``p_ned`` (m), a yaw ``yaw_rad`` and the velocity ``v_ned`` (m/s)
and yaw rate ``yaw_rate_rad_s`` it actually flies. Its autopilot gives it, per vehicle, either

* a velocity command ``v_cmd`` in NED or in the heading frame (``cmd_body``; then the world
  rotates it by the current yaw at every step, the agent model ``pdot = R_z(psi) u`` of
  ``docs/equations.md``, "Scale from motion"), or
* a position to hold ``hold_ned`` (``hold_active``): the velocity command becomes a saturated
  proportional law ``k_p (hold - p)`` with separate horizontal, climb and descent limits,

and either a yaw-rate command or a yaw to hold (``yaw_hold_active``). The actual velocity and
yaw rate follow the commands through a first-order lag with time constants ``tau_v_s`` and
``tau_yaw_s`` whose acceleration and yaw acceleration are limited:

    v' = sat_{a_max}((v_cmd - v) / tau_v),    r' = sat_{yaw_acc_max}((r_cmd - r) / tau_yaw).

The ground is the plane ``z_ned = 0``: a vehicle never goes below it (``z_ned <= 0``) and stops
descending when it touches it. Every function is vectorized over vehicles; the autopilots only
write command arrays.

``realistic`` (a :class:`sim.dynamics.RealisticConfig`) replaces the lag of velocity commands
and yaw-rate commands by realistic multicopter dynamics (:mod:`sim.dynamics`: command delay,
shaped response with overshoot, tilt to accelerate, hover wander) and the report by an EKF-like
one (stamping delay, velocity noise and slowly varying bias, attitude noise and yaw bias); the
autopilot flies on its estimate, so a vehicle told to stop drifts at minus its velocity bias;
position and yaw holds keep the ideal laws, flown through the tilt loop. ``None`` (the default)
is the ideal kinematic model of the paper reproductions.

Reported (measured) quantities are separate from truth: :func:`observe` adds optional seeded
noise to velocity and attitude and derives roll and pitch from the horizontal specific force
needed to accelerate and to hold against a wind (a level multicopter cannot accelerate).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from messages.formation import load_formation
from onboard.geometry import FloatArray, rot_z, wrap_angle
from sim import dynamics as rd

GRAVITY_MPS2 = 9.80665


@dataclass(frozen=True)
class DynamicsConfig:
    """Parameters of the kinematic model (defaults close to a small PX4 quadrotor)."""

    tau_v_s: float = 0.3
    """Time constant of the velocity lag."""
    tau_yaw_s: float = 0.2
    """Time constant of the yaw-rate lag."""
    accel_max_m_s2: float = 4.0
    """Limit on the norm of the acceleration."""
    yaw_acc_max_rad_s2: float = math.radians(360.0)
    v_max_xy_m_s: float = 12.0
    """Absolute limit on commanded horizontal speed (``MPC_XY_VEL_MAX``)."""
    v_max_up_m_s: float = 3.0
    v_max_down_m_s: float = 1.5
    yaw_rate_max_rad_s: float = math.radians(200.0)
    k_hold_per_s: float = 1.0
    """Gain of the position-hold law."""
    hold_max_xy_m_s: float = 5.0
    """Horizontal speed limit while holding/flying to a position (``MPC_XY_CRUISE``)."""
    hold_max_up_m_s: float = 1.5
    """Climb speed while holding/taking off (``MPC_TKO_SPEED``)."""
    hold_max_down_m_s: float = 0.7
    """Descent speed while holding/landing (``MPC_LAND_SPEED``)."""
    k_yaw_per_s: float = 2.0
    """Gain of the yaw-hold law."""
    drag_per_s: float = 0.3
    """Linear drag per unit mass, only used to lean the reported attitude into the wind."""

    def __post_init__(self) -> None:
        for name in ("tau_v_s", "tau_yaw_s", "accel_max_m_s2", "yaw_acc_max_rad_s2"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"DynamicsConfig.{name} must be > 0, got {getattr(self, name)}")


@dataclass(frozen=True)
class SensorNoise:
    """Optional noise on what the autopilots report (truth stays exact). ``seed`` fixes it."""

    velocity_std_m_s: float = 0.0
    attitude_std_rad: float = 0.0
    wind_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Constant wind: the reported attitude leans into it (truth motion is unaffected, as if
    the position controller compensated it perfectly)."""
    seed: int = 0


@dataclass
class World:
    """State and commands of N vehicles (arrays with the vehicle index first)."""

    p_ned: FloatArray
    yaw_rad: FloatArray
    config: DynamicsConfig = field(default_factory=DynamicsConfig)
    t_s: float = 0.0
    realistic: rd.RealisticConfig | None = None
    """Realistic dynamics and EKF-like report (:mod:`sim.dynamics`); ``None``: ideal."""
    dt_s: float = 0.01
    """Step the realistic model's delay lines are sized for (:meth:`step` takes any ``dt``)."""
    rstate: rd.RealisticState | None = field(init=False, default=None)
    v_ned: FloatArray = field(init=False)
    yaw_rate_rad_s: FloatArray = field(init=False)
    a_ned: FloatArray = field(init=False)
    v_cmd: FloatArray = field(init=False)
    cmd_body: np.ndarray = field(init=False)
    yaw_rate_cmd_rad_s: FloatArray = field(init=False)
    hold_ned: FloatArray = field(init=False)
    hold_active: np.ndarray = field(init=False)
    yaw_hold_rad: FloatArray = field(init=False)
    yaw_hold_active: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.p_ned = np.array(self.p_ned, dtype=float).reshape(-1, 3)
        n = self.p_ned.shape[0]
        self.yaw_rad = wrap_angle(np.array(self.yaw_rad, dtype=float).reshape(n))
        if not (np.all(np.isfinite(self.p_ned)) and np.all(np.isfinite(self.yaw_rad))):
            raise ValueError("initial positions and yaws must be finite")
        self.p_ned[:, 2] = np.minimum(self.p_ned[:, 2], 0.0)
        self.v_ned = np.zeros((n, 3))
        self.yaw_rate_rad_s = np.zeros(n)
        self.a_ned = np.zeros((n, 3))
        self.v_cmd = np.zeros((n, 3))
        self.cmd_body = np.zeros(n, dtype=bool)
        self.yaw_rate_cmd_rad_s = np.zeros(n)
        self.hold_ned = self.p_ned.copy()
        self.hold_active = np.zeros(n, dtype=bool)
        self.yaw_hold_rad = self.yaw_rad.copy()
        self.yaw_hold_active = np.zeros(n, dtype=bool)
        if self.realistic is not None:
            self.rstate = rd.initial_state(n, self.realistic, self.dt_s, self.p_ned, self.yaw_rad)

    @property
    def n(self) -> int:
        return int(self.p_ned.shape[0])

    # --- commands (written by the autopilots) -------------------------------------------------
    def command_velocity(self, i: int, v: tuple[float, float, float], body: bool) -> None:
        """Fly vehicle ``i`` at velocity ``v`` (NED, or heading frame if ``body``)."""
        self.v_cmd[i] = v
        self.cmd_body[i] = body
        self.hold_active[i] = False

    def command_hold(self, i: int, p_ned: FloatArray | tuple[float, float, float]) -> None:
        """Fly vehicle ``i`` to ``p_ned`` and hold it there."""
        self.hold_ned[i] = p_ned
        self.hold_active[i] = True

    def command_yaw_rate(self, i: int, yaw_rate_rad_s: float) -> None:
        self.yaw_rate_cmd_rad_s[i] = yaw_rate_rad_s
        self.yaw_hold_active[i] = False

    def command_yaw(self, i: int, yaw_rad: float) -> None:
        self.yaw_hold_rad[i] = yaw_rad
        self.yaw_hold_active[i] = True

    def on_ground(self, eps_m: float = 0.05) -> np.ndarray:
        """Vehicles touching the ground plane (``z_ned > -eps``)."""
        return self.p_ned[:, 2] > -eps_m

    # --- dynamics ---------------------------------------------------------------------------------
    def step(self, dt_s: float) -> None:
        """Advance every vehicle by ``dt_s`` seconds."""
        v_cmd = commanded_velocity(
            self.p_ned,
            self.yaw_rad,
            self.v_cmd,
            self.cmd_body,
            self.hold_ned,
            self.hold_active,
            self.config,
        )
        r_cmd = commanded_yaw_rate(
            self.yaw_rad,
            self.yaw_rate_cmd_rad_s,
            self.yaw_hold_rad,
            self.yaw_hold_active,
            self.config,
        )
        if self.rstate is None:
            a, v_new, r_new = lag_step(
                self.v_ned, self.yaw_rate_rad_s, v_cmd, r_cmd, dt_s, self.config
            )
        else:
            a, v_new, r_new = self._realistic_step(v_cmd, r_cmd, dt_s)
        resting = (self.p_ned[:, 2] >= 0.0) & (v_new[:, 2] >= 0.0)  # on the ground, not climbing
        v_new[resting] = 0.0
        a[resting] = 0.0
        self.a_ned = a
        p_new = self.p_ned + 0.5 * (self.v_ned + v_new) * dt_s
        self.yaw_rad = wrap_angle(self.yaw_rad + 0.5 * (self.yaw_rate_rad_s + r_new) * dt_s)
        self.p_ned, self.v_ned = ground_contact(p_new, v_new)
        self.yaw_rate_rad_s = r_new
        self.t_s += dt_s
        if self.rstate is not None and self.realistic is not None:
            rd.update_report_state(self.rstate, self.p_ned, self.v_ned, self.yaw_rad,
                                   self.yaw_rate_rad_s, self.a_ned, dt_s, self.realistic)  # fmt: skip

    def _realistic_step(
        self, v_cmd: FloatArray, r_cmd: FloatArray, dt_s: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Truth step of the realistic model: velocity commands through the delay and the
        shaped reference, holds straight into the tilt loop; on the ground no wander."""
        st, cfg = self.rstate, self.realistic
        assert st is not None and cfg is not None
        v_old, r_old = self.v_ned.copy(), self.yaw_rate_rad_s.copy()
        # the autopilot flies its own estimate: its velocity loop brings the *reported*
        # velocity (truth + bias) to the command, so the truth flies the command minus the bias
        v_cmd = v_cmd - np.einsum("nij,nj->ni", rot_z(self.yaw_rad), st.vel_bias_heading)
        # position holds: the ideal law's velocity, flown by the tilt loop
        v, a, r = rd.advance(st, self.v_ned, self.a_ned, self.yaw_rate_rad_s, v_cmd, r_cmd,
                             dt_s, cfg, direct=self.hold_active)  # fmt: skip
        yaw_hold = self.yaw_hold_active
        if yaw_hold.any():
            _, _, r_ideal = lag_step(v_old, r_old, v_cmd, r_cmd, dt_s, self.config)
            r[yaw_hold] = st.r_ref[yaw_hold] = r_ideal[yaw_hold]
            st.r_ref_rate[yaw_hold] = 0.0
        grounded = self.on_ground() & (v_cmd[:, 2] >= 0.0)  # resting, not asked to climb
        v[grounded], a[grounded] = 0.0, 0.0  # no wander lifts it off the ground
        return a, v, r


Vec3 = tuple[float, float, float]


def kinematic_step(
    p_ned: Vec3,
    yaw_rad: float,
    v_ned: Vec3,
    yaw_rate_rad_s: float,
    u_cmd_body: Vec3,
    w_cmd_rad_s: float,
    dt_s: float,
    lag_v: float,
    lag_w: float,
) -> tuple[Vec3, float, Vec3, Vec3, float]:
    """One explicit-Euler step of paper 000's vehicle model (eq. 1), ``p' = R_z(psi) u``,
    ``psi' = w``, of one vehicle: the headless runner's world (:mod:`sim.runner`, both engines).

    The commanded heading-frame velocity ``u_cmd_body`` is rotated by the current yaw; with
    ``lag_v``/``lag_w`` in ``(0, 1]`` (``dt / tau``, 0: none) the flown NED velocity and yaw
    rate move that fraction from the previous ones (``v_ned``, ``yaw_rate_rad_s``) towards the
    command (a discrete first-order autopilot lag). The yaw is not wrapped. Returns ``(p_ned,
    yaw_rad, v_ned, v_body, yaw_rate_rad_s)`` after the step (``v_body`` in the new heading)."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    v0 = c * u_cmd_body[0] - s * u_cmd_body[1]
    v1 = s * u_cmd_body[0] + c * u_cmd_body[1]
    v2 = u_cmd_body[2]
    w = w_cmd_rad_s
    if lag_v > 0.0:
        v0 = v_ned[0] + lag_v * (v0 - v_ned[0])
        v1 = v_ned[1] + lag_v * (v1 - v_ned[1])
        v2 = v_ned[2] + lag_v * (v2 - v_ned[2])
    if lag_w > 0.0:
        w = yaw_rate_rad_s + lag_w * (w - yaw_rate_rad_s)
    p = (p_ned[0] + dt_s * v0, p_ned[1] + dt_s * v1, p_ned[2] + dt_s * v2)
    yaw = yaw_rad + dt_s * w
    c, s = math.cos(yaw), math.sin(yaw)
    return p, yaw, (v0, v1, v2), (c * v0 + s * v1, -s * v0 + c * v1, v2), w


def commanded_velocity(
    p_ned: FloatArray,
    yaw_rad: FloatArray,
    v_cmd: FloatArray,
    cmd_body: np.ndarray,
    hold_ned: FloatArray,
    hold_active: np.ndarray,
    cfg: DynamicsConfig,
) -> FloatArray:
    """NED velocity each vehicle is asked to fly, saturated by the configured limits."""
    v_body_rotated = np.einsum("nij,nj->ni", rot_z(yaw_rad), v_cmd)
    v = np.where(cmd_body[:, None], v_body_rotated, v_cmd)
    v_hold = cfg.k_hold_per_s * (hold_ned - p_ned)
    v_hold[:, :2] = _saturate_norm(v_hold[:, :2], cfg.hold_max_xy_m_s)
    v_hold[:, 2] = np.clip(v_hold[:, 2], -cfg.hold_max_up_m_s, cfg.hold_max_down_m_s)
    v = np.where(hold_active[:, None], v_hold, v)
    v[:, :2] = _saturate_norm(v[:, :2], cfg.v_max_xy_m_s)
    v[:, 2] = np.clip(v[:, 2], -cfg.v_max_up_m_s, cfg.v_max_down_m_s)
    return v


def commanded_yaw_rate(
    yaw_rad: FloatArray,
    yaw_rate_cmd_rad_s: FloatArray,
    yaw_hold_rad: FloatArray,
    yaw_hold_active: np.ndarray,
    cfg: DynamicsConfig,
) -> FloatArray:
    """Yaw rate each vehicle is asked to turn at: the command, or ``k_yaw`` times the yaw error."""
    r = np.where(
        yaw_hold_active, cfg.k_yaw_per_s * wrap_angle(yaw_hold_rad - yaw_rad), yaw_rate_cmd_rad_s
    )
    return np.clip(r, -cfg.yaw_rate_max_rad_s, cfg.yaw_rate_max_rad_s)


def lag_step(
    v_ned: FloatArray,
    yaw_rate_rad_s: FloatArray,
    v_cmd_ned: FloatArray,
    yaw_rate_cmd_rad_s: FloatArray,
    dt_s: float,
    cfg: DynamicsConfig,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """One step of the rate-limited first-order lag: ``(a_ned, v_new, yaw_rate_new)``.

    The acceleration is ``(v_cmd - v) / tau`` with its norm limited to ``accel_max``, and never
    more than what reaches the command in one step (no overshoot for any ``dt``).
    """
    a = (v_cmd_ned - v_ned) / max(cfg.tau_v_s, dt_s)
    a = _saturate_norm(a, cfg.accel_max_m_s2)
    r_dot = np.clip(
        (yaw_rate_cmd_rad_s - yaw_rate_rad_s) / max(cfg.tau_yaw_s, dt_s),
        -cfg.yaw_acc_max_rad_s2,
        cfg.yaw_acc_max_rad_s2,
    )
    return a, v_ned + a * dt_s, yaw_rate_rad_s + r_dot * dt_s


def ground_contact(p_ned: FloatArray, v_ned: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Keep vehicles on or above the ground ``z_ned = 0``: one that reaches it stops descending
    (and, from the next step on, rests without sliding until it climbs)."""
    below = p_ned[:, 2] >= 0.0
    p = p_ned.copy()
    v = v_ned.copy()
    p[below, 2] = 0.0
    v[below, 2] = np.minimum(v[below, 2], 0.0)
    return p, v


def _saturate_norm(x: FloatArray, limit: float) -> FloatArray:
    """Scale rows of ``x`` down to norm ``limit`` where they exceed it."""
    norm = np.linalg.norm(x, axis=-1, keepdims=True)
    scale = np.minimum(1.0, limit / np.maximum(norm, 1e-12))
    return x * scale


# --- what the autopilot reports --------------------------------------------------------------------
@dataclass(frozen=True)
class Observation:
    """Reported state of every vehicle (arrays, vehicle index first)."""

    p_ned: FloatArray
    v_ned: FloatArray
    roll_rad: FloatArray
    pitch_rad: FloatArray
    yaw_rad: FloatArray
    yaw_rate_rad_s: FloatArray


def tilt_from_specific_force(
    a_ned: FloatArray,
    v_ned: FloatArray,
    yaw_rad: FloatArray,
    wind_ned: FloatArray,
    drag_per_s: float,
) -> tuple[FloatArray, FloatArray]:
    """Roll and pitch (FRD, rad) a multicopter needs to produce horizontal acceleration ``a``
    against drag ``-c (v - wind)``: the thrust's horizontal part ``f = a + c (v - wind)``
    expressed in the heading frame gives ``pitch = -atan(f_x / g)``, ``roll = atan(f_y / g)``."""
    f_ned = a_ned[:, :2] + drag_per_s * (v_ned[:, :2] - np.asarray(wind_ned)[:2])
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    f_fwd = c * f_ned[:, 0] + s * f_ned[:, 1]
    f_right = -s * f_ned[:, 0] + c * f_ned[:, 1]
    return np.arctan2(f_right, GRAVITY_MPS2), -np.arctan2(f_fwd, GRAVITY_MPS2)


def observe(world: World, noise: SensorNoise, rng: np.random.Generator) -> Observation:
    """Reported state: truth plus the configured noise, attitude leaning with the thrust; with
    realistic dynamics the EKF-like report of :func:`sim.dynamics.report` plus that noise."""
    n = world.n
    if world.rstate is not None and world.realistic is not None:
        p, v_rep, a_old, yaw_t, rate, att = rd.report(world.rstate, world.realistic, rng)
        roll, pitch = tilt_from_specific_force(
            a_old, v_rep, yaw_t, np.asarray(noise.wind_ned_m_s, dtype=float),
            world.config.drag_per_s,
        )  # fmt: skip
        if noise.velocity_std_m_s > 0.0:
            v_rep = v_rep + rng.normal(0.0, noise.velocity_std_m_s, size=(n, 3))
        return Observation(
            p_ned=p.copy(), v_ned=v_rep, roll_rad=roll + att[0], pitch_rad=pitch + att[1],
            yaw_rad=wrap_angle(yaw_t + att[2]), yaw_rate_rad_s=rate.copy(),
        )  # fmt: skip
    roll, pitch = tilt_from_specific_force(
        world.a_ned,
        world.v_ned,
        world.yaw_rad,
        np.asarray(noise.wind_ned_m_s, dtype=float),
        world.config.drag_per_s,
    )
    v = world.v_ned.copy()
    yaw = world.yaw_rad.copy()
    if noise.velocity_std_m_s > 0.0:
        v += rng.normal(0.0, noise.velocity_std_m_s, size=(n, 3))
    if noise.attitude_std_rad > 0.0:
        att = rng.normal(0.0, noise.attitude_std_rad, size=(3, n))
        roll, pitch, yaw = roll + att[0], pitch + att[1], wrap_angle(yaw + att[2])
    return Observation(
        p_ned=world.p_ned.copy(),
        v_ned=v,
        roll_rad=roll,
        pitch_rad=pitch,
        yaw_rad=yaw,
        yaw_rate_rad_s=world.yaw_rate_rad_s.copy(),
    )


# --- layouts ------------------------------------------------------------------------------------------
def grid_layout(n: int, spacing_m: float = 5.0) -> tuple[FloatArray, FloatArray]:
    """``n`` vehicles on the ground in a square-ish grid (rows along north), all facing north."""
    if n < 1:
        raise ValueError(f"need at least one vehicle, got {n}")
    if not spacing_m > 0.0:
        raise ValueError(f"spacing must be > 0, got {spacing_m}")
    cols = math.ceil(math.sqrt(n))
    idx = np.arange(n)
    p = np.stack([(idx // cols) * spacing_m, (idx % cols) * spacing_m, np.zeros(n)], axis=-1)
    return p.astype(float), np.zeros(n)


def random_layout(
    n: int, box_m: tuple[float, float] = (20.0, 20.0), seed: int = 0, min_separation_m: float = 1.0
) -> tuple[FloatArray, FloatArray]:
    """``n`` vehicles on the ground, uniformly in a ``box_m`` (north, east) box with random yaw,
    at least ``min_separation_m`` apart (rejection sampling; same seed, same layout)."""
    if n < 1:
        raise ValueError(f"need at least one vehicle, got {n}")
    rng = np.random.default_rng(seed)
    p = np.zeros((0, 3))
    for _ in range(1000):
        cand = np.array([rng.uniform(0.0, box_m[0]), rng.uniform(0.0, box_m[1]), 0.0])
        if p.shape[0] == 0 or np.min(np.linalg.norm(p - cand, axis=1)) >= min_separation_m:
            p = np.vstack([p, cand])
            if p.shape[0] == n:
                return p, rng.uniform(-math.pi, math.pi, size=n)
    raise ValueError(f"cannot place {n} vehicles {min_separation_m} m apart in {box_m}")


def formation_layout(path: str | Path) -> tuple[FloatArray, FloatArray, list[int]]:
    """Poses of a formation file (the ``check`` format, :mod:`messages.formation`), in agent-id
    order: ``(p_ned, yaw_rad, ids)``. Raises ``ValueError`` (``FormationError``) on bad input."""
    formation = load_formation(path)
    order = np.argsort(formation.ids)
    return (
        np.array(formation.p_ned[order], dtype=float),
        np.array(formation.yaw_rad[order], dtype=float),
        [int(k) for k in formation.ids[order]],
    )
