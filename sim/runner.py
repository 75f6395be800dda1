"""Headless runner: N agent cores and a kinematic R^3 x S^1 world on one fixed clock.

The world is paper 000's model (eq. 1): ``p_i' = R_z(psi_i) u_i``, ``psi_i' = w_i`` with the
commanded ``(u_i, w_i)`` flown exactly (explicit Euler, step ``dt``, 2 ms by default). Every
step each core gets only what its vehicle measures:

* its odometry yaw ``psi_i + o_i`` with an unknown constant offset ``o_i`` per vehicle (agents
  share no frame), its body velocity and yaw rate (optionally noisy);
* its latest camera frame: body-frame bearings along the sensing graph, computed from the
  truth at ``camera_rate_hz`` (50 Hz), optionally perturbed by isotropic angular noise;

and the peer payloads that reached it. Payloads are broadcast along the communication graph
(both directions of every sensing edge) and delivered ``1 + round(latency / dt)`` steps later,
each copy lost with probability ``loss``. Truth goes only to the :class:`Recording`. All
randomness comes from the seed: the same seed gives the same run.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from messages.agent import (
    BearingMeasurement,
    OwnMeasurements,
    RangeMeasurement,
    TargetMeasurement,
)
from messages.codec import Payload
from messages.peer import (
    BearingShare,
    ConsensusState,
    ExcitationTable,
    GradientLocalizationShare,
    LocalizationState,
    MotionShare,
    SfmEstimate,
)
from messages.rigidity import AngleLocalizationShare, RigidityEigenShare
from onboard.core.agent import AgentCore
from onboard.core.config import AgentConfig
from onboard.geometry import FloatArray, IntArray, bearings_body, rot_z
from onboard.graph import edge_index, normalize_edges, reciprocal_pairs, sensing_graph
from sim import draws
from sim.camera import noisy_bearings
from sim.world import kinematic_step


@dataclass(frozen=True)
class RunnerConfig:
    """Clock, sensing and network of one headless run."""

    duration_s: float = 20.0
    dt_s: float = 0.002
    camera_rate_hz: float = 50.0
    latency_s: float = 0.0
    """Extra delay of every payload on top of the one-step transport delay."""
    loss: float = 0.0
    """Probability that one copy of a payload is lost (independent per receiver)."""
    bearing_noise_rad: float = 0.0
    """Standard deviation of the angular noise of each bearing (per axis of the tangent plane)."""
    velocity_noise_m_s: float = 0.0
    yaw_rate_noise_rad_s: float = 0.0
    velocity_bias_m_s: float = 0.0
    """Standard deviation of a constant per-vehicle bias of the horizontal body-frame odometry
    velocity (an optical-flow EKF's, sim/dynamics.py). Each vehicle flies on its biased
    estimate: it reports ``v + b`` and truly moves at the setpoint minus ``b``."""
    yaw_offset_max_rad: float = math.pi
    """Odometry yaw offsets are drawn uniformly in ``[-max, max]``."""
    record_every: int = 5
    camera_latency_s: float = 0.0
    """Delay between a frame's capture (its stamp) and its delivery to the core."""
    tau_v_s: float = 0.0
    tau_yaw_s: float = 0.0
    """Autopilot response: the NED velocity and the yaw rate follow the setpoint through
    first-order lags with these time constants (the MAVLink simulator's ``tau_v_s = 0.3``,
    ``tau_yaw_s = 0.2``); 0 is the paper's kinematic model (the setpoint is the velocity)."""
    seed: int = 0
    fov_deg: float | None = None
    """Virtual field of view: when set, a sensing edge is measured only while its target is
    inside the camera cone and ``sensing_range_m`` (``onboard.graph.sensing_graph``)."""
    sensing_range_m: float = math.inf
    range_pairs: tuple[tuple[int, int], ...] = ()
    """Pairs whose distance both ends measure (e.g. UWB), delivered with every camera frame."""
    target_path: Callable[[float], ArrayLike] | None = None
    """True positions ``(T, 3)`` of mission targets at ``t``: with every camera frame each agent
    gets each target's body bearing and distance (``OwnMeasurements.targets``)."""

    def __post_init__(self) -> None:
        if self.dt_s <= 0 or self.duration_s <= 0 or self.camera_rate_hz <= 0:
            raise ValueError("dt_s, duration_s and camera_rate_hz must be positive")
        if not 0.0 <= self.loss < 1.0:
            raise ValueError("loss must be in [0, 1)")
        if self.record_every < 1:
            raise ValueError("record_every must be >= 1")


@dataclass
class Recording:
    """Everything a run produced, sampled every ``record_every`` steps (truth and estimates)."""

    edges: IntArray
    pairs: IntArray
    """Reciprocal pairs ``(i, j)``, ``i < j``: the SfM edges, in the column order of ``chi_*``."""
    t_s: FloatArray
    p_ned: FloatArray
    yaw_rad: FloatArray
    v_ned: FloatArray
    p_hat_ned: FloatArray
    yaw_hat_rad: FloatArray
    chi_hat: FloatArray
    lambda_bar_est: FloatArray
    e_index_est: FloatArray
    k_e: FloatArray
    w_l: FloatArray
    desired_beta_body: FloatArray | None = None
    """``(E, 3)`` desired bearings in edge order, for formation scenarios."""
    dropped: dict[str, int] = field(default_factory=dict)

    @classmethod
    def allocate(cls, edges: IntArray, pairs: IntArray, n_agents: int, n_samples: int) -> Recording:
        """Zeroed arrays for ``n_samples`` samples of ``n_agents`` (``chi_hat`` NaN: no estimate)."""
        n, t = n_agents, n_samples
        return cls(
            edges=edges,
            pairs=pairs,
            t_s=np.zeros(t),
            p_ned=np.zeros((t, n, 3)),
            yaw_rad=np.zeros((t, n)),
            v_ned=np.zeros((t, n, 3)),
            p_hat_ned=np.zeros((t, n, 3)),
            yaw_hat_rad=np.zeros((t, n)),
            chi_hat=np.full((t, len(pairs)), np.nan),
            lambda_bar_est=np.zeros((t, n)),
            e_index_est=np.zeros((t, n)),
            k_e=np.zeros((t, n)),
            w_l=np.zeros((t, n)),
        )

    @property
    def chi_true(self) -> FloatArray:
        r = self.p_ned[:, self.pairs[:, 1]] - self.p_ned[:, self.pairs[:, 0]]
        return 1.0 / np.linalg.norm(r, axis=-1)

    @property
    def chi_error(self) -> FloatArray:
        return self.chi_hat - self.chi_true

    @property
    def excitation_true(self) -> FloatArray:
        """``lambda_ij = u_ij^T P_ij u_ij`` per reciprocal pair from the true motion, ``(T, K)``."""
        i, j = self.pairs[:, 0], self.pairs[:, 1]
        r = self.p_ned[:, j] - self.p_ned[:, i]
        b = r / np.linalg.norm(r, axis=-1, keepdims=True)
        u = self.v_ned[:, j] - self.v_ned[:, i]  # world frame: the norm is frame-free
        return np.maximum(np.sum(u * u, axis=-1) - np.sum(u * b, axis=-1) ** 2, 0.0)

    def lambda_bar_true(self, p: float = -5.0) -> FloatArray:
        lam = np.maximum(self.excitation_true, 1e-12)
        return np.sum(lam**p, axis=1) ** (1.0 / p)

    def beta_body(self) -> FloatArray:
        """True body-frame bearings ``(T, E, 3)``."""
        out = [
            bearings_body(p, y, self.edges)[0]
            for p, y in zip(self.p_ned, self.yaw_rad, strict=True)
        ]
        return np.asarray(out)

    def beta_hat_body(self) -> FloatArray:
        """Bearings of the estimated configuration ``(T, E, 3)``."""
        out = [
            bearings_body(p, y, self.edges)[0]
            for p, y in zip(self.p_hat_ned, self.yaw_hat_rad, strict=True)
        ]
        return np.asarray(out)


def align_yaw_translation(p_est: ArrayLike, p_true: ArrayLike) -> FloatArray:
    """Move ``p_est`` by the rotation about the vertical and the translation (no scaling) that
    best fit ``p_true`` in least squares; returns the aligned ``(N, 3)`` estimate."""
    pe = np.asarray(p_est, dtype=float)
    pt = np.asarray(p_true, dtype=float)
    ce, ct = pe.mean(axis=0), pt.mean(axis=0)
    a, b = pe - ce, pt - ct
    # maximize sum b . R_z(th) a over th (2-D Procrustes on the horizontal components)
    s = np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    c = np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1])
    return (rot_z(math.atan2(s, c)) @ a.T).T + ct


