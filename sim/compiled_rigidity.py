"""The compiled engine for paper 003's rigidity scenarios (``--engine compiled``).

:func:`run_compiled_rigidity_team` runs the team that
:func:`sim.rigidity_scenarios.run_rigidity_scenario` sets up (``engine="compiled"``) and returns
what that function records (the runner's :class:`sim.runner.Recording` and the layers'
estimates), from :func:`sim.rigidity_kernel.simulate` instead of N Python agent cores with their
rigidity layers. The cores remain the reference (and what the daemons fly); the two engines agree on the
same seed to round-off (``tests/sim/test_rigidity_compiled.py`` bounds the difference).

Supported: the three rigidity scenarios, any :class:`onboard.core.config.AgentConfig` gains,
bearing noise (drawn from the runner's generator in the runner's order), message loss (each copy
of a payload dropped by :func:`sim.draws.lost` for the same ``(step, sender, receiver, kind)`` as
the runner drops it) and latency (delivery ``1 + round(latency / dt)`` steps after publication,
as the runner delivers). Refused with a
:class:`ValueError` naming the option (use engine ``cores``): odometry
noise and bias, camera latency, autopilot lags, the centralized eigen-estimate, a rigidity
period, SfM distances, and graphs other than the complete one.

The first call compiles the kernel (65 s of CPU, 2-3 min on a loaded 2-core machine); numba
caches it next to the sources, so later processes load it in about a second.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from onboard.core.config import AgentConfig, replace_fields
from onboard.geometry import FloatArray, rot_z
from onboard.graph import complete_graph, normalize_edges, reciprocal_pairs
from onboard.rigidity.weights import SensingModel
from onboard.seeded import eigen_restart_block, eigen_start_block
from sim import rigidity_kernel as rk
from sim.runner import Recording, RunnerConfig

MAX_RESTARTS = 16
"""Restarts of each agent's eigen-estimate drawn ahead (the kernel stops beyond them)."""


def parameters(cfg: AgentConfig, runner: RunnerConfig) -> FloatArray:
    """The kernel's float parameters (``rigidity_kernel.P_*``) from the team's config."""
    model = SensingModel(cfg.rigidity.fov_deg, cfg.rigidity.range_m)
    prm = np.zeros(rk.N_PARAMS)
    fov = runner.fov_deg if runner.fov_deg is not None else 360.0
    values = {
        rk.P_DT: runner.dt_s,
        rk.P_K_ANGLE: cfg.rigidity.k_angle_loc,
        rk.P_K_VERTICAL: cfg.rigidity.k_vertical_loc,
        rk.P_K_DISTANCE: cfg.rigidity.k_distance_loc,
        rk.P_LAMBDA_MIN: cfg.rigidity.lambda_min,
        rk.P_LAMBDA_SAFE: cfg.rigidity.lambda_safe,
        rk.P_K_RIGIDITY: cfg.rigidity.k_rigidity,
        rk.P_R_COLL: cfg.rigidity.r_coll_m,
        rk.P_R_SAFE: cfg.rigidity.r_safe_m,
        rk.P_K_COLL: cfg.rigidity.k_collision,
        rk.P_R_TRACK: cfg.rigidity.r_track_m,
        rk.P_K_TRACK_RANGE: cfg.rigidity.k_track_range,
        rk.P_K_TRACK_CAMERA: cfg.rigidity.k_track_camera,
        rk.P_SOFTMIN_TAU: cfg.rigidity.rigidity_softmin_tau,
        rk.P_EIG_STEP: cfg.rigidity.eigen_step,
        rk.P_EIG_KT: cfg.rigidity.eigen_k_t,
        rk.P_EIG_KN: cfg.rigidity.eigen_k_n,
        rk.P_EIG_FORGET: 0.998,
        rk.P_E_G: 0.15,
        rk.P_E_P: 0.5,
        rk.P_E_I: 0.45,
        rk.P_V_MAX: cfg.safety.v_max_m_s,
        rk.P_W_MAX: cfg.safety.yaw_rate_max_rad_s,
        rk.P_PEER_TIMEOUT: cfg.safety.peer_timeout_s,
        rk.P_WARMUP: cfg.rigidity.rigidity_warmup_s,
        rk.P_RANGE_ONE: model.range_full_m,
        rk.P_RANGE_WIDTH: model.range_m - model.range_full_m,
        rk.P_FOV_ONE: model.cos_fov_full,
        rk.P_FOV_WIDTH: model.cos_fov_edge - model.cos_fov_full,
        rk.P_CAM_COS_HALF: -2.0 if fov >= 360.0 else float(np.cos(np.deg2rad(fov) / 2.0)),
        rk.P_CAM_RANGE: runner.sensing_range_m,
        rk.P_YAW_GAIN: 0.2,
        rk.P_MAINTENANCE: 1.0 if cfg.rigidity.rigidity_maintenance else 0.0,
    }
    for key, value in values.items():
        prm[key] = value
    return prm


