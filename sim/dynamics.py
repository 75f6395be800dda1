"""Realistic multicopter dynamics: what real autopilot firmware does that an ideal lag does not.

The ideal model of :mod:`sim.world` flies a velocity command through a first-order lag and
reports the exact state at once: it flatters an estimator. This model (``--dynamics realistic``)
adds, with defaults fitted to ArduCopter 4.7 SITL's measured responses (docs/sim.md, "Realistic
dynamics"; ``benchmarks/bench_sitl_response.py`` measures both side by side):

* a **command delay** ``T_d`` and a **shaped velocity reference**: the delayed command drives a
  second-order filter ``y'' = w^2 (v_cmd(t - T_d) - y) - 2 zeta w y'`` with a lead,
  ``v_ref = y + T_l y'`` (an autopilot's jerk-limited input shaping and velocity loop, seen
  from outside), which gives the measured delay, rise time and overshoot of a velocity step;
* **tilt to accelerate**: the horizontal acceleration is the lean of the thrust, held by an
  attitude loop; the acceleration ``a`` follows the velocity loop's demand
  ``k_v (v_ref - v) + v_ref'`` through a first-order attitude lag ``tau_att``, limited by the
  largest lean angle, and ``v' = a + d``;
* **hover wander**: ``d`` is a disturbance acceleration (gusts, the flow sensor's noise fed
  back through the EKF), an Ornstein-Uhlenbeck process per axis, so the vehicle never rests;
* the **yaw rate** goes through the same delay and second-order shaping;
* an **EKF-like report**: the velocity the autopilot reports is the true one of ``T_r`` ago
  (stamping delay) plus white noise plus a slowly varying bias in the heading frame (an OU
  process with a long time constant, different per vehicle: optical flow's bias), and since
  the autopilot's velocity loop closes on that estimate, the truth flies the command minus the
  bias (a vehicle told to stop drifts at a few cm/s, as SITL does); the attitude
  has white noise and a slowly varying yaw bias; the reported horizontal position
  dead-reckons the velocity error (optical flow has no absolute position).

Every function here is pure (arrays in, arrays out, the random draws passed in); the state
lives in :class:`RealisticState`, advanced by :func:`realistic_step` with a seeded
``numpy.random.Generator``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from onboard.geometry import FloatArray, rot_z

GRAVITY_MPS2 = 9.80665


@dataclass(frozen=True)
class RealisticConfig:
    """Parameters of the realistic model; defaults fitted to ArduCopter 4.7 SITL (optical flow).

    SITL measured (``benchmarks/bench_sitl_response.py --part response``, truth from
    SIM_STATE): a 0 -> 1 m/s body-x step 0.41 s delay (to 10 %), 1.58 s rise (10-90 %), 13 %
    overshoot; a 0 -> 0.5 rad/s yaw-rate step 0.13 s, 0.26 s, 22 %; hover speed 0.081 m/s
    median, 0.114 at p90; reported velocity lag 0 (-0.01 s); hover velocity error about
    3 cm/s per axis. This model (``tests/sim/test_dynamics.py`` holds it to these): 0.41 s,
    1.55 s, 13 %; 0.14 s, 0.25 s, 22 %; hover (wander and bias drift) 0.082 m/s median, 0.134
    at p90."""

    cmd_delay_s: float = 0.12
    """Dead time between a velocity or yaw-rate command and the start of the response."""
    v_omega_rad_s: float = 1.0
    """Natural frequency of the shaped horizontal velocity reference."""
    v_zeta: float = 0.56
    """Damping ratio of the shaped velocity reference."""
    v_lead_s: float = 0.34
    """Lead of the shaped velocity reference, ``v_ref = y + lead y'`` (a zero at ``-1/lead``:
    a jerk-limited shaper starts faster than a plain second-order filter)."""
    vz_tau_s: float = 0.3
    """Vertical velocity: first-order lag (the take-off and landing profiles are the
    autopilot flavour's)."""
    k_v_per_s: float = 5.0
    """Gain of the velocity loop on ``v_ref - v`` (acceleration per velocity error)."""
    tau_att_s: float = 0.10
    """Time constant of the attitude loop that leans the thrust (acceleration follows it)."""
    lean_max_rad: float = math.radians(30.0)
    """Largest lean angle: the horizontal acceleration is at most ``g tan(lean_max)``."""
    yaw_omega_rad_s: float = 6.0
    yaw_zeta: float = 0.43
    """Shaped yaw-rate reference (no lead)."""
    yaw_cmd_delay_s: float = 0.06
    wander_accel_std_m_s2: float = 0.25
    """Standard deviation of each horizontal axis of the disturbance acceleration."""
    wander_tau_s: float = 0.5
    """Correlation time of the disturbance."""
    wander_z_ratio: float = 0.8
    """Vertical disturbance, as a fraction of the horizontal one."""
    report_delay_s: float = 0.0
    """Stamping delay: reported state is the true state this long ago, stamped now (SITL's
    LOCAL_POSITION_NED velocity: none measurable, so 0)."""
    vel_noise_std_m_s: float = 0.02
    """White noise on each axis of the reported velocity."""
    vel_bias_std_m_s: float = 0.03
    """Stationary std of each horizontal heading-frame axis of the reported velocity's bias."""
    vel_bias_tau_s: float = 300.0
    """Correlation time of the velocity bias (constant over a mission, different per vehicle)."""
    att_noise_std_rad: float = math.radians(0.2)
    yaw_bias_std_rad: float = math.radians(0.5)
    yaw_bias_tau_s: float = 120.0
    """A slowly varying per-vehicle yaw error; like ``yaw_offset_rad`` it rotates the reported
    yaw and NED velocity together (optical flow: the heading-frame velocity is unaffected)."""
    yaw_offset_rad: float = 0.0
    """A yaw offset common to every vehicle (SITL without GPS: the magnetic declination,
    12.8 degrees at ArduPilot's test site), rotating the reported yaw and NED velocity together
    (the heading-frame velocity is unaffected; the reported position is not rotated)."""
    seed: int = 0

    def __post_init__(self) -> None:
        positive = ("v_omega_rad_s", "v_zeta", "vz_tau_s", "k_v_per_s", "tau_att_s",
                    "lean_max_rad", "yaw_omega_rad_s", "yaw_zeta", "wander_tau_s",
                    "vel_bias_tau_s", "yaw_bias_tau_s")  # fmt: skip
        for name in positive:
            if not getattr(self, name) > 0.0:
                raise ValueError(f"RealisticConfig.{name} must be > 0, got {getattr(self, name)}")
        non_negative = ("cmd_delay_s", "yaw_cmd_delay_s", "wander_accel_std_m_s2",
                        "wander_z_ratio", "report_delay_s", "vel_noise_std_m_s",
                        "vel_bias_std_m_s", "att_noise_std_rad", "yaw_bias_std_rad")  # fmt: skip
        for name in non_negative:
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"RealisticConfig.{name} must be >= 0, got {getattr(self, name)}")