def localization_error(p_est: ArrayLike, p_true: ArrayLike) -> float:
    """RMS position error (m) after aligning yaw and translation, the estimator's free motions."""
    d = align_yaw_translation(p_est, p_true) - np.asarray(p_true, dtype=float)
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


def scale_ratio(p_est: ArrayLike, p_true: ArrayLike) -> float:
    """Size of the estimated formation over the true one (1 = correct scale)."""
    pe = np.asarray(p_est, dtype=float)
    pt = np.asarray(p_true, dtype=float)
    return float(np.linalg.norm(pe - pe.mean(axis=0)) / np.linalg.norm(pt - pt.mean(axis=0)))


def _noisy_unit(b: FloatArray, sigma: float, rng: np.random.Generator) -> FloatArray:
    if sigma <= 0.0:
        return b
    return noisy_bearings(b, rng.standard_normal(b.shape), sigma)


RIGIDITY_PAYLOADS = (AngleLocalizationShare, RigidityEigenShare)
PAYLOAD_KINDS: dict[type, int] = {
    MotionShare: draws.KIND_MOTION,
    LocalizationState: draws.KIND_LOCALIZATION,
    ConsensusState: draws.KIND_CONSENSUS,
    ExcitationTable: draws.KIND_EXCITATION,
    SfmEstimate: draws.KIND_SFM,
    BearingShare: draws.KIND_BEARING,
    AngleLocalizationShare: draws.KIND_ANGLE_LOCALIZATION,
    RigidityEigenShare: draws.KIND_RIGIDITY_EIGEN,
    GradientLocalizationShare: draws.KIND_GRADIENT_LOCALIZATION,
}
"""The loss stream's word for each payload type (:func:`sim.draws.lost`): a copy's fate
depends on what it is, not on the order the engine sends it in."""


