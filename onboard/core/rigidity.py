"""The agent core's rigidity layer: angle localization, distributed eigen-estimation and the
rigidity-maintenance, collision and tracking actions of paper 003, for one vehicle, no I/O.

The core composes one :class:`RigidityLayer` when its mode is ``rigidity-tracking`` or
``rigidity_maintenance`` is on (:data:`onboard.core.modes.MODE_LAYERS`). It steps at most every
``rigidity_period_s`` (between steps it only takes eigen-estimate rounds); per step it

1. takes the current camera frame (the bearings in ``own.bearings``: the graph switches with
   the field of view), re-reads the yaw of the body frame in the estimated frame, and builds
   its star of angles once (:mod:`onboard.estimation.star_rigidity`) over everyone it sees or
   could see;
2. runs angle localization (eq. 10-11, :mod:`onboard.estimation.angle_localization`) with the
   angles it measures, the gradient blocks its neighbours sent, and the measured ranges (or SfM
   distances) for scale;
3. runs one message round of the distributed subspace iteration
   (:mod:`onboard.estimation.distributed_eigen`) on the weighted angle rigidity matrix built from
   the estimates (candidates: every communication neighbour it could see; the sensing weights
   drop those out of view), or, with ``rigidity_eigen = "centralized"``, computes the eigenpair
   from every agent's shared estimate;
4. returns the body-frame actions: ``-V_R'(lambda) grad L`` (eq. 19-23), collision
   avoidance on estimated positions and the target (eq. 30-31) and target tracking (eq. 33),
   from :mod:`onboard.control.rigidity`. ``grad L`` is the gradient of a smooth minimum of
   the tracked modes' eigenvalues (:func:`onboard.control.rigidity.softmin_weights`): the
   modes near the smallest blend in, so the action does not jump where two modes cross
   (paper 003 follows the smallest mode's gradient alone: ``rigidity_softmin_tau = 0``).

It publishes :class:`messages.rigidity.AngleLocalizationShare` and
:class:`messages.rigidity.RigidityEigenShare` every step (the latter's layout:
:class:`EigenWire`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import msgspec
import numpy as np

from messages.agent import OwnMeasurements
from messages.codec import Payload
from messages.rigidity import AngleLocalizationShare, GradientBlock, RigidityEigenShare
from onboard.control import rigidity as ctl
from onboard.core.config import Graph, RigidityGains
from onboard.core.layer import Command, Own
from onboard.core.peers import PeerTable, Route
from onboard.estimation import star_rigidity as st
from onboard.estimation.angle_localization import AngleLocalizer, distance_gradient
from onboard.estimation.distributed_eigen import (
    DistributedEigenEstimator,
    EigenGains,
    Neighbours,
    n_consensus,
    trivial_motion_blocks,
)
from onboard.geometry import FloatArray
from onboard.graph import complete_graph
from onboard.rigidity.angle import weighted_eigenvalues_gradients
from onboard.rigidity.weights import SensingModel

Vec3 = tuple[float, float, float]
FRAME_MAX_AGE_S = 0.2
"""Bearings older than this are not part of the current sensing graph."""
EIGEN_AGREEMENT = 0.5
"""The maintenance acts only while the neighbours' eigenvalue estimates lie within this fraction
of ``lambda_safe`` of the own one (:meth:`RigidityLayer._agreement`)."""
ROUND_TIMEOUT_S = 0.3
"""The eigen-estimate takes its next round once every candidate's share of its previous round
is in, or after this long (a neighbour that went quiet must not stall it)."""


UNCERTAINTY_PERIOD_S = 0.1
"""The estimate's rate of change is measured over this period (the studies' record period)."""
UNCERTAINTY_LAG_S = 0.3
"""How far behind a fast-changing framework the distributed estimate can be: its worst moments
(issue 30: 17-60% in 5 of 10 unseen seeds) are the first 1-2 s of motion, when the eigenvalue
falls 3-8x within 0.4 s and every agent's estimate (agreeing with the others to 1-2%) follows
0.1-0.3 s late; no mode crossing (the next mode is 1.2-4x above) and no consensus disagreement."""
UNCERTAINTY_HOLD_S = 0.2
"""The rate's peak decays with this time constant (an excursion outlasts the fastest change)."""
UNCERTAIN_REL = 0.10
"""``uncertainty / lambda_hat`` above this flags the estimate (status and alarm)."""