def _check(configs: Sequence[AgentConfig], runner: RunnerConfig) -> None:
    """Raise :class:`ValueError` for what the kernel does not model (module docstring)."""
    from onboard.estimation.angle_localization import AngleLocalizer
    from onboard.estimation.distributed_eigen import EigenGains

    n = len(configs)
    team = replace_fields(configs[0], agent_id=0, track_target=-1)
    complete = {(int(i), int(j)) for i, j in complete_graph(n)}
    for i, c in enumerate(configs):
        if c.graph.agent_id != i:
            raise ValueError(f"configs[{i}] has agent_id {c.graph.agent_id}: give them in id order")
        if replace_fields(c, agent_id=0, track_target=-1) != team:
            raise ValueError("the compiled engine needs one configuration for the whole team")
    cfg = configs[0]
    if cfg.mode != "rigidity-tracking":
        raise ValueError(
            f"the compiled rigidity engine runs mode 'rigidity-tracking', not {cfg.mode!r}"
        )
    if {tuple(e) for e in cfg.graph.edges} != complete or (
        cfg.rigidity.rigidity_edges and {tuple(e) for e in cfg.rigidity.rigidity_edges} != complete
    ):
        raise ValueError("the compiled rigidity engine needs the complete graph")
    g = EigenGains()
    loc = AngleLocalizer(np.zeros(3))
    unsupported = {
        "rigidity_eigen": cfg.rigidity.rigidity_eigen != "distributed",
        "rigidity_period_s": cfg.rigidity.rigidity_period_s != 0.0,
        "rigidity_scale_from_sfm": cfg.rigidity.rigidity_scale_from_sfm,
        "eigen forget/consensus gains": (
            g.forget,
            g.consensus.e_g,
            g.consensus.e_p,
            g.consensus.e_i,
        )
        != (0.998, 0.15, 0.5, 0.45),
        "yaw_gain": loc.yaw_gain != 0.2,
        "range/fov of the sensing model": math.isinf(cfg.rigidity.range_m)
        or cfg.rigidity.fov_deg >= 360.0,
        "camera_latency_s": runner.camera_latency_s != 0.0,
        "velocity_noise_m_s": runner.velocity_noise_m_s != 0.0,
        "yaw_rate_noise_rad_s": runner.yaw_rate_noise_rad_s != 0.0,
        "velocity_bias_m_s": runner.velocity_bias_m_s != 0.0,
        "tau_v_s": runner.tau_v_s != 0.0,
        "tau_yaw_s": runner.tau_yaw_s != 0.0,
    }
    bad = [k for k, v in unsupported.items() if v]
    if bad:
        raise ValueError(
            f"the compiled rigidity engine does not model {', '.join(bad)}; use engine 'cores'"
        )
    EigenGains(
        columns=cfg.rigidity.eigen_columns,
        step=cfg.rigidity.eigen_step,
        k_t=cfg.rigidity.eigen_k_t,
        k_n=cfg.rigidity.eigen_k_n,
    )