def _undirected(edges: IntArray, n: int) -> list[list[int]]:
    """Each agent's neighbours over ``edges`` in either direction, in edge order."""
    out: list[list[int]] = [[] for _ in range(n)]
    for i, j in edges:
        for a, b in ((int(i), int(j)), (int(j), int(i))):
            if b not in out[a]:
                out[a].append(b)
    return out


def run(
    configs: Sequence[AgentConfig],
    p0_ned: ArrayLike,
    yaw0_rad: ArrayLike,
    runner: RunnerConfig = RunnerConfig(),
    progress: Callable[[float], None] | None = None,
    on_record: Callable[[int, float, Sequence[AgentCore]], None] | None = None,
) -> Recording:
    """Run ``len(configs)`` agent cores from the true initial state ``(p0_ned, yaw0_rad)``.

    ``on_record(r, t, cores)`` is called at every recorded sample (extra per-scenario records).
    """
    n = len(configs)
    p0 = np.asarray(p0_ned, dtype=float).reshape(n, 3)
    y0 = np.asarray(yaw0_rad, dtype=float).reshape(n)
    edges = normalize_edges(configs[0].graph.edges)
    pairs = reciprocal_pairs(edges)
    cores = [AgentCore(c) for c in configs]
    rng = np.random.default_rng(runner.seed)
    offsets = rng.uniform(-runner.yaw_offset_max_rad, runner.yaw_offset_max_rad, n).tolist()

    # the cameras see along the formation's edges and the rigidity layer's (AgentConfig)
    extra = configs[0].rigidity.rigidity_edges
    sensed = normalize_edges([*configs[0].graph.edges, *extra]) if extra else edges
    comm = _undirected(edges, n)
    # neighbours only the rigidity layer talks to get only its payloads (as a daemon subscribes)
    comm_rigidity = [
        [b for b in nb if b not in comm[a]] for a, nb in enumerate(_undirected(sensed, n))
    ]
    edge_rows = [np.flatnonzero(sensed[:, 0] == i) for i in range(n)]

    dt = runner.dt_s
    n_steps = round(runner.duration_s / dt)
    frame_every = max(1, round(1.0 / (runner.camera_rate_hz * dt)))
    lag = round(runner.latency_s / dt)
    n_rec = n_steps // runner.record_every + 1
    rec = Recording.allocate(edges, pairs, n, n_rec)

    p = [(float(x[0]), float(x[1]), float(x[2])) for x in p0]
    yaw = y0.tolist()
    v_body = [(0.0, 0.0, 0.0)] * n
    w_body = [0.0] * n
    frames: list[tuple[BearingMeasurement, ...]] = [()] * n
    extras: list[dict[str, tuple]] = [{} for _ in range(n)]
    edge_row = edge_index(sensed)
    pending: dict[int, list[list[Payload]]] = {}
    noise_v = runner.velocity_noise_m_s
    noise_w = runner.yaw_rate_noise_rad_s
    v_ned: list[tuple[float, ...]] = [(0.0, 0.0, 0.0)] * n
    cam_lag = round(runner.camera_latency_s / dt)
    in_flight: dict[int, list[tuple[BearingMeasurement, ...]]] = {}
    bias = [(0.0, 0.0, 0.0)] * n
    if runner.velocity_bias_m_s > 0.0:  # its own stream: the other draws stay the same
        b_rng = np.random.default_rng([runner.seed, 22])
        bias = [
            (float(x), float(y), 0.0)
            for x, y in b_rng.normal(0.0, runner.velocity_bias_m_s, (n, 2))
        ]
    lag_v = min(1.0, dt / runner.tau_v_s) if runner.tau_v_s > 0.0 else 0.0
    lag_w = min(1.0, dt / runner.tau_yaw_s) if runner.tau_yaw_s > 0.0 else 0.0
    r_idx = 0
    report_every = max(1, n_steps // 100)

    for k in range(n_steps + 1):
        t = k * dt
        if k % frame_every == 0:
            beta, _ = bearings_body(np.asarray(p), np.asarray(yaw), sensed)
            beta = _noisy_unit(beta, runner.bearing_noise_rad, rng)
            rows = beta.tolist()
            seen = None
            if runner.fov_deg is not None:
                fov_edges = sensing_graph(p, yaw, runner.fov_deg, runner.sensing_range_m)
                seen = {edge_row[(int(a), int(b))] for a, b in fov_edges if (a, b) in edge_row}
            captured = [
                tuple(
                    BearingMeasurement(int(sensed[e, 1]), tuple(rows[e]), t)
                    for e in edge_rows[i]
                    if seen is None or e in seen
                )
                for i in range(n)
            ]
            in_flight[k + cam_lag] = captured
        if k in in_flight:
            frames = in_flight.pop(k)
            if runner.range_pairs or runner.target_path is not None:
                extras = _extra_measurements(p, yaw, t, runner)
        inboxes = pending.pop(k, None) or [[] for _ in range(n)]
        if noise_v > 0.0 or noise_w > 0.0:
            nz = rng.standard_normal((n, 4)).tolist()
        else:
            nz = None
        setpoints = []
        for i, core in enumerate(cores):
            v, w = v_body[i], w_body[i]
            if runner.velocity_bias_m_s > 0.0:
                bi = bias[i]
                v = (v[0] + bi[0], v[1] + bi[1], v[2])
            if nz is not None:
                e = nz[i]
                v = (v[0] + noise_v * e[0], v[1] + noise_v * e[1], v[2] + noise_v * e[2])
                w = w + noise_w * e[3]
            own = OwnMeasurements(
                t_s=t,
                yaw_rad=yaw[i] + offsets[i],
                v_body=v,
                yaw_rate_rad_s=w,
                bearings=frames[i],
                **extras[i],
            )
            sp, out = core.step(t, own, inboxes[i])
            setpoints.append(sp)
            if out:
                target = pending.setdefault(k + 1 + lag, [[] for _ in range(n)])
                rig_out = [m for m in out if isinstance(m, RIGIDITY_PAYLOADS)]
                for r, msgs in [
                    *((r, out) for r in comm[i]),
                    *((r, rig_out) for r in comm_rigidity[i]),
                ]:
                    if runner.loss > 0.0:
                        target[r].extend(
                            m
                            for m in msgs
                            if not draws.lost(
                                runner.seed, k, i, r, n, PAYLOAD_KINDS[type(m)], runner.loss
                            )
                        )
                    else:
                        target[r].extend(msgs)
        if k % runner.record_every == 0:
            _record(rec, r_idx, t, p, yaw, v_body, cores, pairs)
            if on_record is not None:
                on_record(r_idx, t, cores)
            r_idx += 1
        for i, sp in enumerate(setpoints):
            u, w = sp.v_body, sp.yaw_rate_rad_s
            if runner.velocity_bias_m_s > 0.0:
                bi = bias[i]
                u = (u[0] - bi[0], u[1] - bi[1], u[2])
            p[i], yaw[i], v_ned[i], v_body[i], w_body[i] = kinematic_step(
                p[i], yaw[i], v_ned[i], w_body[i], u, w, dt, lag_v, lag_w
            )
        if progress is not None and (k % report_every == 0 or k == n_steps):
            progress(k / n_steps)
    for core in cores:
        for reason, count in core.dropped.items():
            rec.dropped[reason] = rec.dropped.get(reason, 0) + count
    return rec


def _extra_measurements(
    p: list[tuple[float, float, float]], yaw: list[float], t: float, runner: RunnerConfig
) -> list[dict[str, tuple]]:
    """Per agent: ranges of ``runner.range_pairs`` (both ends) and mission target measurements."""
    n = len(p)
    out: list[dict[str, tuple]] = [{} for _ in range(n)]
    pa = np.asarray(p)
    for a, b in runner.range_pairs:
        d = float(np.linalg.norm(pa[b] - pa[a]))
        for i, j in ((a, b), (b, a)):
            out[i]["ranges"] = (*out[i].get("ranges", ()), RangeMeasurement(j, d, t))
    if runner.target_path is not None:
        targets = np.asarray(runner.target_path(t), dtype=float).reshape(-1, 3)
        r = targets[None, :, :] - pa[:, None, :]
        d = np.linalg.norm(r, axis=-1)
        beta = np.einsum("nji,ntj->nti", rot_z(np.asarray(yaw)), r / d[..., None]).tolist()
        for i in range(n):
            out[i]["targets"] = tuple(
                TargetMeasurement(m, tuple(beta[i][m]), float(d[i, m]), t)
                for m in range(len(targets))
            )
    return out


def _record(
    rec: Recording,
    r: int,
    t: float,
    p: list[tuple[float, float, float]],
    yaw: list[float],
    v_body: list[tuple[float, float, float]],
    cores: list[AgentCore],
    pairs: IntArray,
) -> None:
    rec.t_s[r] = t
    rec.p_ned[r] = p
    rec.yaw_rad[r] = yaw
    y = np.asarray(yaw)
    rec.v_ned[r] = np.einsum("nij,nj->ni", rot_z(y), np.asarray(v_body))
    for i, core in enumerate(cores):
        loc = core.pose
        rec.p_hat_ned[r, i] = loc.p_hat_ned
        rec.yaw_hat_rad[r, i] = loc.yaw_hat_rad
        rec.lambda_bar_est[r, i] = core.lambda_bar
        rec.e_index_est[r, i] = core.e_index
        rec.k_e[r, i] = core.k_e
        rec.w_l[r, i] = core.w_l
    for k, (i, j) in enumerate(pairs):
        chi = cores[int(i)].chi_hat(int(j))
        if chi is not None:
            rec.chi_hat[r, k] = chi


def converged_time(t_s: FloatArray, error: FloatArray, threshold: float = 0.01) -> float | None:
    """First time after which every ``|error|`` stays below ``threshold``; ``None`` if never.

    ``error`` is ``(T, K)``; NaN (no estimate yet) counts as not converged.
    """
    ok = np.all(np.abs(np.nan_to_num(error, nan=np.inf)) < threshold, axis=1)
    if not ok[-1]:
        return None
    bad = np.flatnonzero(~ok)
    return float(t_s[0] if len(bad) == 0 else t_s[bad[-1] + 1])


def summarize(rec: Recording, threshold: float = 0.01) -> dict[str, float | None]:
    """Scalar results of a run (the numbers ``bearingflock scenario --json`` prints)."""
    err = rec.chi_error
    conv = converged_time(rec.t_s, err, threshold)
    final_err = np.abs(err[-1])
    beta_true = bearings_body(rec.p_ned[-1], rec.yaw_rad[-1], rec.edges)[0]
    beta_hat = bearings_body(rec.p_hat_ned[-1], rec.yaw_hat_rad[-1], rec.edges)[0]
    cos_loc = np.clip(np.sum(beta_true * beta_hat, axis=1), -1.0, 1.0)
    out: dict[str, float | None] = {
        "converged_s": conv,
        "converged_s_at_0p02": converged_time(rec.t_s, err, 0.02),
        "lambda_bar_mean": float(np.mean(rec.lambda_bar_true())),
        "final_chi_error_max": float(np.nanmax(final_err))
        if np.any(np.isfinite(final_err))
        else None,
        "final_localization_error": localization_error(rec.p_hat_ned[-1], rec.p_ned[-1]),
        "final_scale_ratio": scale_ratio(rec.p_hat_ned[-1], rec.p_ned[-1]),
        "final_bearing_localization_error_deg": float(np.degrees(np.max(np.arccos(cos_loc)))),
        "final_bearing_error_deg": None,
    }
    if rec.desired_beta_body is not None:
        cos_f = np.clip(np.sum(beta_true * rec.desired_beta_body, axis=1), -1.0, 1.0)
        out["final_bearing_error_deg"] = float(np.degrees(np.max(np.arccos(cos_f))))
    return out