def lag_uncertainty(rate_prev: float, lam_prev: float, lam_now: float, dt_s: float) -> float:
    """The decaying peak of ``|d lambda_hat / dt|`` after one period ``dt_s`` (multiply by
    :data:`UNCERTAINTY_LAG_S` for the estimate's uncertainty): how far the eigenvalue may have
    moved since the estimate last caught up with it (README, "Paper 003", reproduced numbers)."""
    rate = abs(lam_now - lam_prev) / dt_s
    return max(rate, rate_prev * math.exp(-dt_s / UNCERTAINTY_HOLD_S))


def estimate_uncertain(lambda_hat: float, uncertainty: float) -> bool:
    """Whether an eigenvalue estimate with this uncertainty is flagged (:data:`UNCERTAIN_REL`)."""
    return uncertainty > UNCERTAIN_REL * abs(lambda_hat)


BLEND_FLOOR = 1e-3
"""Modes whose smooth-minimum weight is below this are left out of the blended gradient (the
others' weights renormalized): a mode 0.07 above the smallest, at the default temperature."""


def _blend(theta: FloatArray, tau: float) -> list[tuple[int, float]]:
    """``(mode, weight)`` of the modes the rigidity action blends
    (:func:`onboard.control.rigidity.softmin_weights`, above :data:`BLEND_FLOOR`)."""
    if len(theta) == 0:
        return []
    pi = ctl.softmin_weights(theta, tau)
    kept = [(m, float(w)) for m, w in enumerate(pi.tolist()) if w >= BLEND_FLOOR]
    total = sum(w for _, w in kept)
    return [(m, w / total) for m, w in kept]


def _keep(j: int, msg: Any) -> bool:
    return True


def _block_for(msg: AngleLocalizationShare, me: int) -> Vec3 | None:
    """The first gradient block ``msg`` addresses to agent ``me`` (``None``: none)."""
    for b in msg.blocks:
        if b.target == me:
            return b.grad_ned
    return None


def _vec(a: FloatArray) -> Vec3:
    return (float(a[0]), float(a[1]), float(a[2]))


def _vecs(a: FloatArray) -> list[Vec3]:
    return [(r[0], r[1], r[2]) for r in a.tolist()]


class EigenWire:
    """The layout of :class:`RigidityEigenShare`'s two vectors for ``k`` vectors per agent.

    ``state`` is ``[x (n_c) | z (n_c) | V_i (3 k, row-major) | degree | sbar]`` and
    ``per_target``, per target, ``[M_w V block (3 k, row-major) | weighted-degree part |
    form-gradient block (3)]`` (:mod:`onboard.estimation.distributed_eigen`). A payload whose
    lengths do not match ``k`` is malformed."""

    def __init__(self, k: int) -> None:
        self.k = k
        self.n_c = n_consensus(k)
        self.state_length = 2 * self.n_c + 3 * k + 2
        self.per_target = 3 * k + 4

    def fits(self, msg: RigidityEigenShare) -> bool:
        """Whether the payload's lengths match this layout."""
        return (
            len(msg.state) == self.state_length
            and len(msg.per_target) == len(msg.targets) * self.per_target
        )

    def pack(
        self,
        x: FloatArray,
        z: FloatArray,
        v: FloatArray,
        degree: int,
        s_bar: float,
        mv: FloatArray,
        s_parts: FloatArray,
        form: FloatArray,
    ) -> tuple[FloatArray, FloatArray]:
        """``(state, per_target)`` from the consensus state ``x, z``, ``V_i`` ``(3, k)``, and per
        target ``(M,)`` its block of ``M_w V`` ``(M, 3, k)``, weighted-degree part ``(M,)`` and
        form-gradient block ``(M, 3)``."""
        state = np.concatenate((x, z, v.ravel(), (float(degree), s_bar)))
        per = np.concatenate((mv.reshape(len(mv), 3 * self.k), s_parts[:, None], form), axis=1)
        return state, per.ravel()

    def unpack(self, msgs: list[RigidityEigenShare]) -> tuple[Neighbours, FloatArray]:
        """The senders' consensus states and their ``V_j`` ``(K, 3, k)``."""
        n_c, k = self.n_c, self.k
        if not msgs:
            return Neighbours.none(n_c), np.zeros((0, 3, k))
        rows = np.array([m.state for m in msgs], dtype=float)
        v = rows[:, 2 * n_c : 2 * n_c + 3 * k].reshape(len(msgs), 3, k)
        return Neighbours(rows[:, :n_c], rows[:, n_c : 2 * n_c], rows[:, -2], rows[:, -1]), v

    def addressed_to(
        self, msgs: list[RigidityEigenShare], me: int
    ) -> tuple[FloatArray, float, FloatArray]:
        """Sums of what the senders addressed to ``me``: blocks of ``M_w V`` ``(3, k)``,
        weighted-degree parts and form-gradient blocks ``(3,)``."""
        per = self.per_target
        parts = [
            m.per_target[(t := m.targets.index(me)) * per : (t + 1) * per]
            for m in msgs
            if me in m.targets
        ]
        if not parts:
            return np.zeros((3, self.k)), 0.0, np.zeros(3)
        total = sum(parts[1:], parts[0])  # a few small adds: cheaper than stacking them
        n = 3 * self.k
        return total[:n].reshape(3, self.k), float(total[n]), total[n + 1 :]