@dataclass
class RealisticState:
    """Internal state of the realistic model for N vehicles (vehicle index first)."""

    y: FloatArray
    """Second-order filter state of the velocity reference (before the lead)."""
    y_rate: FloatArray
    v_ref: FloatArray
    v_ref_rate: FloatArray
    r_ref: FloatArray
    r_ref_rate: FloatArray
    disturbance: FloatArray
    vel_bias_heading: FloatArray
    yaw_bias_rad: FloatArray
    pos_drift_ned: FloatArray
    v_cmd_line: FloatArray
    """Delay line of the NED velocity commands, ``(k, n, 3)``, oldest first."""
    r_cmd_line: FloatArray
    """Delay line of the yaw-rate commands, ``(k, n)``."""
    history: FloatArray
    """Past true states for the stamping delay, ``(k, n, 9)``: p (3), v (3), yaw, yaw rate,
    and the reported velocity error's heading-frame noise-free part is added at report time."""
    a_hist: FloatArray
    """Past accelerations, ``(k, n, 3)``, for the reported attitude."""
    rng: np.random.Generator


def delay_steps(delay_s: float, dt_s: float) -> int:
    """Whole steps of ``dt_s`` closest to ``delay_s`` (at least 1: the newest sample)."""
    return max(1, round(delay_s / dt_s) + 1)