def run_compiled_rigidity_team(
    configs: Sequence[AgentConfig],
    p0_ned: FloatArray,
    yaw0_rad: FloatArray,
    runner: RunnerConfig,
    target_path: Callable[[float], FloatArray],
) -> tuple[Recording, FloatArray, FloatArray, FloatArray, dict[str, int]]:
    """The team of ``configs`` from the true start: the runner's :class:`Recording` and the
    layers' ``(lambda_hat (T, N), p_hat (T, N, 3), yaw_hat (T, N))`` and counters."""
    _check(configs, runner)
    cfg = configs[0]
    n = len(configs)
    k = cfg.rigidity.eigen_columns
    p0 = np.array(p0_ned, dtype=float).reshape(n, 3)
    yaw0 = np.array(yaw0_rad, dtype=float).reshape(n)
    dt = runner.dt_s
    n_steps = round(runner.duration_s / dt)
    frame_every = max(1, round(1.0 / (runner.camera_rate_hz * dt)))
    n_frames = n_steps // frame_every + 1
    # the runner's generator, drawn in its order: yaw offsets, then bearing noise per frame
    rng = np.random.default_rng(runner.seed)
    offsets = rng.uniform(-runner.yaw_offset_max_rad, runner.yaw_offset_max_rad, n)
    n_edges = n * (n - 1)
    sigma = runner.bearing_noise_rad
    if sigma > 0.0:
        noise = np.stack([rng.standard_normal((n_edges, 3)) * sigma for _ in range(n_frames)])
    else:
        noise = np.zeros((1, n_edges, 3))
    # the onboard estimator's own draws (DistributedEigenEstimator.start and its restarts)
    v0 = np.stack([eigen_start_block(cfg.graph.seed, i, k) for i in range(n)])
    restart_v = np.stack(
        [
            np.stack(
                [
                    eigen_restart_block(cfg.graph.seed * 7919 + i, r, k)
                    for r in range(1, MAX_RESTARTS + 1)
                ]
            )
            for i in range(n)
        ]
    )
    p_hat0 = (
        np.array(cfg.graph.p_hat0_ned, dtype=float).reshape(n, 3)
        if cfg.graph.p_hat0_ned
        else np.zeros((n, 3))
    )
    targets = np.stack(
        [
            np.asarray(target_path(f * frame_every * dt), dtype=float).reshape(-1, 3)
            for f in range(n_frames)
        ]
    )
    track = np.array([c.rigidity.track_target for c in configs], dtype=np.int64)
    pairs_r = np.array(runner.range_pairs, dtype=np.int64).reshape(-1, 2)
    (rp, ryaw, rvb, rlam, rph, ryh), (nonfinite, restarts) = rk.simulate(
        p0,
        yaw0,
        offsets,
        p_hat0,
        v0,
        restart_v,
        targets,
        track,
        pairs_r,
        noise,
        parameters(cfg, runner),
        n_steps,
        frame_every,
        runner.record_every,
        1 + round(runner.latency_s / dt),
        runner.loss,
        runner.seed,
    )
    edges = normalize_edges(cfg.graph.edges)
    rec = Recording.allocate(edges, reciprocal_pairs(edges), n, len(rp))
    rec.t_s[:] = np.arange(len(rp)) * runner.record_every * dt
    rec.p_ned[:] = rp
    rec.yaw_rad[:] = ryaw
    rec.v_ned[:] = np.einsum("tnij,tnj->tni", rot_z(ryaw), rvb)
    # in mode rigidity-tracking the paper 000 localization filter keeps its prior
    y_hat0 = (
        np.array(cfg.graph.yaw_hat0_rad, dtype=float) if cfg.graph.yaw_hat0_rad else np.zeros(n)
    )
    rec.p_hat_ned[:] = p_hat0
    rec.yaw_hat_rad[:] = y_hat0
    counters = {"nonfinite_actions": int(nonfinite), "eigen_restarts": int(restarts)}
    return rec, rlam, rph, ryh, counters
