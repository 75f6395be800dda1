"""The headless runner's compiled engine: paper 000's team at hundreds of times real time.

:func:`run_compiled` takes what :func:`sim.runner.run` takes and returns the same
:class:`sim.runner.Recording`, from :func:`sim.team_kernel.simulate` instead of N Python
:class:`onboard.core.agent.AgentCore` objects. Use it for studies (many seeds, long runs); the cores
remain the reference, and what the daemons fly. The two engines agree on the same seed (tests
compare trajectories, convergence times and estimates), with these differences:

* both lose the same message copies (:func:`sim.draws.lost` of the step sent, the sender, the
  receiver and the payload kind) and add the same noise (the runner's streams, pre-drawn in
  its order), so they agree to round-off with and without loss;
* supported: modes ``active``, ``random``, ``formation``, ``formation-active`` and ``hold``,
  bearing and odometry noise, loss, latency and the autopilot lags. Not: camera latency,
  field of view, ranges, targets, the rigidity layer (:class:`ValueError` names the option).

The first call compiles the kernel (about 30 s on a small machine); numba caches it next
to the sources (``__pycache__``), so later processes load it in about a second.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from onboard.control.random_motion import _BLOCK
from onboard.core.bearings import MAX_ODOMETRY_GAP_S
from onboard.core.config import AgentConfig, replace_fields
from onboard.estimation.localization import MAX_CORRECTION_M_S, MAX_CORRECTION_RAD_S
from onboard.graph import normalize_edges, reciprocal_pairs
from onboard.seeded import active_start_direction
from sim import team_kernel
from sim.runner import Recording, RunnerConfig


class Gains(NamedTuple):
    """The :class:`AgentConfig` values the kernel uses (one set for the whole team)."""

    alpha: float
    h_other: float
    h_floor: float
    chi_min: float
    k_loc_b: float
    k_loc_d: float
    loc_max_m_s: float
    loc_max_rad_s: float
    cons_gamma: float
    cons_kp: float
    cons_ki: float
    k_wl_coupling: float
    w_l_max: float
    p_norm: float
    k_nu: float
    nu_star: float
    k_lambda: float
    k_w: float
    gamma: float
    k_lambda0: float
    e_low: float
    e_high: float
    e_folds_min: float
    k_formation: float
    k_yaw: float
    v_max: float
    w_max: float
    timeout: float
    random_tau_s: float
    w_l_start: float

    @classmethod
    def of(cls, c: AgentConfig) -> Gains:
        s, a, f, lim = c.scale, c.active, c.formation, c.safety
        return cls(
            s.alpha, s.h_other, s.h_floor, s.chi_min_inv_m, s.k_loc_bearing, s.k_loc_distance,
            MAX_CORRECTION_M_S, MAX_CORRECTION_RAD_S, s.consensus_gamma, s.consensus_k_p,
            s.consensus_k_i, a.k_w_l_coupling, a.w_l_max_rad_s, s.p_norm, a.k_nu, a.nu_star,
            a.k_lambda, a.k_w, a.gamma, a.k_lambda0, s.e_low, s.e_high, s.converged_e_folds,
            f.k_formation, f.k_yaw, lim.v_max_m_s, lim.yaw_rate_max_rad_s, lim.peer_timeout_s,
            a.random_tau_s, a.w_l_start_rad_s,
        )  # fmt: skip


def _check(configs: Sequence[AgentConfig], runner: RunnerConfig) -> None:
    team = replace_fields(configs[0], agent_id=0)
    for i, c in enumerate(configs):
        if c.graph.agent_id != i:
            raise ValueError(f"configs[{i}] has agent_id {c.graph.agent_id}: give them in id order")
        if c.mode not in team_kernel.MODE_CODES:
            raise ValueError(f"the compiled engine has no mode {c.mode!r}; use engine 'cores'")
        if c.rigidity.rigidity_maintenance:
            raise ValueError("the compiled engine has no rigidity layer; use engine 'cores'")
        if c.gradloc.localization != "paper000":
            raise ValueError(
                f"the compiled engine flies paper 000's localization, not "
                f"{c.gradloc.localization!r}; use engine 'cores'"
            )
        s = c.scale
        safeguards = (s.sfm_bias_speed_m_s, s.sfm_folds_forget_s, s.sfm_wander_max, s.sfm_bias_gain)
        if any(x != 0.0 for x in safeguards):
            raise ValueError(
                "the compiled engine runs paper 000's SfM observer: set sfm_bias_speed_m_s, "
                "sfm_folds_forget_s, sfm_wander_max and sfm_bias_gain to 0 (sim.scenarios.PAPER_SFM) or use "
                "engine 'cores'"
            )
        if replace_fields(c, agent_id=0) != team:
            raise ValueError("the compiled engine needs one configuration for the whole team")
    unsupported = {
        "camera_latency_s": runner.camera_latency_s != 0.0,
        "fov_deg": runner.fov_deg is not None,
        "range_pairs": bool(runner.range_pairs),
        "target_path": runner.target_path is not None,
        "velocity_bias_m_s": runner.velocity_bias_m_s != 0.0,
    }
    bad = [k for k, v in unsupported.items() if v]
    if bad:
        raise ValueError(f"the compiled engine does not support {', '.join(bad)}")


def _random_motion_noise(cfg: AgentConfig, n_steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Initial directions and the noise rows :class:`RandomMotion` would draw, in its order."""
    n = cfg.graph.n_agents
    z0 = np.zeros((n, 3))
    noise = np.zeros((n, max(n_steps, 1), 3))
    for me in range(n):
        rng = np.random.default_rng(cfg.graph.seed * 1000 + me)
        z0[me] = rng.standard_normal(3)
        rows = [rng.standard_normal((_BLOCK, 3))[::-1] for _ in range(-(-n_steps // _BLOCK))]
        if rows:
            noise[me] = np.concatenate(rows)[:n_steps]
    return z0, noise


def run_compiled(
    configs: Sequence[AgentConfig],
    p0_ned: ArrayLike,
    yaw0_rad: ArrayLike,
    runner: RunnerConfig | None = None,
    progress: Callable[[float], None] | None = None,
) -> Recording:
    """:func:`sim.runner.run` with the compiled engine (see the module docstring)."""
    runner = runner or RunnerConfig()
    _check(configs, runner)
    cfg = configs[0]
    n = len(configs)
    p = np.array(p0_ned, dtype=float).reshape(n, 3)
    yaw = np.array(yaw0_rad, dtype=float).reshape(n)
    edges = normalize_edges(cfg.graph.edges)
    pairs = reciprocal_pairs(edges)
    adj = np.zeros((n, n), dtype=bool)
    adj[edges[:, 0], edges[:, 1]] = True

    dt = runner.dt_s
    n_steps = round(runner.duration_s / dt)
    frame_every = max(1, round(1.0 / (runner.camera_rate_hz * dt)))
    delay = 1 + round(runner.latency_s / dt)
    if delay >= team_kernel.PAIR_HISTORY * frame_every:
        raise ValueError(f"latency {runner.latency_s} s is longer than the frames kept")
    # the runner's random streams, drawn in its order: offsets, then per step frame, odometry
    rng = np.random.default_rng(runner.seed)
    offsets = rng.uniform(-runner.yaw_offset_max_rad, runner.yaw_offset_max_rad, n)
    noisy_v = runner.velocity_noise_m_s > 0.0 or runner.yaw_rate_noise_rad_s > 0.0
    n_frames = n_steps // frame_every + 1
    bearing_noise = np.zeros((n_frames if runner.bearing_noise_rad > 0 else 1, len(edges), 3))
    vel_noise = np.zeros((n_steps + 1 if noisy_v else 1, n, 4))
    if runner.bearing_noise_rad > 0.0 or noisy_v:
        for k in range(n_steps + 1):
            if k % frame_every == 0 and runner.bearing_noise_rad > 0.0:
                bearing_noise[k // frame_every] = rng.standard_normal((len(edges), 3))
            if noisy_v:
                vel_noise[k] = rng.standard_normal((n, 4))

    p_hat = np.array(cfg.graph.p_hat0_ned or [(0.0, 0.0, 0.0)] * n, dtype=float)
    yaw_hat = np.array(cfg.graph.yaw_hat0_rad or [0.0] * n, dtype=float)
    d0 = np.linalg.norm(p_hat[pairs[:, 1]] - p_hat[pairs[:, 0]], axis=1)
    chi = 1.0 / np.maximum(d0 if cfg.graph.p_hat0_ned else np.ones(len(pairs)), 1e-3)
    speed = math.sqrt(2.0 * cfg.active.nu_star)
    u_cmd = np.zeros((n, 3))
    if cfg.mode == "active":
        for me in range(n):
            u_cmd[me] = speed * active_start_direction(cfg.graph.seed, me)  # as motion.Active
    rand_z, rand_noise = (
        _random_motion_noise(cfg, n_steps)
        if cfg.mode == "random"
        else (np.zeros((n, 3)), np.zeros((n, 1, 3)))
    )
    des = np.zeros((n, n, 3))
    has_des = np.zeros((n, n), dtype=bool)
    for i, j, b in cfg.formation.desired_beta_body:
        des[i, j], has_des[i, j] = b, True
    des_yaw = np.array(cfg.formation.desired_yaw_rad or [0.0] * n, dtype=float)

    rec = Recording.allocate(edges, pairs, n, n_steps // runner.record_every + 1)
    team = team_kernel.Team(
        mode=team_kernel.MODE_CODES[cfg.mode],
        n_steps=n_steps,
        dt=dt,
        frame_every=frame_every,
        delay=delay,
        record_every=runner.record_every,
        relay_every=cfg.scale.excitation_relay_every,
        max_odometry_gap_s=MAX_ODOMETRY_GAP_S,
        window_s=cfg.scale.e_window_s,
        adj=adj,
        pair_ends=pairs.astype(np.int64),
        des=des,
        has_des=has_des,
        des_yaw=des_yaw,
        use_des_yaw=bool(cfg.formation.desired_yaw_rad),
        speed=speed,
        seed=int(runner.seed),
        loss=float(runner.loss),
        lag_v=min(1.0, dt / runner.tau_v_s) if runner.tau_v_s > 0.0 else 0.0,
        lag_w=min(1.0, dt / runner.tau_yaw_s) if runner.tau_yaw_s > 0.0 else 0.0,
    )
    noise = team_kernel.Noise(
        bearing=bearing_noise,
        sigma_bearing_rad=float(runner.bearing_noise_rad),
        odometry=vel_noise,
        sigma_v_m_s=float(runner.velocity_noise_m_s),
        sigma_w_rad_s=float(runner.yaw_rate_noise_rad_s),
        random_motion=rand_noise,
    )
    state = team_kernel.State(p, yaw, offsets, p_hat, yaw_hat, chi, u_cmd, rand_z)
    trace = team_kernel.Trace(
        rec.t_s, rec.p_ned, rec.yaw_rad, rec.v_ned, rec.p_hat_ned, rec.yaw_hat_rad,
        rec.chi_hat, rec.lambda_bar_est, rec.e_index_est, rec.k_e, rec.w_l,
    )  # fmt: skip
    team_kernel.simulate(Gains.of(cfg), team, noise, state, trace)
    if progress is not None:
        progress(1.0)
    return rec