def initial_state(n: int, cfg: RealisticConfig, dt_s: float, p_ned: FloatArray,
                  yaw_rad: FloatArray) -> RealisticState:  # fmt: skip
    """Vehicles at rest; biases drawn from their stationary distributions (seeded)."""
    rng = np.random.default_rng(cfg.seed)
    k_hist = delay_steps(cfg.report_delay_s, dt_s)
    hist = np.zeros((k_hist, n, 9))
    hist[:, :, 0:3] = p_ned
    hist[:, :, 6] = yaw_rad
    return RealisticState(
        y=np.zeros((n, 3)),
        y_rate=np.zeros((n, 3)),
        v_ref=np.zeros((n, 3)),
        v_ref_rate=np.zeros((n, 3)),
        r_ref=np.zeros(n),
        r_ref_rate=np.zeros(n),
        disturbance=rng.normal(0.0, 1.0, (n, 3)) * wander_std(cfg),
        vel_bias_heading=np.concatenate(
            [rng.normal(0.0, cfg.vel_bias_std_m_s, (n, 2)), np.zeros((n, 1))], axis=1
        ),
        yaw_bias_rad=rng.normal(0.0, cfg.yaw_bias_std_rad, n),
        pos_drift_ned=np.zeros((n, 3)),
        v_cmd_line=np.zeros((delay_steps(cfg.cmd_delay_s, dt_s), n, 3)),
        r_cmd_line=np.zeros((delay_steps(cfg.yaw_cmd_delay_s, dt_s), n)),
        history=hist,
        a_hist=np.zeros((k_hist, n, 3)),
        rng=rng,
    )


def wander_std(cfg: RealisticConfig) -> FloatArray:
    """Per-axis stationary std of the disturbance acceleration, ``(3,)``."""
    s = cfg.wander_accel_std_m_s2
    return np.array([s, s, s * cfg.wander_z_ratio])


def push(line: FloatArray, x: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Delay line: append ``x`` as the newest sample, return ``(oldest, new line)``."""
    new = np.concatenate([line[1:], x[None]], axis=0)
    return new[0], new


def ou_step(x: FloatArray, std: FloatArray | float, tau_s: float, dt_s: float,
            white: FloatArray) -> FloatArray:  # fmt: skip
    """Exact discretization of an Ornstein-Uhlenbeck process with stationary std ``std`` and
    correlation time ``tau_s``: ``x e^{-dt/tau} + std sqrt(1 - e^{-2 dt/tau}) w``, ``w ~ N(0,1)``."""
    phi = math.exp(-dt_s / tau_s)
    return x * phi + np.asarray(std) * math.sqrt(1.0 - phi * phi) * white


def shaped_step(y: FloatArray, y_rate: FloatArray, u: FloatArray, omega: float, zeta: float,
                dt_s: float) -> tuple[FloatArray, FloatArray]:  # fmt: skip
    """One semi-implicit Euler step of ``y'' = w^2 (u - y) - 2 zeta w y'``: ``(y, y')``."""
    acc = omega * omega * (u - y) - 2.0 * zeta * omega * y_rate
    y_rate_new = y_rate + dt_s * acc
    return y + dt_s * y_rate_new, y_rate_new


def tilt_step(v_ned: FloatArray, a_ned: FloatArray, v_ref: FloatArray, v_ref_rate: FloatArray,
              disturbance: FloatArray, dt_s: float,
              cfg: RealisticConfig) -> tuple[FloatArray, FloatArray]:  # fmt: skip
    """Horizontal tilt-to-accelerate step: the velocity loop asks for ``k_v (v_ref - v) +
    v_ref'``, limited to ``g tan(lean_max)``; the acceleration (the lean) follows through the
    attitude lag; ``v' = a + d``. Vertical: a first-order lag on ``v_ref``. ``(v, a)``."""
    a_max = GRAVITY_MPS2 * math.tan(cfg.lean_max_rad)
    demand = cfg.k_v_per_s * (v_ref[:, :2] - v_ned[:, :2]) + v_ref_rate[:, :2]
    norm = np.linalg.norm(demand, axis=1, keepdims=True)
    demand = demand * np.minimum(1.0, a_max / np.maximum(norm, 1e-12))
    a = a_ned.copy()
    a[:, :2] = a_ned[:, :2] + (dt_s / max(cfg.tau_att_s, dt_s)) * (demand - a_ned[:, :2])
    a[:, 2] = (v_ref[:, 2] - v_ned[:, 2]) / max(cfg.vz_tau_s, dt_s)
    v = v_ned + dt_s * (a + disturbance)
    return v, a


