"""The agent core: one vehicle's estimators and controllers of paper 000, with no I/O.

``AgentCore.step(t_s, own, inbox) -> (setpoint, outbox)`` sees only the vehicle's own
measurements (:class:`messages.agent.OwnMeasurements`) and the peer payloads it received
(:mod:`messages.peer`); it never sees simulator truth. Inside, per step:

1. ingest peer payloads (latest of each kind per neighbour; stale ones are ignored);
2. relative yaw on every reciprocal edge from stamp-matched bearing pairs
   (:mod:`onboard.estimation.relative_yaw`) and ``u_ij = iR_j u_j - u_i`` (eq. 7);
3. one SfM observer (eq. 8, 10) per reciprocal edge whose lower id is this agent; the other end
   receives the result as :class:`messages.peer.SfmEstimate`;
4. the localization filter (eq. 6) with the SfM distances as virtual measurements;
5. ``lambdabar`` (eq. 11) from every edge's excitation, relayed hop by hop
   (:class:`messages.peer.ExcitationTable`; exact after a few steps), and PI average consensus
   (fig. 1) for ``E`` (eq. 10) and, when the formation is constrained, the barycenter ``pbar``
   and ``d lambdabar / d w_l`` (eq. 14). (A PI consensus on ``lambda_k^p`` as in fig. 1 was
   tried first: ``lambda^p`` spans ten decades within 0.4 s when the rotation kicks in, the
   estimator lags, and the over-estimated gradient made eq. 15 diverge.)
6. the controller of the configured mode: ``active`` (eq. 12), ``random`` (the baseline),
   ``formation`` (paper 002 eq. 20 + yaw alignment), ``formation-active`` (eq. 13-16),
   ``rigidity-tracking`` (paper 003: rigidity maintenance, collision avoidance and target
   tracking; paper 000's SfM machinery is off) or ``hold``; the setpoint is saturated.

With mode ``rigidity-tracking`` or ``rigidity_maintenance`` on, a
:class:`onboard.rigidity_layer.RigidityLayer` also runs angle localization and the distributed
rigidity eigen-estimation (paper 003); ``rigidity_maintenance`` adds its rigidity and collision
actions to any mode (e.g. ``formation-active``, whose SfM distances then give the scale).

Explicit Euler with the step's ``dt`` everywhere (the paper's loop is 2 ms).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from messages.agent import AgentStatus, OwnMeasurements, Setpoint
from messages.codec import Payload
from messages.limits import STAMP_FUTURE_MAX_S, stamp_ahead
from messages.peer import (
    BearingShare,
    ConsensusState,
    ExcitationTable,
    LocalizationState,
    MotionShare,
    SfmEstimate,
)
from messages.rigidity import AngleLocalizationShare, RigidityEigenShare
from onboard.agent_config import AgentConfig, Vec3
from onboard.control import active_scale as act
from onboard.control.formation import formation_velocity, yaw_alignment_rate
from onboard.control.random_motion import RandomMotion
from onboard.estimation.consensus import PIConsensus
from onboard.estimation.localization import LocalizationFilter
from onboard.estimation.relative_yaw import RelativeYawEdge
from onboard.estimation.sfm_observer import SfmEdge, WindowAverage, excitation
from onboard.estimation.time_alignment import SignalHistory, step_times
from onboard.rigidity_layer import RigidityLayer

MAX_SFM_STEP_S = 0.01
"""Longest interval one explicit-Euler step of an SfM observer may span (``h dt = 0.1``): longer
intervals between samples are integrated in equal sub-steps."""
MAX_ODOMETRY_GAP_S = 0.25
"""Longest gap between two own (or a peer's) odometry samples the SfM observers integrate across
(an autopilot streams 20-50 Hz); across a longer one they resynchronize after it."""
CONSENSUS_NAMES = frozenset({"e_index", "p_bar", "dlam_dwl", "w_l"})
"""The quantities agents run consensus on (:class:`messages.peer.ConsensusState` names): any
other name from a neighbour is counted (``unknown_name``) and dropped, so a neighbour cannot
grow a receiver's tables (issue 23: 45,000 names per payload took a daemon to 650 MB)."""


def _rotz(psi: float, v: Vec3) -> Vec3:
    c, s = math.cos(psi), math.sin(psi)
    return (c * v[0] - s * v[1], s * v[0] + c * v[1], v[2])


def _saturate(v: Vec3, limit: float) -> Vec3:
    n = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    if n <= limit:
        return v
    k = limit / n
    return (k * v[0], k * v[1], k * v[2])


def _finite(v: Iterable[float]) -> bool:
    return all(math.isfinite(x) for x in v)


class AgentCore:
    """One vehicle's estimators and controllers (paper 000). See the module docstring."""

    def __init__(self, config: AgentConfig) -> None:
        cfg = config
        self.config = cfg
        me = cfg.agent_id
        self.id = me
        self.out_targets = sorted({j for i, j in cfg.edges if i == me})
        self.in_sources = sorted({i for i, j in cfg.edges if j == me})
        self.reciprocal = sorted(set(self.out_targets) & set(self.in_sources))
        self.neighbours = sorted(set(self.out_targets) | set(self.in_sources))
        self.running = [j for j in self.reciprocal if me < j]
        self.paper000 = cfg.mode != "rigidity-tracking"
        if not self.paper000:  # no SfM edges, relative yaws or bearing localization
            self.reciprocal, self.running = [], []
        self.rigidity: RigidityLayer | None = None
        self.rigidity_neighbours: frozenset[int] = frozenset()
        if cfg.mode == "rigidity-tracking" or cfg.rigidity_maintenance:
            r_edges = cfg.rigidity_edges or cfg.edges
            r_out = sorted({j for i, j in r_edges if i == me})
            r_in = {i for i, j in r_edges if j == me}
            self.rigidity_neighbours = frozenset(r_out) | r_in
            self.rigidity = RigidityLayer(cfg, r_out, sorted(self.rigidity_neighbours))

        p0 = cfg.p_hat0_ned or tuple((0.0, 0.0, 0.0) for _ in range(cfg.n_agents))
        y0 = cfg.yaw_hat0_rad or tuple(0.0 for _ in range(cfg.n_agents))
        self.localization = LocalizationFilter(
            tuple(p0[me]), y0[me], cfg.k_loc_bearing, cfg.k_loc_distance
        )
        self.sfm: dict[int, SfmEdge] = {}
        for j in self.running:
            d0 = math.dist(p0[me], p0[j]) if cfg.p_hat0_ned else 1.0
            self.sfm[j] = SfmEdge(
                chi_hat=1.0 / max(d0, 1e-3),
                alpha=cfg.alpha,
                h_other=cfg.h_other,
                h_floor=cfg.h_floor,
                window=WindowAverage(cfg.e_window_s),
                bias_speed_m_s=cfg.sfm_bias_speed_m_s,
                folds_forget_s=cfg.sfm_folds_forget_s,
                wander_window=(
                    WindowAverage(cfg.sfm_wander_window_s) if cfg.sfm_wander_max > 0.0 else None
                ),
                wander_max=cfg.sfm_wander_max,
                folds_cap=0.9 * cfg.converged_e_folds,
            )
        self.yaw_edges = {j: RelativeYawEdge() for j in self.reciprocal}
        # time alignment of the SfM observers (onboard.estimation.time_alignment): own and
        # peer ``(u_x, u_y, u_z, w, yaw)`` histories, the observer's own clock, frames to replay
        self._own_hist = SignalHistory(angle_index=4)
        self._motion_hist = {j: SignalHistory(angle_index=4) for j in self.running}
        self._sfm_t: dict[int, float] = {}
        self._sfm_frames: dict[int, deque[tuple[float, Vec3]]] = {
            j: deque(maxlen=64) for j in self.running
        }
        self.desired = {(i, j): tuple(b) for i, j, b in cfg.desired_beta_body}

        # latest peer data
        self._motion: dict[int, MotionShare] = {}
        self._loc: dict[int, LocalizationState] = {}
        self._beta_in: dict[int, tuple[float, Vec3]] = {}  # j -> (stamp, beta_ji)
        self._sfm_in: dict[int, tuple[float, float]] = {}  # j -> (stamp, chihat_ij)
        self._e_folds_in: dict[int, float] = {}  # j -> e-foldings of edge (j, self)
        self._cons_in: dict[str, dict[int, tuple[float, list[float], list[float]]]] = {}
        self._heard: dict[int, float] = {}
        self._lam_table: dict[tuple[int, int], tuple[float, float]] = {}  # edge -> (stamp, lambda)
        # own bearings
        self._beta_out: dict[int, tuple[float, Vec3]] = {}
        self._last_frame_s = -math.inf
        # consensus and control state
        self._consensus: dict[str, PIConsensus] = {}
        self.lambda_bar = 0.0
        self.e_index = 0.0
        self.k_e = 0.0
        self.w_l = 0.0
        self.dlam_dwl = 0.0
        self.p_bar: Vec3 = (0.0, 0.0, 0.0)
        self.u_cmd: Vec3 = (0.0, 0.0, 0.0)
        self.w_cmd = 0.0
        speed = math.sqrt(2.0 * cfg.nu_star)
        self._random = RandomMotion(
            seed=cfg.seed * 1000 + me, speed_m_s=speed, tau_s=cfg.random_tau_s
        )
        if cfg.mode == "active":
            d = np.random.default_rng(cfg.seed * 1000 + me + 500).standard_normal(3)
            self.u_cmd = tuple((speed * d / np.linalg.norm(d)).tolist())
        self._t: float | None = None
        self._rigidity_t: float | None = None
        self._seq = 0
        self.dropped: dict[str, int] = {}
        self._neighbour_set = frozenset(self.neighbours)
        # the excitation table's keys: the fleet's reciprocal edges, run by their lower id
        edges = set(cfg.edges)
        self._known_edges = frozenset((i, j) for i, j in edges if i < j and (j, i) in edges)
        rigidity_senders = (
            self._neighbour_set if self.rigidity is None else self.rigidity_neighbours
        )
        # per payload type: its handler and who may send it (one lookup per message)
        self._routes: dict[type, tuple[Callable[[int, Any], None], frozenset[int]]] = {
            MotionShare: (self._on_motion, self._neighbour_set),
            LocalizationState: (self._on_localization, self._neighbour_set),
            BearingShare: (self._on_bearings, self._neighbour_set),
            SfmEstimate: (self._on_sfm, self._neighbour_set),
            ExcitationTable: (self._on_excitation, self._neighbour_set),
            ConsensusState: (self._on_consensus, self._neighbour_set),
            AngleLocalizationShare: (self._on_rigidity, rigidity_senders),
            RigidityEigenShare: (self._on_rigidity, rigidity_senders),
        }
        self._cons_out: tuple[list[str], list[list[float]], list[list[float]]] = ([], [], [])

    # ----------------------------------------------------------------- inbox
    def _drop(self, reason: str) -> None:
        self.dropped[reason] = self.dropped.get(reason, 0) + 1

    def _receive(self, msg: Payload, t_s: float) -> None:
        j = msg.sender
        route = self._routes.get(type(msg))
        if j not in (self._neighbour_set if route is None else route[1]):
            self._drop("not_neighbour")
            return
        if route is None:
            self._drop("unknown_type")
            return
        if stamp_ahead(msg.stamp_s, t_s):  # "the newest by stamp" would keep it for good
            self._drop("future_stamp")
            return
        self._heard[j] = t_s
        route[0](j, msg)

    def _on_motion(self, j: int, msg: MotionShare) -> None:
        self._motion[j] = msg
        hist = self._motion_hist.get(j)
        if hist is not None:
            hist.add(msg.stamp_s, (*msg.v_body, msg.yaw_rate_rad_s, msg.yaw_rad))

    def _on_localization(self, j: int, msg: LocalizationState) -> None:
        self._loc[j] = msg

    def _on_bearings(self, j: int, msg: BearingShare) -> None:
        if len(msg.targets) != len(msg.beta_body):
            self._drop("malformed")
            return
        for target, beta in zip(msg.targets, msg.beta_body, strict=True):
            if target == self.id:
                prev = self._beta_in.get(j)
                if prev is None or msg.stamp_s > prev[0]:
                    self._beta_in[j] = (msg.stamp_s, tuple(beta))
                if j in self.yaw_edges:
                    self.yaw_edges[j].add_peer(msg.stamp_s, msg.yaw_rad, tuple(beta))

    def _on_sfm(self, j: int, msg: SfmEstimate) -> None:
        n = len(msg.peers)
        if not (len(msg.chi_hat_inv_m) == len(msg.excitation) == len(msg.e_index) == n):
            self._drop("malformed")
            return
        for m, peer in enumerate(msg.peers):
            if peer == self.id:
                self._sfm_in[j] = (msg.stamp_s, msg.chi_hat_inv_m[m])
                if len(msg.e_folds) == n:
                    self._e_folds_in[j] = msg.e_folds[m]

    def _on_excitation(self, j: int, msg: ExcitationTable) -> None:
        n = len(msg.first)
        if not (len(msg.second) == len(msg.excitation) == len(msg.stamps_s) == n):
            self._drop("malformed")
            return
        table, known = self._lam_table, self._known_edges
        ahead = False
        for a, b, lam, stamp in zip(
            msg.first, msg.second, msg.excitation, msg.stamps_s, strict=True
        ):
            if (a, b) not in known:  # only the fleet's edges: the table stays bounded
                self._drop("unknown_edge")
                continue
            if stamp > msg.stamp_s + STAMP_FUTURE_MAX_S:  # measured after it was sent
                ahead = True
                continue
            prev = table.get((a, b))
            if prev is None or stamp > prev[0]:
                table[(a, b)] = (stamp, lam)
        if ahead:
            self._drop("future_stamp")

    def _on_consensus(self, j: int, msg: ConsensusState) -> None:
        if not len(msg.names) == len(msg.x) == len(msg.z):
            self._drop("malformed")
            return
        for name, x, z in zip(msg.names, msg.x, msg.z, strict=True):
            if name not in CONSENSUS_NAMES:
                self._drop("unknown_name")
                continue
            self._cons_in.setdefault(name, {})[j] = (msg.stamp_s, x, z)

    def _on_rigidity(self, j: int, msg: Payload) -> None:
        if self.rigidity is None:
            self._drop("unknown_type")
        elif not self.rigidity.receive(j, msg):
            self._drop("malformed")

    def _fresh(self, stamp_s: float, t_s: float) -> bool:
        return t_s - stamp_s <= self.config.peer_timeout_s

    def _forget_time(self) -> None:
        """Resynchronize after the clock went back by more than
        :data:`messages.limits.STAMP_FUTURE_MAX_S` (a restarted simulator, a stepped wall
        clock): everything kept "newest by stamp" now lies in the future and would never be
        replaced, so the stamped peer data, histories, frames and relative yaws are dropped and
        rebuilt from the next samples. Estimates (``phat``, ``chihat``, consensus) are kept."""
        cfg = self.config
        self._own_hist = SignalHistory(angle_index=4)
        self._motion_hist = {j: SignalHistory(angle_index=4) for j in self.running}
        self._sfm_t.clear()
        for frames in self._sfm_frames.values():
            frames.clear()
        for edge in self.sfm.values():
            edge.resync()
            edge.last_frame_s = edge.t_s = -math.inf
            edge.window = WindowAverage(cfg.e_window_s)
        self.yaw_edges = {j: RelativeYawEdge() for j in self.reciprocal}
        for table in (self._motion, self._loc, self._beta_in, self._sfm_in, self._e_folds_in,
                      self._cons_in, self._heard, self._lam_table, self._beta_out):  # fmt: skip
            table.clear()
        self._last_frame_s = -math.inf
        self._rigidity_t = None

    # ----------------------------------------------------------------- step
    def step(
        self, t_s: float, own: OwnMeasurements, inbox: Iterable[Payload] = ()
    ) -> tuple[Setpoint, list[Payload]]:
        """Advance the core to ``t_s`` and return the setpoint and the payloads to publish."""
        cfg = self.config
        dt = 0.0 if self._t is None else t_s - self._t
        if dt < 0.0:
            self._drop("time_backwards")
            if dt < -STAMP_FUTURE_MAX_S:  # the clock was reset (a restarted simulator)
                self._forget_time()
            dt = 0.0
        self._t = t_s
        for msg in inbox:
            self._receive(msg, t_s)
        outbox: list[Payload] = []

        try:  # plain floats: numpy scalars must not leak into payloads
            v = own.v_body
            u_i = (float(v[0]), float(v[1]), float(v[2]))
            w_i = float(own.yaw_rate_rad_s)
            yaw_own = float(own.yaw_rad)
        except (TypeError, ValueError, IndexError):
            u_i, w_i, yaw_own = (math.nan,) * 3, math.nan, math.nan
        if not (_finite(u_i) and math.isfinite(w_i) and math.isfinite(yaw_own)):
            self._drop("nonfinite_own")
            return Setpoint(v_body=(0.0, 0.0, 0.0), yaw_rate_rad_s=0.0), []

        odo_s = own.odometry_stamp_s
        if odo_s is None or not math.isfinite(odo_s) or odo_s > t_s + self.config.peer_timeout_s:
            odo_s = t_s
        self._own_hist.add(odo_s, (*u_i, w_i, yaw_own))
        self._take_bearings(own, yaw_own, outbox)

        # relative velocity on reciprocal edges: u_ij = iR_j u_j - u_i (eq. 7)
        rel: dict[int, tuple[float, Vec3]] = {}
        for j in self.reciprocal:
            m = self._motion.get(j)
            if m is None or not self._fresh(m.stamp_s, t_s):
                continue
            yaw_j = m.yaw_rad + m.yaw_rate_rad_s * (t_s - m.stamp_s)
            psi = self.yaw_edges[j].psi(yaw_own, yaw_j)
            if psi is None:
                continue
            uj = _rotz(psi, m.v_body)
            rel[j] = (psi, (uj[0] - u_i[0], uj[1] - u_i[1], uj[2] - u_i[2]))

        # SfM observers (eq. 8) on the edges this agent runs, time-aligned with the peer
        ran = [(j, edge) for j, edge in self.sfm.items() if self._advance_sfm(j, edge, t_s)]
        if ran:
            outbox.append(
                SfmEstimate(
                    sender=self.id,
                    seq=self._seq,
                    stamp_s=t_s,
                    peers=[j for j, _ in ran],
                    chi_hat_inv_m=[e.chi_at(t_s, cfg.peer_timeout_s) for _, e in ran],
                    excitation=[e.excitation for _, e in ran],
                    e_index=[e.e_index for _, e in ran],
                    e_folds=[e.e_folds for _, e in ran],
                )
            )

        last = self._rigidity_t
        if self.rigidity is not None and (
            last is None or t_s - last >= cfg.rigidity_period_s - 1e-9
        ):
            sfm_d = {j: 1.0 / c for j in self.reciprocal if (c := self.chi_hat(j)) and c > 0}
            dt_r = dt if last is None else t_s - last
            self.rigidity.step(t_s, dt_r, own, yaw_own, u_i, sfm_d, self._seq, outbox)
            self._rigidity_t = t_s
        elif self.rigidity is not None:
            self.rigidity.eigen_round(t_s, self._seq, outbox)
        self._cons_out = ([], [], [])
        if self.paper000:
            self._localize(dt, t_s, u_i, w_i)
            self._run_consensus(dt, t_s, rel, outbox)
        v, w = self._control(dt, t_s, u_i, rel)
        if self.rigidity is not None and cfg.mode != "rigidity-tracking":
            du, dw = self.rigidity.u_rigidity, self.rigidity.w_rigidity
            v = (float(v[0] + du[0]), float(v[1] + du[1]), float(v[2] + du[2]))
            w = float(w + dw)
        v = _saturate(v, cfg.v_max_m_s)
        w = max(-cfg.yaw_rate_max_rad_s, min(cfg.yaw_rate_max_rad_s, w))

        if not self.paper000:
            self._seq += 1
            return Setpoint(v_body=v, yaw_rate_rad_s=w), outbox
        names, xs, zs = self._cons_out
        if cfg.mode == "formation-active":
            names.append("w_l")
            xs.append([self.w_l])
            zs.append([])
        outbox.append(
            ConsensusState(sender=self.id, seq=self._seq, stamp_s=t_s, names=names, x=xs, z=zs)
        )
        loc = self.localization
        outbox.append(
            MotionShare(
                sender=self.id,
                seq=self._seq,
                stamp_s=odo_s,
                v_body=u_i,
                yaw_rate_rad_s=w_i,
                yaw_rad=yaw_own,
            )
        )
        outbox.append(
            LocalizationState(
                sender=self.id,
                seq=self._seq,
                stamp_s=t_s,
                p_hat_ned=loc.p_hat_ned,
                yaw_hat_rad=loc.yaw_hat_rad,
            )
        )
        self._seq += 1
        return Setpoint(v_body=v, yaw_rate_rad_s=w), outbox

    def _take_bearings(self, own: OwnMeasurements, yaw_own: float, outbox: list[Payload]) -> bool:
        """Store a new camera frame, feed the relative-yaw trackers and share it."""
        fresh: list[tuple[int, float, Vec3]] = []
        newest = self._last_frame_s
        for b in own.bearings:
            if b.stamp_s <= self._last_frame_s or b.target not in self.out_targets:
                continue
            if stamp_ahead(b.stamp_s, own.t_s):  # would blind the camera for good
                self._drop("future_stamp")
                continue
            newest = max(newest, b.stamp_s)  # a bad detection is counted once, not every step
            try:
                beta = (float(b.beta_body[0]), float(b.beta_body[1]), float(b.beta_body[2]))
            except (TypeError, ValueError, IndexError):
                beta = (math.nan,) * 3
            if not _finite(beta) or abs(beta[0] ** 2 + beta[1] ** 2 + beta[2] ** 2 - 1.0) > 1e-3:
                self._drop("bad_bearing")
                continue
            fresh.append((b.target, float(b.stamp_s), beta))
        self._last_frame_s = newest
        if not fresh:
            return False
        stamp = max(s for _, s, _ in fresh)
        for target, s, beta in fresh:
            self._beta_out[target] = (s, beta)
            if target in self._sfm_frames:
                self._sfm_frames[target].append((s, beta))
            if target in self.yaw_edges:
                self.yaw_edges[target].add_own(s, self._yaw_at(s, yaw_own), beta)
        outbox.append(
            BearingShare(
                sender=self.id,
                seq=self._seq,
                stamp_s=stamp,
                yaw_rad=self._yaw_at(stamp, yaw_own),
                targets=[t for t, _, _ in fresh],
                beta_body=[b for _, _, b in fresh],
            )
        )
        return True

    def _yaw_at(self, stamp_s: float, yaw_now: float) -> float:
        """Own odometry yaw when a frame was captured: a frame reaches the core 10-150 ms late
        (Zenoh, image processing) and pairing it with the yaw of its arrival biases the
        relative yaw by ``yaw rate x latency``."""
        hist = self._own_hist
        sample = hist.at(stamp_s)
        if sample is None:
            return yaw_now
        if stamp_s > hist.newest_s:  # captured after the newest odometry: extrapolate
            return sample[4] + sample[3] * min(stamp_s - hist.newest_s, MAX_ODOMETRY_GAP_S)
        return sample[4]

    def _advance_sfm(self, j: int, edge: SfmEdge, t_s: float) -> bool:
        """Advance the observer of edge ``(self, j)`` to the newest instant ``tau`` at which
        every input is known: ``j``'s motion, the own odometry and a camera frame of ``j``.
        It replays own samples and camera frames in between with ``u_j`` interpolated at the
        same instants (:mod:`onboard.estimation.time_alignment`), so a frame is always taken
        at its capture time, however late it arrives. ``False`` while any input is stale or
        the relative yaw unknown."""
        peer, own, frames = self._motion_hist[j], self._own_hist, self._sfm_frames[j]
        newest_frame_s = max(frames[-1][0] if frames else -math.inf, edge.last_frame_s)
        tau1 = min(t_s, peer.newest_s, own.newest_s, newest_frame_s)
        if not self._fresh(tau1, t_s) or self.yaw_edges[j].offset_rad is None:
            return False
        tau0 = self._sfm_t.get(j, tau1)
        if tau0 == tau1 and j in self._sfm_t:  # no new instant (9 steps in 10 at 50 Hz frames)
            return True
        if tau1 - tau0 > self.config.peer_timeout_s:  # after a gap: restart, do not integrate
            tau0 = tau1
            edge.resync()
        if tau1 < tau0:  # the newest frame went back (its buffer was emptied): wait
            return True
        self._sfm_t[j] = tau1
        while len(frames) > 1 and frames[1][0] <= tau0:  # left over from a gap: keep the newest
            frames.popleft()
        prev = tau0
        for s in step_times(own.times_in(tau0, tau1), tau0, tau1, MAX_SFM_STEP_S):
            mine, theirs = own.at(s), peer.at(s)
            ds, prev = s - prev, s
            hole = max(own.gap_at(s), peer.gap_at(s)) > MAX_ODOMETRY_GAP_S
            if mine is None or theirs is None or hole:
                # a hole in the own or the peer's odometry (a stalled process, lost messages):
                # do not integrate across it, and restart the bearing state after it
                if edge.beta_hat is not None:
                    self._drop("sfm_hole")  # the frames inside it are not used
                edge.resync()
                while frames and frames[0][0] <= s:
                    frames.popleft()
                continue
            psi = self.yaw_edges[j].psi(mine[4], theirs[4])
            assert psi is not None
            uj = _rotz(psi, (theirs[0], theirs[1], theirs[2]))
            u_ij = (uj[0] - mine[0], uj[1] - mine[1], uj[2] - mine[2])
            while frames and frames[0][0] <= s:
                stamp, beta = frames.popleft()
                edge.new_bearing(beta, stamp, s, u_ij, mine[3])
            edge.step(s, ds, u_ij, mine[3])
        return True

    def chi_hat(self, j: int) -> float | None:
        """Inverse-distance estimate on reciprocal edge ``(self, j)`` now: an own observer's carried
        to the core's time (:meth:`SfmEdge.chi_at`), a received one as its sender carried it,
        while it is fresh (``peer_timeout_s``: a silent neighbour's last estimate is not kept)."""
        t = self._t or 0.0
        if j in self.sfm:
            return self.sfm[j].chi_at(t, self.config.peer_timeout_s)
        m = self._sfm_in.get(j)
        return None if m is None or not self._fresh(m[0], t) else m[1]

    def _localize(self, dt: float, t_s: float, u_i: Vec3, w_i: float) -> None:
        out_edges = []
        for j in self.out_targets:
            loc, b = self._loc.get(j), self._beta_out.get(j)
            if loc is not None and b is not None and self._fresh(loc.stamp_s, t_s):
                out_edges.append((loc.p_hat_ned, b[1]))
        in_edges = []
        for j in self.in_sources:
            loc, b = self._loc.get(j), self._beta_in.get(j)
            if loc is not None and b is not None and self._fresh(loc.stamp_s, t_s):
                in_edges.append((loc.p_hat_ned, loc.yaw_hat_rad, b[1]))
        distances = []
        for j in self.reciprocal:
            chi, loc = self.chi_hat(j), self._loc.get(j)
            if chi is not None and chi >= self.config.chi_min_inv_m and loc is not None:
                distances.append((loc.p_hat_ned, 1.0 / chi))
        self.localization.step(dt, u_i, w_i, out_edges, in_edges, distances)

    # ------------------------------------------------------------ consensus
    def _consensus_step(self, name: str, dt: float, t_s: float, phi: list[float]) -> list[float]:
        cfg = self.config
        est = self._consensus.get(name)
        if est is None:
            est = PIConsensus(
                list(phi), gamma=cfg.consensus_gamma, k_p=cfg.consensus_k_p, k_i=cfg.consensus_k_i
            )
            self._consensus[name] = est
        nbrs = [
            (x, z)
            for stamp, x, z in self._cons_in.get(name, {}).values()
            if self._fresh(stamp, t_s) and len(x) == len(phi) and len(z) == len(phi)
        ]
        x = est.step(dt, phi, nbrs)
        names, xs, zs = self._cons_out
        names.append(name)
        xs.append(x)
        zs.append(est.z)
        return x

    def _run_consensus(
        self, dt: float, t_s: float, rel: dict[int, tuple[float, Vec3]], outbox: list[Payload]
    ) -> None:
        cfg = self.config
        n = cfg.n_agents
        p = cfg.p_norm
        for j, edge in self.sfm.items():
            if edge.beta_pred is not None:
                self._lam_table[(self.id, j)] = (t_s, edge.excitation)
        fresh = [(k, v) for k, v in self._lam_table.items() if self._fresh(v[0], t_s)]
        self.lambda_bar = act.lambda_bar([v[1] for _, v in fresh], p)
        # own edges every step, the relayed rest of the table every few steps
        if self._seq % cfg.excitation_relay_every:
            fresh = [(k, v) for k, v in fresh if k[0] == self.id]
        if fresh:
            outbox.append(
                ExcitationTable(
                    sender=self.id,
                    seq=self._seq,
                    stamp_s=t_s,
                    first=[k[0] for k, _ in fresh],
                    second=[k[1] for k, _ in fresh],
                    excitation=[v[1] for _, v in fresh],
                    stamps_s=[v[0] for _, v in fresh],
                )
            )
        e_sum = sum(
            e.e_index + (cfg.e_high if e.e_folds < cfg.converged_e_folds else 0.0)
            for e in self.sfm.values()
        )
        x = self._consensus_step("e_index", dt, t_s, [e_sum])
        self.e_index = max(n * x[0], 0.0)
        if cfg.mode != "formation-active":
            return
        loc = self.localization
        pb = self._consensus_step("p_bar", dt, t_s, list(loc.p_hat_ned))
        self.p_bar = (pb[0], pb[1], pb[2])
        grad = act.lambda_bar_gradient(self._excitation_terms(rel), self.lambda_bar, p)
        n3 = act.rotation_velocity_body(loc.p_hat_ned, loc.yaw_hat_rad, self.p_bar)
        delta = grad[0] * n3[0] + grad[1] * n3[1] + grad[2] * n3[2]
        x = self._consensus_step("dlam_dwl", dt, t_s, [delta])
        self.dlam_dwl = n * x[0]

    def _excitation_terms(
        self, rel: dict[int, tuple[float, Vec3]]
    ) -> list[tuple[Vec3, Vec3, float]]:
        """``(beta_ij, u_ij, lambda_ij)`` for reciprocal edges with a bearing and a relative yaw."""
        terms = []
        for j, (_, u_ij) in rel.items():
            b = self._beta_out.get(j)
            if b is not None:
                terms.append((b[1], u_ij, excitation(b[1], u_ij)))
        return terms

    # ------------------------------------------------------------- control
    def _control(
        self, dt: float, t_s: float, u_i: Vec3, rel: dict[int, tuple[float, Vec3]]
    ) -> tuple[Vec3, float]:
        cfg = self.config
        mode = cfg.mode
        if mode == "hold":
            return (0.0, 0.0, 0.0), 0.0
        if mode == "rigidity-tracking":
            assert self.rigidity is not None
            u, w = self.rigidity.u_rigidity, self.rigidity.w_rigidity
            return (float(u[0]), float(u[1]), float(u[2])), float(w)
        if mode == "random":
            self.u_cmd = self._random.step(dt)
            return self.u_cmd, 0.0
        if mode == "active":
            grad = act.lambda_bar_gradient(self._excitation_terms(rel), self.lambda_bar, cfg.p_norm)
            du = act.active_velocity_rate(self.u_cmd, grad, cfg.k_nu, cfg.nu_star, cfg.k_lambda)
            u = self.u_cmd
            self.u_cmd = (u[0] + dt * du[0], u[1] + dt * du[1], u[2] + dt * du[2])
            return self.u_cmd, 0.0
        u_f, w_f = self._formation(t_s)
        if mode == "formation":
            return u_f, w_f
        # formation-active (eq. 13-16)
        self.k_e = act.convergence_gain(self.e_index, cfg.e_low, cfg.e_high)
        dw = act.rotation_rate_derivative(
            self.w_l, self.dlam_dwl, self.lambda_bar, self.k_e, cfg.k_w, cfg.k_lambda0, cfg.gamma
        )
        shared = [
            x[0]
            for stamp, x, _ in self._cons_in.get("w_l", {}).values()
            if self._fresh(stamp, t_s) and len(x) == 1
        ]
        dw += cfg.k_w_l_coupling * sum(w - self.w_l for w in shared)
        # anti-windup: the vehicle cannot turn the formation faster than this, so integrating
        # past it only stores error (with delayed lambdabar it ran away to 1e35 otherwise)
        self.w_l = max(-cfg.w_l_max_rad_s, min(cfg.w_l_max_rad_s, self.w_l + dt * dw))
        loc = self.localization
        n3 = act.rotation_velocity_body(loc.p_hat_ned, loc.yaw_hat_rad, self.p_bar)
        wl = self.w_l
        return (u_f[0] + wl * n3[0], u_f[1] + wl * n3[1], u_f[2] + wl * n3[2]), w_f + wl

    def _formation(self, t_s: float) -> tuple[Vec3, float]:
        """``(u^F, w^F)``: bearing formation law (paper 002 eq. 20) and yaw alignment."""
        cfg = self.config
        me = self.id
        yaw_i = self.localization.yaw_hat_rad
        out_edges = [
            (self._beta_out[j][1], self.desired[(me, j)])
            for j in self.out_targets
            if j in self._beta_out and (me, j) in self.desired
        ]
        in_edges = []
        yaws = []
        for j in self.neighbours:
            loc = self._loc.get(j)
            if loc is None or not self._fresh(loc.stamp_s, t_s):
                continue
            if cfg.desired_yaw_rad:
                yaws.append((loc.yaw_hat_rad, cfg.desired_yaw_rad[j] - cfg.desired_yaw_rad[me]))
            b = self._beta_in.get(j)
            if b is not None and (j, me) in self.desired:
                in_edges.append((loc.yaw_hat_rad - yaw_i, b[1], self.desired[(j, me)]))
        u_f = formation_velocity(out_edges, in_edges, cfg.k_formation)
        w_f = yaw_alignment_rate(yaw_i, yaws, cfg.k_yaw)
        return u_f, w_f

    # -------------------------------------------------------------- status
    def status(self) -> AgentStatus:
        """Health and estimates for the ground station."""
        loc = self.localization
        t = self._t or 0.0
        chis = {j: c for j in self.reciprocal if (c := self.chi_hat(j)) is not None}
        p_hat, yaw_hat = loc.p_hat_ned, loc.yaw_hat_rad
        lam = None
        if self.rigidity is not None:
            lam = self.rigidity.lambda_hat
            if not self.paper000:  # angle localization is the position estimate
                p_hat = tuple(float(x) for x in self.rigidity.loc.p_hat_ned)  # type: ignore[assignment]
                yaw_hat = self.rigidity.yaw_hat
        return AgentStatus(
            sender=self.id,
            seq=self._seq,
            stamp_s=t,
            mode=self.config.mode,
            p_hat_ned=p_hat,
            yaw_hat_rad=yaw_hat,
            chi_hat_inv_m=chis,
            e_index=self.e_index,
            lambda_bar=self.lambda_bar,
            neighbours=sorted(j for j, s in self._heard.items() if t - s <= 1.0),
            rigidity_eigenvalue=lam,
            scale_converged=self.scale_converged(),
        )

    def scale_converged(self) -> bool:
        """Whether the metric scale can be trusted, from onboard information only: the network's
        convergence index ``E`` (eq. 10) is below ``e_low`` and every SfM edge this agent runs has
        been excited enough (:attr:`SfmEdge.e_folds`; shared in
        :class:`messages.peer.SfmEstimate` for the edges a neighbour runs), since ``E`` is also
        small before any motion."""
        cfg = self.config
        if not self.paper000 or not self.reciprocal or self.e_index >= cfg.e_low:
            return False
        folds = [
            self.sfm[j].e_folds if j in self.sfm else self._received_e_folds(j)
            for j in self.reciprocal
        ]
        return min(folds) >= cfg.converged_e_folds

    def _received_e_folds(self, j: int) -> float:
        """E-foldings of edge ``(j, self)`` as ``j`` last shared them; 0 once its SfM estimate
        is stale (a neighbour that went silent no longer vouches for the scale)."""
        m = self._sfm_in.get(j)
        if m is None or not self._fresh(m[0], self._t or 0.0):
            return 0.0
        return self._e_folds_in.get(j, 0.0)