class RigidityLayer:
    """One agent's paper 003 estimators and controller terms (module docstring)."""

    def __init__(self, graph: Graph, gains: RigidityGains, peers: PeerTable,
                 distances: Callable[[], dict[int, float]] | None = None,
                 localizes: bool = True) -> None:  # fmt: skip
        """``peers``: the core's table (its rigidity payloads' senders: :attr:`neighbours`);
        ``distances``: SfM distances per neighbour (paper 000's scale layer), used as scale
        with ``rigidity_scale_from_sfm``; ``localizes``: angle localization is the agent's
        position estimate (its status), as when no scale layer runs."""
        cfg = gains
        self.cfg = gains
        self.graph = graph
        self.peers = peers
        self.id = me = graph.agent_id
        r_edges = gains.rigidity_edges or graph.edges
        self.candidates = sorted({j for i, j in r_edges if i == me})
        self.neighbours = sorted(set(self.candidates) | {i for i, j in r_edges if j == me})
        senders = frozenset(self.neighbours)
        self.routes = {
            AngleLocalizationShare: Route(senders, _keep),  # the table keeps it
            RigidityEigenShare: Route(senders, self.take_eigen),
        }
        self._distances_of = distances
        self.localizes = localizes
        self._t: float | None = None
        self.loc = AngleLocalizer(np.asarray(graph.p0(me), dtype=float))
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
            softmin_tau=cfg.rigidity_softmin_tau,
        )
        # per-round gains: the same for any message rate and team size
        gains = EigenGains(
            columns=cfg.eigen_columns, step=cfg.eigen_step, k_t=cfg.eigen_k_t, k_n=cfg.eigen_k_n
        )
        self.eigen = DistributedEigenEstimator.start(graph.seed, self.id, gains)
        self.wire = EigenWire(self.eigen.gains.columns)
        self.lambda_hat = 0.0
        self.lambda_rate = 0.0  # decaying peak of |d lambda_hat / dt| (lag_uncertainty)
        self._unc_t_s: float | None = None
        self._unc_lam = 0.0
        self.grad_lambda_p = np.zeros(3)
        self.grad_lambda_yaw = 0.0
        self.yaw_hat = 0.0
        self.seen: list[int] = []
        self.u_rigidity = np.zeros(3)
        self.w_rigidity = 0.0
        self._t0: float | None = None
        self._round_t_s = -math.inf
        self._last_share: RigidityEigenShare | None = None
        self._frozen: tuple[FloatArray, dict[int, FloatArray], list[int], st.Star] | None = None
        self.rounds = 0
        """Rounds of the distributed eigen-estimate taken so far."""
        self.agreed = False
        """Whether the candidates' eigenvalue estimates agree with this one (the maintenance
        acts only then)."""
        self.nonfinite = 0
        """Steps whose action was not finite (dropped to zero)."""

    # ------------------------------------------------------------------ inbox
    def take_eigen(self, j: int, msg: RigidityEigenShare) -> bool:
        """Whether neighbour ``j``'s eigen share fits this agent's :class:`EigenWire` (the
        table keeps it)."""
        return self.wire.fits(msg)

    @property
    def _loc_in(self) -> dict[int, AngleLocalizationShare]:
        return self.peers.all(AngleLocalizationShare)

    @property
    def _eig_in(self) -> dict[int, RigidityEigenShare]:
        return self.peers.all(RigidityEigenShare)

    def _fresh(self, stamp_s: float, t_s: float) -> bool:
        return self.peers.is_fresh(stamp_s, t_s)

    # ------------------------------------------------------------------- step
    def step(self, own: Own, outbox: list[Payload]) -> Command | None:
        """Advance the estimators if ``rigidity_period_s`` passed since the last time (else
        take an eigen-estimate round if one is due); the actions of the latest advance."""
        t_s, last = own.t_s, self._t
        if last is None or t_s - last >= self.cfg.rigidity_period_s - 1e-9:
            sfm_d = {} if self._distances_of is None else self._distances_of()
            dt = own.dt_s if last is None else t_s - last
            self.advance(t_s, dt, own.raw, own.yaw_rad, own.v_body, sfm_d, own.seq, outbox)
            self._t = t_s
        else:
            self.eigen_round(t_s, own.seq, outbox)
        u, w = self.u_rigidity, self.w_rigidity
        return Command((float(u[0]), float(u[1]), float(u[2])), float(w))

    def finish(self, own: Own, outbox: list[Payload]) -> None:
        return None

    def forget_time(self) -> None:
        """The clock went back: the next step advances at once."""
        self._t = None

    def status(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "rigidity_eigenvalue": self.lambda_hat,
            "rigidity_eigenvalue_uncertainty": self.lambda_uncertainty,
        }
        if self.localizes:  # angle localization is the position estimate
            out["p_hat_ned"] = tuple(float(x) for x in self.loc.p_hat_ned)
            out["yaw_hat_rad"] = self.yaw_hat
        return out

    @property
    def lambda_uncertainty(self) -> float:
        """How far the true eigenvalue may be from :attr:`lambda_hat` (:func:`lag_uncertainty`)."""
        return UNCERTAINTY_LAG_S * self.lambda_rate

    @property
    def lambda_uncertain(self) -> bool:
        """The estimate is not to be trusted now (uncertainty above :data:`UNCERTAIN_REL`)."""
        return estimate_uncertain(self.lambda_hat, self.lambda_uncertainty)

    def _track_uncertainty(self, t_s: float) -> None:
        if self._unc_t_s is None or t_s < self._unc_t_s:
            self._unc_t_s, self._unc_lam = t_s, self.lambda_hat
        elif t_s - self._unc_t_s >= UNCERTAINTY_PERIOD_S:
            dt = t_s - self._unc_t_s
            self.lambda_rate = lag_uncertainty(self.lambda_rate, self._unc_lam, self.lambda_hat, dt)
            self._unc_t_s, self._unc_lam = t_s, self.lambda_hat

    def advance(
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
        live = [(j, m.p_hat_ned) for j, m in self._loc_in.items() if self._fresh(m.stamp_s, t_s)]
        p_all = np.array([p for _, p in live], dtype=float).reshape(-1, 3)  # one conversion
        p_est = {j: p_all[r] for r, (j, _) in enumerate(live)}
        self.seen, beta = self._current_frame(own, t_s, p_est)
        fresh = {j: m for j, m in self._eig_in.items() if self._fresh(m.stamp_s, t_s)}
        cand = [j for j in self.candidates if j in p_est and j in fresh]

        # 1. yaw in the estimated frame; one star over everyone seen or a candidate
        loc = self.loc
        row = {j: r for r, (j, _) in enumerate(live)}
        if self.seen:
            loc.update_yaw(yaw_odometry_rad, beta, p_all[[row[j] for j in self.seen]])
        self.yaw_hat = loc.yaw_hat(yaw_odometry_rad)
        p_own = loc.p_hat_ned.copy()
        ids = sorted(set(self.seen) | set(cand))
        whole = st.star(p_own, self.yaw_hat, p_all[[row[j] for j in ids]], self.model)
        pos = {j: m for m, j in enumerate(ids)}

        # 2. angle localization (eq. 10-11)
        s_seen = (
            whole
            if ids == self.seen
            else st.restrict(whole, np.array([pos[j] for j in self.seen], dtype=np.int64))
        )
        g_loc = st.angle_gradient(s_seen, beta, cfg.k_angle_loc)[1]
        g_loc += st.vertical_gradient(s_seen, beta, cfg.k_vertical_loc)[1]
        # the own block plus what the neighbours sent, summed in order (one conversion)
        me = self.id
        sent = [
            g
            for j, msg in self._loc_in.items()
            if j in p_est and (g := _block_for(msg, me)) is not None
        ]
        grad = np.concatenate((g_loc[:1], np.array(sent, dtype=float).reshape(-1, 3))).sum(axis=0)
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
                blocks=[
                    GradientBlock(t, g) for t, g in zip(self.seen, _vecs(g_loc[1:]), strict=True)
                ],
            )
        )
        loc.step(dt, v_body, yaw_odometry_rad, grad)

        # 3. eigenvalue and its gradient
        s_cand = (
            whole
            if ids == cand
            else st.restrict(whole, np.array([pos[j] for j in cand], dtype=np.int64))
        )
        self._frozen = (p_own, p_est, cand, s_cand)
        if self._new_round(t_s, fresh, cand):
            self._eigen_step(t_s, p_own, p_est, fresh, cand, s_cand, seq, outbox)
        elif self._last_share is not None:
            # still waiting: send the last round again, so that a share lost on the way
            # stalls the neighbours one step period instead of a whole round trip; numbered
            # by this step, or the receivers' replay window counts the copy as a replay
            outbox.append(msgspec.structs.replace(self._last_share, seq=seq))
        self.agreed = self._agreement(fresh, cand)
        self._track_uncertainty(t_s)

        # 4. actions
        self._actions(own, t_s, p_own, p_all)

    def eigen_round(self, t_s: float, seq: int, outbox: list[Payload]) -> None:
        """Between two :meth:`advance` calls: take an eigen-estimate round if every candidate's
        share of the previous round is in, on the framework of the last step.

        A round per message trip instead of per step: with the layer at 20 Hz and 30 ms of
        latency, rounds waiting for the next step came 5-6 times a second and the estimates
        spread by 15%."""
        if self._frozen is None:
            return
        p_own, p_est, cand, s_cand = self._frozen
        fresh = {j: m for j, m in self._eig_in.items() if self._fresh(m.stamp_s, t_s)}
        if not all(j in fresh for j in cand):  # a candidate went quiet: wait for the next step
            return
        if self._new_round(t_s, fresh, cand):
            self._eigen_step(t_s, p_own, p_est, fresh, cand, s_cand, seq, outbox)
            self.agreed = self._agreement(fresh, cand)

    def _current_frame(
        self, own: OwnMeasurements, t_s: float, p_est: dict[int, FloatArray]
    ) -> tuple[list[int], FloatArray]:
        """The targets of the current frame's bearings, ascending, and the bearings ``(M, 3)``."""
        kept = sorted(
            (
                (b.target, b.beta_body)
                for b in own.bearings
                if b.target in p_est
                and t_s - b.stamp_s <= FRAME_MAX_AGE_S
                and len(b.beta_body) == 3
            ),
            key=lambda x: x[0],
        )
        if not kept:
            return [], np.zeros((0, 3))
        beta = np.array([bb for _, bb in kept], dtype=float)
        norm2 = np.einsum("md,md->m", beta, beta)
        ok = np.abs(norm2 - 1.0) <= 1e-3  # finite unit vectors only (nan and inf compare false)
        return [j for (j, _), good in zip(kept, ok.tolist(), strict=True) if good], beta[ok]

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

    def _agreement(self, fresh: dict[int, RigidityEigenShare], cand: list[int]) -> bool:
        """Whether every candidate's ``lambda_hat`` is within :data:`EIGEN_AGREEMENT` x
        ``lambda_safe`` of this agent's.

        The estimates are one consensus value once the iteration has converged; while it has
        not (start-up, a restarted neighbour, an eigenvalue crossing it is still following on
        a slow, lossy link) one agent's estimate can drop to 0 alone, and the barrier
        ``V'(lambda)`` of eq. 19 turns that into a command of 10^4 m/s. A team that really
        loses rigidity sees every estimate fall together, and is acted on."""
        if self.cfg.rigidity_eigen == "centralized":
            return True
        tol = EIGEN_AGREEMENT * self.gains.lambda_safe
        return bool(cand) and all(abs(fresh[j].lambda_hat - self.lambda_hat) <= tol for j in cand)

    def _new_round(self, t_s: float, fresh: dict[int, RigidityEigenShare], cand: list[int]) -> bool:
        """Whether the eigen-estimate takes a round now.

        The subspace iteration and its consensus are defined in synchronous message rounds
        (:mod:`onboard.estimation.distributed_eigen`): round ``r + 1`` combines the neighbours'
        round ``r``. Stepped at every core tick with messages ``d`` ticks late, each round used
        states ``d`` rounds old, and a delayed consensus is stable only while ``k mu_max d`` stays
        below about ``pi / 2``: with 30 ms of latency at 200 Hz (``d = 7``) the estimate blew up
        to 50x the eigenvalue and collapsed to 0. Waiting until every candidate's share is of
        round ``r`` (or :data:`ROUND_TIMEOUT_S`) keeps ``d = 1`` at any tick rate and latency;
        rounds then come once per message trip."""
        behind = [fresh[j].round for j in cand]
        if any(r < self.rounds for r in behind) and t_s - self._round_t_s < ROUND_TIMEOUT_S:
            return False
        # a (re)started agent joins at its neighbours' round instead of counting up to it
        self.rounds = max(self.rounds, min(behind, default=0)) + 1
        self._round_t_s = t_s
        return True

    def _eigen_step(
        self,
        t_s: float,
        p_own: FloatArray,
        p_est: dict[int, FloatArray],
        fresh: dict[int, RigidityEigenShare],
        cand: list[int],
        s_cand: st.Star,
        seq: int,
        outbox: list[Payload],
    ) -> None:
        cfg = self.cfg
        eig = self.eigen
        wire = self.wire
        msgs = list(fresh.values())
        nbrs, v_all = wire.unpack(msgs)
        if cand == list(fresh):  # every sender is a candidate, in the same order
            v_cand = v_all
        else:
            row = {j: r for r, j in enumerate(fresh)}
            v_cand = v_all[[row[j] for j in cand]]
        mv = st.weighted_matvec(s_cand, eig.v, v_cand)
        s_parts = st.weighted_degree(s_cand)
        mv_in, s_in, form_in = wire.addressed_to(msgs, self.id)
        mv_i = mv[0] + mv_in
        s_i = float(s_parts[0]) + s_in
        # the Ritz vectors' blocks with this agent's view of the Ritz problem (previous round)
        t_blocks = trivial_motion_blocks(np.array([p_own, *[p_est[j] for j in cand]]))
        y = eig.ritz_blocks(np.concatenate([eig.v[None], v_cand]), t_blocks)
        g_form, g_form_yaw = np.zeros((len(cand) + 1, 3)), 0.0
        if y is not None:  # the smooth minimum's gradient: the modes' gradients, blended
            for m, weight in _blend(eig.theta, self.gains.softmin_tau):
                g_m, g_m_yaw = st.form_gradient_only(s_cand, y[0, :, m], y[1:, :, m])
                g_form = g_form + weight * g_m
                g_form_yaw += weight * g_m_yaw
        eig.step(t_blocks[0], mv_i, s_i, nbrs)
        x, z = eig.share()
        # after a restart (the estimator diverged) there is no consensus state to send until
        # its next round: an empty one was counted as malformed by every neighbour
        if len(x) == 0:
            self._last_share = None
        else:
            state, per = wire.pack(
                x, z, eig.v, eig.degree, eig.s_bar, mv[1:], s_parts[1:], g_form[1:]
            )
            self._last_share = RigidityEigenShare(
                sender=self.id,
                seq=seq,
                stamp_s=t_s,
                lambda_hat=eig.lambda_hat,
                targets=cand,
                state=state,
                per_target=per,
                round=self.rounds,
            )
        if self._last_share is not None:
            outbox.append(self._last_share)
        if cfg.rigidity_eigen == "centralized":
            self._centralized(p_own, t_s)
            return
        # |y|^2 = N (Ritz normalization): d lambda/dx = d(y^T M_w y)/dx / N (eq. 21)
        self.lambda_hat = eig.lambda_hat
        self.grad_lambda_p = (g_form[0] + form_in) / self.graph.n_agents
        self.grad_lambda_yaw = g_form_yaw / self.graph.n_agents

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
        lams, gp, gy = weighted_eigenvalues_gradients(
            p, yaw, complete_graph(len(ids)), self.model, self.cfg.eigen_columns
        )
        self.lambda_hat = float(lams[0])
        self.grad_lambda_p = np.zeros(3)
        self.grad_lambda_yaw = 0.0
        for m, weight in _blend(lams, self.gains.softmin_tau):
            self.grad_lambda_p = self.grad_lambda_p + weight * gp[m, me]
            self.grad_lambda_yaw += weight * float(gy[m, me])

    def _actions(
        self, own: OwnMeasurements, t_s: float, p_own: FloatArray, others: FloatArray
    ) -> None:
        """Rigidity, collision and tracking actions; ``others`` ``(K, 3)``: the fresh
        neighbour estimates."""
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
            if cfg.rigidity_maintenance and self.agreed and self.lambda_hat < g.lambda_safe:
                du, dw = ctl.rigidity_control_body(
                    self.lambda_hat, self.grad_lambda_p, self.grad_lambda_yaw, self.yaw_hat, g
                )
                u += du
                w += dw
            if len(others):
                _, gc = ctl.collision_potential(p_own, others, g)
                if gc.any():  # nobody within r_safe: a zero push, in any frame
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