def reported_velocity(v_true_ned: FloatArray, yaw_true_rad: FloatArray,
                      bias_heading: FloatArray, white: FloatArray) -> FloatArray:  # fmt: skip
    """EKF velocity (NED): the truth plus the heading-frame bias rotated by the true yaw plus
    white noise (``white`` already scaled)."""
    return v_true_ned + np.einsum("nij,nj->ni", rot_z(yaw_true_rad), bias_heading) + white


def rotate_frame(x_ned: FloatArray, angle_rad: float | FloatArray) -> FloatArray:
    """Vectors ``(n, 3)`` of the NED frame as an autopilot whose yaw reads ``angle_rad`` (one
    for all, or one per row) more than the truth reports them: rotated by ``angle_rad`` about
    down, so that its body frame (its yaw) sees the true body-frame vector."""
    a = np.asarray(angle_rad, dtype=float)
    if not a.any():
        return x_ned
    c, s = np.cos(a), np.sin(a)
    out = x_ned.copy()
    out[..., 0] = c * x_ned[..., 0] - s * x_ned[..., 1]
    out[..., 1] = s * x_ned[..., 0] + c * x_ned[..., 1]
    return out


def step_metrics(t_s: np.ndarray, y: np.ndarray, t_step_s: float, target: float) -> dict:
    """Response of ``y(t)`` to a step to ``target`` at ``t_step_s``: delay (first 10 %), rise
    time (10 -> 90 %), overshoot (peak above the target, fraction) and final value (mean of
    the last 2 s)."""
    sel = t_s >= t_step_s
    t, v = t_s[sel] - t_step_s, y[sel]

    def first(level: float) -> float:
        k = np.nonzero(v >= level * target)[0]
        return float(t[k[0]]) if len(k) else math.nan

    t10, t90 = first(0.1), first(0.9)
    final = float(np.mean(v[t >= t[-1] - 2.0])) if len(t) else math.nan
    return {
        "delay_s": t10,
        "rise_s": t90 - t10,
        "overshoot": float(np.max(v) / target - 1.0) if len(v) else math.nan,
        "final": final,
    }


def step_response(cfg: RealisticConfig, dt_s: float, duration_s: float, v_step_m_s: float = 1.0,
                  r_step_rad_s: float = 0.0,
                  wander: bool = False) -> tuple[FloatArray, FloatArray, FloatArray]:  # fmt: skip
    """One vehicle, a step of the body-x velocity (and the yaw rate) at ``t = 0`` from hover:
    ``(t, v_ned (k, 3), yaw_rate (k,))`` of the truth (for fitting and tests)."""
    st = initial_state(1, cfg, dt_s, np.zeros((1, 3)), np.zeros(1))
    if not wander:
        st.disturbance[:] = 0.0
    v, a, r = np.zeros((1, 3)), np.zeros((1, 3)), np.zeros(1)
    cmd = np.array([[v_step_m_s, 0.0, 0.0]])
    steps = round(duration_s / dt_s)
    ts, vs, rs = np.zeros(steps), np.zeros((steps, 3)), np.zeros(steps)
    for k in range(steps):
        v, a, r = advance(st, v, a, r, cmd, np.array([r_step_rad_s]), dt_s, cfg, wander)
        ts[k], vs[k], rs[k] = (k + 1) * dt_s, v[0], r[0]
    return ts, vs, rs


