"""The agent core's rigidity layer: angle localization, distributed eigen-estimation and the
rigidity-maintenance, collision and tracking actions of paper 003, for one vehicle, no I/O.

:class:`onboard.agent.AgentCore` owns one :class:`RigidityLayer` when its mode is
``rigidity-tracking`` or ``rigidity_maintenance`` is on. Per step the layer

1. takes the current camera frame (the bearings in ``own.bearings``: the graph switches with
   the field of view) and re-reads the yaw of the body frame in the estimated frame;
2. runs angle localization (eq. 10-11, :mod:`onboard.estimation.angle_localization`) with its
   own angles, the gradient blocks its neighbours sent, and the measured ranges (or SfM
   distances) for scale;
3. runs one round of the distributed power iteration
   (:mod:`onboard.estimation.distributed_eigen`) on the weighted angle rigidity matrix built from
   the estimates (candidates: every communication neighbour it could see; the sensing weights
   drop those out of view), or, with ``rigidity_eigen = "centralized"``, computes the eigenpair
   from every agent's shared estimate;
4. returns the body-frame actions: ``-V_R'(lambda) grad lambda`` (eq. 19-23), collision
   avoidance on estimated positions and the target (eq. 30-31) and target tracking (eq. 33),
   from :mod:`onboard.control.rigidity`.

It publishes :class:`messages.rigidity.AngleLocalizationShare` and
:class:`messages.rigidity.RigidityEigenShare` every step.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from messages.agent import OwnMeasurements
from messages.codec import Payload
from messages.rigidity import AngleLocalizationShare, RigidityEigenShare
from onboard.control import rigidity as ctl
from onboard.estimation.angle_localization import (
    AngleLocalizer,
    distance_gradient,
    local_angle_gradient,
    local_vertical_gradient,
)
from onboard.estimation.distributed_eigen import (
    DistributedEigenEstimator,
    EigenGains,
    local_gram_and_form_gradient,
    trivial_motion_block,
)
from onboard.geometry import FloatArray
from onboard.graph import complete_graph
from onboard.rigidity.angle import weighted_eigenvalue_gradient
from onboard.rigidity.weights import SensingModel

if TYPE_CHECKING:
    from onboard.agent import AgentConfig

Vec3 = tuple[float, float, float]
FRAME_MAX_AGE_S = 0.2
"""Bearings older than this are not part of the current sensing graph."""


def _vec(a: FloatArray) -> Vec3:
    return (float(a[0]), float(a[1]), float(a[2]))


class RigidityLayer:
    """One agent's paper 003 estimators and controller terms (module docstring)."""

    def __init__(self, cfg: AgentConfig, out_targets: list[int], neighbours: list[int]) -> None:
        self.cfg = cfg
        self.id = cfg.agent_id
        self.candidates = list(out_targets)
        self.neighbours = list(neighbours)
        p0 = cfg.p_hat0_ned[self.id] if cfg.p_hat0_ned else (0.0, 0.0, 0.0)
        self.loc = AngleLocalizer(np.asarray(p0, dtype=float))
        self.model = SensingModel(cfg.fov_deg, cfg.range_m)
        self.gains = ctl.MaintenanceGains(
            lambda_min=cfg.lambda_min,
            lambda_safe=cfg.lambda_safe,
            k_rigidity=cfg.k_rigidity,
            r_coll_m=cfg.r_coll_m,
            r_safe_m=cfg.r_safe_m,
            k_collision=cfg.k_collision,
            r_track_m=cfg.r_track_m,
            k_track_range=cfg.k_track_range,
            k_track_camera=cfg.k_track_camera,
        )
        eg = EigenGains(
            k_m=cfg.eigen_k_m,
            k_t=cfg.eigen_k_t,
            k_n=cfg.eigen_k_n,
            gamma=cfg.eigen_gamma,
            k_p=cfg.eigen_k_p,
            k_i=cfg.eigen_k_i,
            momentum=cfg.eigen_momentum,
        )
        self.eigen = DistributedEigenEstimator.start(cfg.seed, self.id, eg)
        self._loc_in: dict[int, AngleLocalizationShare] = {}
        self._eig_in: dict[int, RigidityEigenShare] = {}
        self.lambda_hat = 0.0
        self.grad_lambda_p = np.zeros(3)
        self.grad_lambda_yaw = 0.0
        self.yaw_hat = 0.0
        self.seen: list[int] = []
        self.u_rigidity = np.zeros(3)
        self.w_rigidity = 0.0
        self._t0: float | None = None
        self.nonfinite = 0
        """Steps whose action was not finite (dropped to zero)."""

    # ------------------------------------------------------------------ inbox
    def receive(self, j: int, msg: Payload) -> bool:
        """Keep the latest rigidity payload of neighbour ``j``; False if malformed."""
        if isinstance(msg, AngleLocalizationShare):
            if len(msg.targets) != len(msg.grad_ned):
                return False
            self._loc_in[j] = msg
        elif isinstance(msg, RigidityEigenShare):
            if not (len(msg.targets) == len(msg.mv) == len(msg.form_grad_ned)):
                return False
            self._eig_in[j] = msg
        return True

    def _fresh(self, stamp_s: float, t_s: float) -> bool:
        return t_s - stamp_s <= self.cfg.peer_timeout_s

    def _received_blocks(self, inbox: dict, field: str, t_s: float) -> FloatArray:
        """Sum of the blocks neighbours addressed to this agent in ``field``."""
        total = np.zeros(3)
        for msg in inbox.values():
            if not self._fresh(msg.stamp_s, t_s):
                continue
            for target, block in zip(msg.targets, getattr(msg, field), strict=True):
                if target == self.id:
                    total += block
        return total

    # ------------------------------------------------------------------- step
    def step(
        self,
        t_s: float,
        dt: float,
        own: OwnMeasurements,
        yaw_odometry_rad: float,
        v_body: Vec3,
        sfm_distances: dict[int, float],
        seq: int,
        outbox: list[Payload],
    ) -> None:
        """Advance estimators and compute the actions (read them from the attributes)."""
        cfg = self.cfg
        p_est = {
            j: np.asarray(m.p_hat_ned, dtype=float)
            for j, m in self._loc_in.items()
            if self._fresh(m.stamp_s, t_s)
        }
        frame = self._current_frame(own, t_s, p_est)
        self.seen = [j for j, _ in frame]
        beta = np.array([b for _, b in frame]).reshape(-1, 3)
        p_seen = np.array([p_est[j] for j in self.seen]).reshape(-1, 3)

        # 1-2. yaw in the estimated frame, angle localization (eq. 10-11)
        loc = self.loc
        if self.seen:
            loc.update_yaw(yaw_odometry_rad, beta, p_seen)
        self.yaw_hat = loc.yaw_hat(yaw_odometry_rad)
        p_own = loc.p_hat_ned.copy()
        _, g_loc = local_angle_gradient(p_own, p_seen, beta, cfg.k_angle_loc)
        g_loc += local_vertical_gradient(p_own, p_seen, beta, cfg.k_vertical_loc)[1]
        grad = g_loc[0] + self._received_blocks(self._loc_in, "grad_ned", t_s)
        for j, d in self._distances(own, t_s, sfm_distances).items():
            if j in p_est:
                grad += distance_gradient(p_own, p_est[j], d, cfg.k_distance_loc)[1]
        outbox.append(
            AngleLocalizationShare(
                sender=self.id,
                seq=seq,
                stamp_s=t_s,
                p_hat_ned=_vec(p_own),
                yaw_hat_rad=self.yaw_hat,
                yaw_known=loc.yaw_known,
                targets=list(self.seen),
                grad_ned=[_vec(g) for g in g_loc[1:]],
            )
        )
        loc.step(dt, v_body, yaw_odometry_rad, grad)

        # 3. eigenvalue and its gradient
        self._eigen_step(t_s, dt, p_own, p_est, seq, outbox)

        # 4. actions
        self._actions(own, t_s, p_own, p_est)

    def _current_frame(
        self, own: OwnMeasurements, t_s: float, p_est: dict[int, FloatArray]
    ) -> list[tuple[int, FloatArray]]:
        frame = []
        for b in own.bearings:
            if b.target not in p_est or t_s - b.stamp_s > FRAME_MAX_AGE_S:
                continue
            beta = np.asarray(b.beta_body, dtype=float)
            if beta.shape != (3,) or not np.all(np.isfinite(beta)):
                continue
            if abs(float(beta @ beta) - 1.0) > 1e-3:
                continue
            frame.append((b.target, beta))
        return sorted(frame, key=lambda x: x[0])

    def _distances(
        self, own: OwnMeasurements, t_s: float, sfm_distances: dict[int, float]
    ) -> dict[int, float]:
        out: dict[int, float] = {}
        if self.cfg.rigidity_scale_from_sfm:
            out.update(sfm_distances)
        for r in own.ranges:
            if math.isfinite(r.range_m) and r.range_m > 0.0 and t_s - r.stamp_s <= FRAME_MAX_AGE_S:
                out[r.target] = r.range_m
        return out

    def _eigen_step(
        self,
        t_s: float,
        dt: float,
        p_own: FloatArray,
        p_est: dict[int, FloatArray],
        seq: int,
        outbox: list[Payload],
    ) -> None:
        cfg = self.cfg
        eig = self.eigen
        fresh = {j: m for j, m in self._eig_in.items() if self._fresh(m.stamp_s, t_s)}
        cand = [j for j in self.candidates if j in p_est and j in fresh]
        p_cand = np.array([p_est[j] for j in cand]).reshape(-1, 3)
        v_loc = np.vstack([eig.v, *[np.asarray(fresh[j].v) for j in cand]])
        gram, _, g_form, g_form_yaw = local_gram_and_form_gradient(
            p_own, self.yaw_hat, p_cand, v_loc, self.model
        )
        mv = (gram @ v_loc.ravel()).reshape(-1, 3)
        mv_i = mv[0] + self._received_blocks(fresh, "mv", t_s)
        nbrs = [(m.x, m.z) for m in fresh.values()]
        x = eig.step(dt, trivial_motion_block(p_own), mv_i, nbrs)
        outbox.append(
            RigidityEigenShare(
                sender=self.id,
                seq=seq,
                stamp_s=t_s,
                v=_vec(v_loc[0]),
                x=x,
                z=list(eig.z),
                lambda_hat=eig.lambda_hat,
                targets=cand,
                mv=[_vec(m) for m in mv[1:]],
                form_grad_ned=[_vec(g) for g in g_form[1:]],
            )
        )
        if cfg.rigidity_eigen == "centralized":
            self._centralized(p_own, t_s)
            return
        scale = cfg.n_agents * max(eig.norm2_avg, 1e-9)
        self.lambda_hat = eig.lambda_hat
        self.grad_lambda_p = (g_form[0] + self._received_blocks(fresh, "form_grad_ned", t_s)) / (
            scale
        )
        self.grad_lambda_yaw = g_form_yaw / scale

    def _centralized(self, p_own: FloatArray, t_s: float) -> None:
        """Eigenpair from every agent's shared estimate (all-to-all communication needed)."""
        shares = {
            j: m for j, m in self._loc_in.items() if self._fresh(m.stamp_s, t_s) and m.yaw_known
        }
        ids = sorted([self.id, *shares])
        if len(ids) < 3:
            return
        me = ids.index(self.id)
        p = np.array([p_own if j == self.id else shares[j].p_hat_ned for j in ids])
        yaw = np.array([self.yaw_hat if j == self.id else shares[j].yaw_hat_rad for j in ids])
        lam, gp, gy = weighted_eigenvalue_gradient(p, yaw, complete_graph(len(ids)), self.model)
        self.lambda_hat = lam
        self.grad_lambda_p = gp[me]
        self.grad_lambda_yaw = float(gy[me])

    def _actions(
        self, own: OwnMeasurements, t_s: float, p_own: FloatArray, p_est: dict[int, FloatArray]
    ) -> None:
        cfg = self.cfg
        g = self.gains
        u = np.zeros(3)
        w = 0.0
        if self._t0 is None:
            self._t0 = t_s
        if t_s - self._t0 < cfg.rigidity_warmup_s:  # estimators converge before anyone moves
            self.u_rigidity, self.w_rigidity = u, w
            return
        if self.loc.yaw_known:
            if cfg.rigidity_maintenance:
                du, dw = ctl.rigidity_control_body(
                    self.lambda_hat, self.grad_lambda_p, self.grad_lambda_yaw, self.yaw_hat, g
                )
                u += du
                w += dw
            others = np.array(list(p_est.values())).reshape(-1, 3)
            if len(others):
                _, gc = ctl.collision_potential(p_own, others, g)
                u += ctl.world_to_body_control(gc, 0.0, self.yaw_hat)[0]
        for tm in own.targets:
            beta = np.asarray(tm.beta_body, dtype=float)
            if (
                t_s - tm.stamp_s > FRAME_MAX_AGE_S
                or not np.all(np.isfinite(beta))
                or not (math.isfinite(tm.range_m) and tm.range_m > 0.0)
            ):
                continue
            r_body = tm.range_m * beta
            _, gc = ctl.collision_potential(np.zeros(3), r_body[None, :], g)
            u -= gc  # body frame: the target's position is measured in it
            if tm.target == cfg.track_target:
                du, dw = ctl.tracking_control_body(beta, tm.range_m, g)
                u += du
                w += dw
        if not (np.all(np.isfinite(u)) and math.isfinite(w)):
            self.nonfinite += 1
            u, w = np.zeros(3), 0.0
        self.u_rigidity = u
        self.w_rigidity = w
