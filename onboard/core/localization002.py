"""Paper 002's distributed gradient localization as a layer: bearings + SfM ranges, known
rotations (paper 002 eq. 16-17 and 22; docs/distributed.md, "Flying it").

Each agent ``i`` owns its translation ``T_i`` and the scales ``lambda_ij`` of its out-edges
(the edges along which its camera measures ``beta_ij``). Per core step (one gradient round per
step, so its rate is the core's):

1. **Rotations (known).** The frame is paper 000's shared estimated frame: the one of
   :class:`messages.peer.LocalizationState`, fixed by the prior (``p_hat0_ned``,
   ``yaw_hat0_rad``). Agent ``i``'s rotation ``R_i = R_z(psihat_i)`` is the yaw of paper 000's
   filter (eq. 6; the scale layer keeps running it), so ``u_ij = R_z(psihat_i) beta_ij``.
   With ``gradloc_yaw_from_bearings`` the layer estimates ``psihat_i`` itself instead, by
   paper 002's yaw-only rotation estimation (eq. 13-15 on SO(2), :mod:`onboard.distributed.yaw`,
   docs/distributed.md "Yaw-only rotations"): ``psihat_i`` starts at the prior's yaw
   (``yaw_hat0_rad``, as paper 000's filter), is carried by the odometry yaw rate, and takes one
   gradient round per core step of ``sum_j f_R(|wrap(psihat_j - psihat_i - psi_ij)|)`` over the
   reciprocal edges with a relative yaw ``psi_ij`` this step (the camera layer's trackers, from
   reciprocal bearings; :attr:`onboard.core.scale.Scale.rel`) and a fresh share of
   ``psihat_j`` (carried to now with its yaw rate). Step ``1 / (2 b^2 deg_i)``, ``deg_i`` the
   agent's reciprocal edges: the per-agent (Jacobi) form of the SO(3) rule
   (:func:`onboard.distributed.rotation.rotation_lipschitz`), a descent step. The global yaw is
   the gauge the prior fixes; an agent without reciprocal edges keeps the prior's yaw plus its
   odometry.
2. **Carry by odometry.** ``T_i += dt R_i v_i`` and ``lambda_ij += dt u_ij . (v_j - v_i)``
   (paper 002 is static; between rounds the vehicles fly). Neighbours' ``T_j`` are carried from
   their share's stamp to now with the velocity they shared.
3. **One Jacobi-scaled gradient step** of eq. 16 + 22 over the agent's incident edges, from its
   own and its neighbours' latest shared states only: out-edge ``(i, j)`` with ``i``'s own
   ``T_i``, ``lambda_ij``, ``u_ij`` and ``j``'s ``T_j``; in-edge ``(j, i)`` with ``j``'s
   ``T_j`` and ``lambda_ji u_ji``. Gradients from
   :func:`onboard.distributed.localization.localization_gradients`, steps from
   :func:`~onboard.distributed.localization.localization_steps` (``1 / (6 deg_i)`` and
   ``1 / (2 + 4 sqrt(3) + c_D)``: plain descent, which stays convergent with neighbour states
   several rounds late, ``benchmarks/bench_paper002_delay.py``; the accelerated step does not).
   The range term ``f_D(lambda_ij - 1 / chihat_ij)`` is on every reciprocal edge whose SfM
   inverse distance (paper 000 eq. 8, the scale layer's) is at least ``chi_min_inv_m``, as paper
   000's filter uses it: the observer starts at the prior's distance and converges with the
   active motion. A fresh *measured* range ``d_ij`` of the out-edge (``own.ranges``, kept by
   the camera layer :attr:`onboard.core.bearings.Bearings.range_out`, used while
   ``peer_timeout_s`` old like the bearings: the camera pipeline's disc ranges) adds
   ``f_D(lambda_ij - d_ij)`` with its own weight ``gradloc_measured_range_weight`` (the noise
   of a range against a bearing's). Until the scale layer's SfM scale has converged
   (:meth:`onboard.core.scale.Scale.scale_converged`) it *replaces* the SfM term on that edge:
   the camera measures the distance now, while the SfM estimate of the same distance starts at
   the prior's (40% off in the demo) and only converges with motion. From then on both terms
   stay, each with its weight, so the edge's scale settles at their weighted mean: in flight a
   converged SfM distance was the better one (camera e2e, 3 vehicles about 7 m apart: SfM
   median 0.15% off the true distance, the rendered discs' ranges 0.4%). The ``lambda_ij`` step is
   ``1 / (2 + 4 sqrt(3) + c_D)`` with the ``c_D`` of the terms on the edge. With ranges in
   the fleet's graph the ``lambda >= 1`` constraint (eq. 17) is dropped, as the paper says; a
   fleet without reciprocal edges keeps it until the agent uses its first measured range, and
   from then on never again.
4. **Publish** :class:`messages.peer.GradientLocalizationShare`: ``T_i``, ``R_i v_i`` and
   ``lambda_ij u_ij`` per out-edge with a fresh bearing.

A step that would make the state non-finite is not taken (counted ``nonfinite``), an own
velocity beyond :data:`messages.limits.SPEED_MAX_M_S` is not used (``nonfinite_own``); a share
that is non-finite or beyond :mod:`messages.limits` (a core fed without the codec) is counted
``malformed`` and dropped, an entry for an edge this agent does not have ``unknown_edge``.
``T_i`` replaces paper 000's ``phat_i`` for the formation laws (:attr:`Scale.pose`) and the
status; paper 000's filter, SfM observers and consensus are unchanged.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from messages.codec import Payload
from messages.limits import ANGLE_MAX_RAD, POSITION_MAX_M, RATE_MAX_RAD_S, SPEED_MAX_M_S
from messages.peer import GradientLocalizationShare, ScaledBearing
from messages.vocabulary import DropReason
from onboard.core.bearings import Bearings, finite
from onboard.core.config import GradientLocalizationGains, Graph
from onboard.core.layer import Command, Own, Vec3
from onboard.core.peers import Drops, PeerTable, Route
from onboard.core.scale import Scale, rotz
from onboard.distributed.localization import (
    LAMBDA_MIN,
    localization_gradients,
    localization_steps,
)
from onboard.distributed.reshaping import F_R, ReshapeD
from onboard.distributed.rotation import rotation_lipschitz
from onboard.distributed.yaw import yaw_gradients
from onboard.estimation.angles import wrap_rad


def range_edge_gradients(lam: np.ndarray, range_m: np.ndarray, f_d: ReshapeD) -> np.ndarray:
    """``d/d lambda f_D(lambda - d)`` per edge (paper 002 eq. 22), 0 where ``range_m`` is NaN."""
    lam = np.asarray(lam, dtype=float)
    r = np.asarray(range_m, dtype=float)
    has = np.isfinite(r)
    out = np.zeros_like(lam)
    out[has] = f_d.deriv(lam[has] - r[has])
    return out


def _within(v: tuple[float, ...], limit: float) -> bool:
    return finite(v) and all(abs(x) <= limit for x in v)


class GradientLocalization:
    """One agent's paper 002 localization (module docstring)."""

    def __init__(self, graph: Graph, gains: GradientLocalizationGains, peers: PeerTable,
                 bearings: Bearings, scale: Scale, drops: Drops) -> None:  # fmt: skip
        me = graph.agent_id
        self.id = me
        self.peers = peers
        self.bearings = bearings
        self.scale = scale
        self._drops = drops
        self.out_targets = list(bearings.out_targets)
        self.in_sources = list(bearings.in_sources)
        self.routes = {GradientLocalizationShare: Route(peers.neighbours, self._take)}
        self.f_d = ReshapeD(w=gains.gradloc_range_weight)
        self.f_d_measured = ReshapeD(w=gains.gradloc_measured_range_weight)
        edges = set(graph.edges)
        ranged = any((j, i) in edges for i, j in edges)
        self.lambda_min: float | None = None if ranged else LAMBDA_MIN
        """Eq. 17's constraint, only without ranges in the fleet's graph (module docstring)."""
        # the agent's incident edges as a local graph (node 0 = this agent): its own step
        local = [(0, 1 + k) for k in range(len(self.out_targets))]
        local += [(1 + len(self.out_targets) + k, 0) for k in range(len(self.in_sources))]
        arr = np.array(local, dtype=np.int64).reshape(-1, 2)
        h_t, h_l = localization_steps(arr, 1 + len(local), self.f_d)
        self.h_t = float(h_t[0])
        self.h_lambda = float(h_l[0]) if len(h_l) else 0.0
        h_lm = localization_steps(arr, 1 + len(local), self.f_d_measured)[1]
        self.h_lambda_measured = float(h_lm[0]) if len(h_lm) else 0.0
        """The ``lambda_ij`` step on an out-edge with a measured range only (its ``c_D``)."""
        both = ReshapeD(w=gains.gradloc_range_weight + gains.gradloc_measured_range_weight)
        h_lb = localization_steps(arr, 1 + len(local), both)[1]
        self.h_lambda_both = float(h_lb[0]) if len(h_lb) else 0.0
        """... and with a measured range and an SfM distance (the sum of their ``c_D``)."""
        p0 = graph.p0(me)
        self.t_ned: Vec3 = p0
        self.v_ned: Vec3 = (0.0, 0.0, 0.0)
        self.lam: dict[int, float] = {
            j: (max(math.dist(p0, graph.p0(j)), 1e-3) if graph.p_hat0_ned else 1.0)
            for j in self.out_targets
        }
        """``lambda_ij`` per out-edge target ``j`` (m once a range sets the scale)."""
        if self.lambda_min is not None:
            self.lam = {j: max(v, self.lambda_min) for j, v in self.lam.items()}
        self._w_in: dict[int, Vec3] = {}
        """In-edge source ``j`` -> ``lambda_ji u_ji`` of its latest share."""
        self.rounds = 0
        self.range_terms = 0
        """Measured-range terms used so far (one per out-edge and step)."""
        self.own_yaw = gains.gradloc_yaw_from_bearings
        """Whether ``psihat_i`` is this layer's yaw-only estimate (module docstring)."""
        self.psi_hat_rad = float(graph.yaw0(me))
        self.h_yaw = 1.0 / rotation_lipschitz(F_R, len(scale.reciprocal))
        """``1 / (2 b^2 deg_i)`` (module docstring)."""
        self.yaw_rate_rad_s = 0.0
        self.yaw_rounds = 0

    # ----------------------------------------------------------------- pose
    @property
    def p_hat_ned(self) -> Vec3:
        """``T_i``: this agent's position in the shared estimated frame."""
        return self.t_ned

    @property
    def yaw_hat_rad(self) -> float:
        """The known rotation: paper 000's filter yaw, or this layer's yaw-only estimate with
        ``gradloc_yaw_from_bearings`` (module docstring)."""
        return self.psi_hat_rad if self.own_yaw else self.scale.localization.yaw_hat_rad

    def _step_yaw(self, own: Own) -> None:
        """Carry ``psihat_i`` by the odometry, then one round of eq. 13-15 on SO(2)."""
        t_s = own.t_s
        w = own.yaw_rate_rad_s if abs(own.yaw_rate_rad_s) <= RATE_MAX_RAD_S else 0.0
        self.yaw_rate_rad_s = w
        psi = wrap_rad(self.psi_hat_rad + own.dt_s * w)
        nbr, meas = [], []
        for j, (psi_ij, _) in self.scale.rel.items():
            m = self.peers.latest_fresh(GradientLocalizationShare, j, t_s)
            if m is None or m.yaw_hat_rad is None:
                continue
            nbr.append(m.yaw_hat_rad + (t_s - m.stamp_s) * m.yaw_rate_rad_s)
            meas.append(psi_ij)
        if meas:
            k = len(meas)
            edges = np.c_[np.zeros(k, dtype=np.int64), np.arange(1, k + 1)]
            g = float(yaw_gradients([psi, *nbr], edges, meas, F_R).g_src.sum())
            psi = wrap_rad(psi - self.h_yaw * g)
        if math.isfinite(psi):
            self.psi_hat_rad = psi
            self.yaw_rounds += bool(meas)
        else:  # never let a non-finite yaw out: keep the last one
            self._drops.count(DropReason.NONFINITE)

    # ----------------------------------------------------------------- inbox
    def _take(self, j: int, msg: GradientLocalizationShare) -> bool:
        if not (_within(msg.t_ned, POSITION_MAX_M) and _within(msg.v_ned, SPEED_MAX_M_S)):
            return False
        yaw = () if msg.yaw_hat_rad is None else (msg.yaw_hat_rad,)
        if not (_within(yaw, ANGLE_MAX_RAD) and _within((msg.yaw_rate_rad_s,), RATE_MAX_RAD_S)):
            return False
        w: Vec3 | None = None
        for e in msg.edges:
            if not _within(e.w_ned, POSITION_MAX_M):
                return False
            if e.target == self.id:
                if j not in self.in_sources:
                    self._drops.count(DropReason.UNKNOWN_EDGE)
                elif w is None:
                    w = (float(e.w_ned[0]), float(e.w_ned[1]), float(e.w_ned[2]))
        if w is None:
            self._w_in.pop(j, None)
        else:
            self._w_in[j] = w
        return True

    # ------------------------------------------------------------------ step
    def step(self, own: Own, outbox: list[Payload]) -> Command | None:
        t_s, dt = own.t_s, own.dt_s
        if self.own_yaw:
            self._step_yaw(own)
        yaw = self.yaw_hat_rad
        v_i = rotz(yaw, own.v_body)
        if not _within(v_i, SPEED_MAX_M_S):  # beyond what a share may carry: not flown on
            self._drops.count(DropReason.NONFINITE_OWN)
            v_i = (0.0, 0.0, 0.0)
        t_i = self.t_ned
        t_i = (t_i[0] + dt * v_i[0], t_i[1] + dt * v_i[1], t_i[2] + dt * v_i[2])
        lam = dict(self.lam)
        # neighbours' latest shares, carried to now
        nb: dict[int, tuple[Vec3, Vec3]] = {}
        for j, m in self.peers.fresh(GradientLocalizationShare, t_s):
            a = t_s - m.stamp_s
            p, v = m.t_ned, m.v_ned
            nb[j] = ((p[0] + a * v[0], p[1] + a * v[1], p[2] + a * v[2]), v)
        # out-edges: own T_i, lambda_ij, u_ij; j's T_j
        out_j, out_t, out_u, out_r, out_m = [], [], [], [], []
        beta_out, fresh = self.bearings.beta_out, self.peers.is_fresh
        range_out = self.bearings.range_out
        sc = self.scale
        sfm_trusted: bool | None = None  # the scale layer's verdict, asked once if needed
        for j in self.out_targets:
            b = beta_out.get(j)
            if j not in nb or b is None or not fresh(b[0], t_s):
                continue
            u = rotz(yaw, b[1])
            v_j = nb[j][1]
            lam[j] += dt * (u[0] * (v_j[0] - v_i[0]) + u[1] * (v_j[1] - v_i[1])
                            + u[2] * (v_j[2] - v_i[2]))  # fmt: skip
            d = range_out.get(j)
            meas = d[1] if d is not None and fresh(d[0], t_s) else math.nan
            chi = sc.chi_hat(j) if j in sc.reciprocal else None
            rng = 1.0 / chi if chi is not None and chi >= sc.gains.chi_min_inv_m else math.nan
            if math.isfinite(meas) and math.isfinite(rng):
                if sfm_trusted is None:
                    sfm_trusted = sc.scale_converged()
                if not sfm_trusted:  # the measured range replaces an unconverged SfM distance
                    rng = math.nan
            out_j.append(j)
            out_t.append(nb[j][0])
            out_u.append(u)
            out_r.append(rng)
            out_m.append(meas)
        g_t = np.zeros(3)
        g_lam = np.zeros(0)
        if out_j:
            k = len(out_j)
            g = localization_gradients(
                [t_i, *out_t],
                [lam[j] for j in out_j],
                np.c_[np.zeros(k, dtype=np.int64), np.arange(1, k + 1)],
                out_u,
                out_r,
                f_d=self.f_d,
            )
            g_t += g.g_src.sum(axis=0)
            lam_out = np.array([lam[j] for j in out_j])
            g_lam = g.g_edge + range_edge_gradients(lam_out, np.array(out_m), self.f_d_measured)
        # in-edges: j's T_j and lambda_ji u_ji (unit scale on the shared product)
        in_t, in_w = [], []
        for j in self.in_sources:
            if j in nb and j in self._w_in:
                in_t.append(nb[j][0])
                in_w.append(self._w_in[j])
        if in_t:
            k = len(in_t)
            g = localization_gradients(
                [t_i, *in_t],
                np.ones(k),
                np.c_[np.arange(1, k + 1), np.zeros(k, dtype=np.int64)],
                in_w,
            )
            g_t += g.g_dst.sum(axis=0)
        new_t = (t_i[0] - self.h_t * g_t[0], t_i[1] - self.h_t * g_t[1],
                 t_i[2] - self.h_t * g_t[2])  # fmt: skip
        n_measured = sum(1 for m in out_m if math.isfinite(m))
        lam_min = None if n_measured else self.lambda_min  # eq. 17 off with a range (docstring)
        for j, gl, m, r in zip(out_j, g_lam.tolist(), out_m, out_r, strict=True):
            if math.isfinite(m):
                h = self.h_lambda_both if math.isfinite(r) else self.h_lambda_measured
            else:
                h = self.h_lambda
            lam[j] -= h * gl
            if lam_min is not None:
                lam[j] = max(lam[j], lam_min)
        new_t = (float(new_t[0]), float(new_t[1]), float(new_t[2]))
        if _within(new_t, POSITION_MAX_M) and _within(tuple(lam.values()), POSITION_MAX_M):
            self.t_ned, self.lam = new_t, lam
            if out_j or in_t:
                self.rounds += 1
            if n_measured:
                self.range_terms += n_measured
                self.lambda_min = None
        else:  # never let a non-finite (or absurd) estimate out: keep the last one
            self._drops.count(DropReason.NONFINITE)
        self.v_ned = v_i
        edges = []
        for j, u in zip(out_j, out_u, strict=True):
            s = self.lam[j]
            edges.append(ScaledBearing(j, (s * u[0], s * u[1], s * u[2])))
        outbox.append(
            GradientLocalizationShare(
                sender=self.id,
                seq=own.seq,
                stamp_s=t_s,
                t_ned=self.t_ned,
                v_ned=v_i,
                edges=edges,
                yaw_hat_rad=self.psi_hat_rad if self.own_yaw else None,
                yaw_rate_rad_s=self.yaw_rate_rad_s,
            )
        )
        return None

    def finish(self, own: Own, outbox: list[Payload]) -> None:
        return None

    def forget_time(self) -> None:
        """Nothing kept by stamp besides the peer table (cleared by the core); estimates stay."""
        self._w_in.clear()

    def status(self) -> dict[str, Any]:
        return {"p_hat_ned": self.t_ned, "range_terms": self.range_terms}