def advance(st: RealisticState, v_ned: FloatArray, a_ned: FloatArray, yaw_rate: FloatArray,
            v_cmd_ned: FloatArray, r_cmd: FloatArray, dt_s: float, cfg: RealisticConfig,
            wander: bool = True,
            direct: np.ndarray | None = None) -> tuple[FloatArray, FloatArray, FloatArray]:  # fmt: skip
    """One step of the truth dynamics (updates the delay lines, the shaped references and the
    disturbance in ``st``): ``(v_ned, a_ned, yaw_rate)``. Vehicles in ``direct`` (position
    holds: the command is the autopilot's own position loop) skip the delay and the shaping."""
    n = v_ned.shape[0]
    v_cmd_d, st.v_cmd_line = push(st.v_cmd_line, v_cmd_ned)
    r_cmd_d, st.r_cmd_line = push(st.r_cmd_line, r_cmd)
    if direct is not None and direct.any():  # restart the shaping from the current velocity
        st.y[direct], st.y_rate[direct] = v_ned[direct], 0.0
        v_cmd_d = v_cmd_d.copy()
        v_cmd_d[direct] = v_cmd_ned[direct]
    y_rate_old = st.y_rate
    st.y, st.y_rate = shaped_step(st.y, st.y_rate, v_cmd_d, cfg.v_omega_rad_s, cfg.v_zeta, dt_s)
    v_ref = st.y + cfg.v_lead_s * st.y_rate
    st.v_ref_rate = st.y_rate + cfg.v_lead_s * (st.y_rate - y_rate_old) / dt_s
    st.v_ref = v_ref
    st.v_ref[:, 2], st.v_ref_rate[:, 2] = v_cmd_d[:, 2], 0.0
    if direct is not None and direct.any():
        st.v_ref[direct], st.v_ref_rate[direct] = v_cmd_ned[direct], 0.0
    st.r_ref, st.r_ref_rate = shaped_step(st.r_ref, st.r_ref_rate, r_cmd_d, cfg.yaw_omega_rad_s,
                                          cfg.yaw_zeta, dt_s)  # fmt: skip
    if wander:
        st.disturbance = ou_step(st.disturbance, wander_std(cfg), cfg.wander_tau_s, dt_s,
                                 st.rng.standard_normal((n, 3)))  # fmt: skip
    v, a = tilt_step(v_ned, a_ned, st.v_ref, st.v_ref_rate, st.disturbance if wander else 0.0 * a_ned, dt_s, cfg)  # fmt: skip
    return v, a, st.r_ref.copy()


def update_report_state(st: RealisticState, p_ned: FloatArray, v_ned: FloatArray,
                        yaw_rad: FloatArray, yaw_rate: FloatArray, a_ned: FloatArray,
                        dt_s: float, cfg: RealisticConfig) -> None:  # fmt: skip
    """After a truth step: drift the EKF's biases, dead-reckon the position error, and push the
    true state into the stamping-delay history."""
    n = p_ned.shape[0]
    white = st.rng.standard_normal((n, 3))
    st.vel_bias_heading[:, :2] = ou_step(st.vel_bias_heading[:, :2], cfg.vel_bias_std_m_s,
                                         cfg.vel_bias_tau_s, dt_s, white[:, :2])  # fmt: skip
    st.yaw_bias_rad = ou_step(st.yaw_bias_rad, cfg.yaw_bias_std_rad, cfg.yaw_bias_tau_s, dt_s,
                              white[:, 2])  # fmt: skip
    bias_ned = np.einsum("nij,nj->ni", rot_z(yaw_rad), st.vel_bias_heading)
    st.pos_drift_ned[:, :2] += dt_s * bias_ned[:, :2]
    row = np.concatenate([p_ned, v_ned, yaw_rad[:, None], yaw_rate[:, None], np.zeros((n, 1))],
                         axis=1)  # fmt: skip
    _, st.history = push(st.history, row)
    _, st.a_hist = push(st.a_hist, a_ned)


def report(st: RealisticState, cfg: RealisticConfig,
           rng: np.random.Generator) -> tuple[FloatArray, ...]:  # fmt: skip
    """What the autopilot reports now: ``(p_ned, v_ned, a_ned, yaw_rad, yaw_rate, att_noise
    (3, n))``, the delayed true state with the EKF's errors; ``rng`` draws the white noise."""
    old = st.history[0]
    n = old.shape[0]
    p, v, yaw, rate = old[:, 0:3], old[:, 3:6], old[:, 6], old[:, 7]
    v_rep = reported_velocity(v, yaw, st.vel_bias_heading,
                              rng.normal(0.0, cfg.vel_noise_std_m_s, (n, 3)))  # fmt: skip
    p_rep = p + st.pos_drift_ned
    att = rng.normal(0.0, cfg.att_noise_std_rad, (3, n))
    att[2] += st.yaw_bias_rad + cfg.yaw_offset_rad
    # optical flow measures the velocity in the body frame and the EKF rotates it with its own
    # yaw: a yaw error (common offset or per-vehicle bias) rotates the NED velocity with it,
    # and the heading-frame velocity stays right (SITL: its 12.8 degree offset does exactly so)
    rot = cfg.yaw_offset_rad + st.yaw_bias_rad
    return (p_rep, rotate_frame(v_rep, rot), st.a_hist[0], yaw, rate, att)
