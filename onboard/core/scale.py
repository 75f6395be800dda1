"""Paper 000's scale estimation as one layer: SfM observers, localization and consensus.

Per step, after the camera layer (:class:`onboard.core.bearings.Bearings`) took the frame:

1. ``u_ij = iR_j u_j - u_i`` (eq. 7) on every reciprocal edge with a relative yaw;
2. one SfM observer (eq. 8, 10) per reciprocal edge whose lower id is this agent, time-aligned
   with the peer's odometry (:mod:`onboard.estimation.time_alignment`); the other end receives
   the result as :class:`messages.peer.SfmEstimate`;
3. the localization filter (eq. 6) with the SfM distances as virtual measurements;
4. ``lambdabar`` (eq. 11) from every edge's excitation, relayed hop by hop
   (:class:`messages.peer.ExcitationTable`; exact after a few steps), and PI average consensus
   (fig. 1) for ``E`` (eq. 10) and, with ``rotation_terms`` (the bearing-constrained active
   perception), the barycenter ``pbar`` and ``d lambdabar / d w_l`` (eq. 14). (A PI consensus
   on ``lambda_k^p`` as in fig. 1 was tried first: ``lambda^p`` spans ten decades within 0.4 s
   when the rotation kicks in, the estimator lags, and the over-estimated gradient made eq. 15
   diverge.)

After every layer stepped it publishes :class:`messages.peer.ConsensusState` (with what the
controllers shared through :meth:`Scale.share`), :class:`messages.peer.MotionShare` and
:class:`messages.peer.LocalizationState`. It contributes no velocity.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any, Protocol

from messages.codec import Payload
from messages.limits import STAMP_FUTURE_MAX_S
from messages.peer import (
    BearingShare,
    ConsensusEntry,
    ConsensusState,
    EdgeExcitation,
    ExcitationTable,
    LocalizationState,
    MotionShare,
    SfmEdgeEstimate,
    SfmEstimate,
)
from messages.vocabulary import DropReason
from onboard.control import active_scale as act
from onboard.core.bearings import MAX_ODOMETRY_GAP_S, Bearings
from onboard.core.config import Graph, ScaleGains
from onboard.core.layer import Command, Own, Vec3
from onboard.core.peers import Drops, JumpGate, PeerTable, Route
from onboard.estimation.consensus import PIConsensus
from onboard.estimation.localization import LocalizationFilter
from onboard.estimation.sfm_observer import SfmEdge, WindowAverage, excitation
from onboard.estimation.team_scale import fused_distances, triangle_log_shape, vertex_angle
from onboard.estimation.time_alignment import SignalHistory, step_times

MAX_SFM_STEP_S = 0.01
"""Longest interval one explicit-Euler step of an SfM observer may span (``h dt = 0.1``): longer
intervals between samples are integrated in equal sub-steps."""
CONSENSUS_NAMES = frozenset({"e_index", "p_bar", "dlam_dwl", "w_l"})
"""The quantities agents run consensus on (:class:`messages.peer.ConsensusState` names): any
other name from a neighbour is counted (``unknown_name``) and dropped, so a neighbour cannot
grow a receiver's tables (issue 23: 45,000 names per payload took a daemon to 650 MB)."""
E_STEP_MAX_HIGHS = 10.0
"""A neighbour's ``e_index`` consensus state (``x`` or ``z``, paper 000 eq. 10 through the PI
estimator of fig. 1; docs/equations.md, "Average consensus") that moved by more than this many
``e_high`` since the last sample taken from it waits for the next one to confirm it
(:class:`onboard.core.peers.JumpGate`, ``implausible_jump``). The gate ``k_E(E)`` (eq. 16)
reads ``E`` on a log scale between ``e_low`` and ``e_high``, and the PI estimator forgets a
kick only at its slow rate (``k_i = 1``: seconds): ONE bit-flipped sample (``x`` 1e-9 -> 1.0)
kept a converged team's ``E`` above ``e_low`` for 30 s, the active rotation at ``w_l_max`` and
the vehicles at the 2 m/s limit, the formation 11.7 -> 26.7 -> 8.6 m (bench_poison
``d1-bitflip``, offline). Real steps are window averages (eq. 10) moving by at most 7.8e-4 per
20 ms sample in the demo team and 1.4e-4 per 2 ms in the paper's scenarios."""
CONSENSUS_STEP_MAX = {"p_bar": 10.0, "dlam_dwl": 1.0, "w_l": 0.3}
"""The same confirmation for the other consensus states (``x`` and ``z`` of each component):
``pbar`` in m (the barycenter of eq. 14), ``d lambdabar / d w_l`` (eq. 14) and the shared
``w_l`` in rad/s (the default bound ``w_l_max``). ONE ``pbar`` state whose integral ``z`` a
flipped exponent made 5.5e6 put the receivers' barycenter 55 km away, decaying over tens of
seconds: the rotation velocity ``w_l (e3 x (p - pbar))`` of eq. 13 saturated at 2 m/s as soon
as ``k_E`` opened a little, the fast motion corrected the SfM distances by more than
``wander_max`` (their edges un-converged, ``E`` rose by ``e_high`` per edge, ``k_E = 1``) and
the team flew at the limit for the whole watch (bench_poison ``d1-bitflip`` offline, seed 28:
14.3 s of 15 s, the formation 9.9 m off). Real steps per 20 ms sample in the demo team from
its start: ``pbar`` 0.17 m, ``d lambdabar / d w_l`` 0.08, ``w_l`` 0.0065 rad/s."""
LOC_STEP_MAX_M = 10.0
LOC_STEP_MAX_RAD = 0.5
"""A neighbour's :class:`messages.peer.LocalizationState` (eq. 6; docs/equations.md, "Scale
from motion") whose position moved by more than :data:`LOC_STEP_MAX_M` (per axis) or whose
yaw turned by more than :data:`LOC_STEP_MAX_RAD` (wrapped) since the last one taken from it
waits for the next one to confirm it (:class:`onboard.core.peers.JumpGate`,
``implausible_jump``). ONE bit-flipped yaw (2.83 -> 724 rad: another angle) made its
receivers' localization, yaw alignment and formation laws turn: 9.3 s at up to 2 m/s, the
formation 11.8 -> 15.5 m for good (offline; held 0.3 s: +1 rad 2-3 s fast, +0.3 rad and +20 m
nothing). Real steps per 20 ms sample: 0.11 m and 0.15 rad in the demo team's first 0.1 s (the
filter's first corrections), then 0.07 m and 0.014 rad. A fixed gate of 5 m / 0.25 rad that
took nothing unconfirmed, comparing each sample with the previous one, rejected real samples
on a loaded flying team (05aa96b); here a held-back real jump costs one sample."""


TEAM_SCALE_WEIGHT_FLOOR = 1e-3
"""Added to each edge's excitation ``lambda`` (m^2/s^2) as its weight in the fused team scale
(:mod:`onboard.estimation.team_scale`): a team at rest still has a scale, every edge's vote."""


class Pose(Protocol):
    """A position and yaw estimate in the team's shared estimated frame."""

    @property
    def p_hat_ned(self) -> Vec3: ...

    @property
    def yaw_hat_rad(self) -> float: ...


def rotz(psi: float, v: Vec3) -> Vec3:
    """``v`` rotated by ``psi`` about the vertical."""
    c, s = math.cos(psi), math.sin(psi)
    return (c * v[0] - s * v[1], s * v[0] + c * v[1], v[2])


class Scale:
    """One agent's paper 000 estimators (module docstring)."""

    def __init__(self, graph: Graph, gains: ScaleGains, peers: PeerTable, bearings: Bearings,
                 reciprocal: list[int], drops: Drops, rotation_terms: bool) -> None:  # fmt: skip
        me = graph.agent_id
        self.id = me
        self.n_agents = graph.n_agents
        self.gains = gains
        self.peers = peers
        self.bearings = bearings
        self.rotation_terms = rotation_terms
        self._drops = drops
        self.reciprocal = list(reciprocal)
        self.running = [j for j in reciprocal if me < j]
        neighbours = peers.neighbours
        self.routes = {
            MotionShare: Route(neighbours, self._take_motion),
            LocalizationState: Route(neighbours, self._take_localization),  # the table keeps it
            SfmEstimate: Route(neighbours, self._take_sfm),
            ExcitationTable: Route(neighbours, self._take_excitation),
            ConsensusState: Route(neighbours, self._take_consensus),
        }
        self.localization = LocalizationFilter(
            graph.p0(me), graph.yaw0(me), gains.k_loc_bearing, gains.k_loc_distance
        )
        self.pose: Pose = self.localization
        """The estimate the formation laws and ``pbar`` use: paper 000's filter, or paper 002's
        localization layer when the fleet selects it (:func:`onboard.core.modes.compose`)."""
        self.sfm: dict[int, SfmEdge] = {}
        for j in self.running:
            d0 = math.dist(graph.p0(me), graph.p0(j)) if graph.p_hat0_ned else 1.0
            self.sfm[j] = SfmEdge(
                chi_hat=1.0 / max(d0, 1e-3),
                alpha=gains.alpha,
                h_other=gains.h_other,
                h_floor=gains.h_floor,
                window=WindowAverage(gains.e_window_s),
                bias_speed_m_s=gains.sfm_bias_speed_m_s,
                folds_forget_s=gains.sfm_folds_forget_s,
                wander_window=(
                    WindowAverage(gains.sfm_wander_window_s) if gains.sfm_wander_max > 0.0 else None
                ),
                wander_max=gains.sfm_wander_max,
                folds_cap=0.9 * gains.converged_e_folds,
                bias_gain=gains.sfm_bias_gain,
                bias_max_m_s=gains.sfm_bias_max_m_s,
            )
        # time alignment of the SfM observers: peer ``(u_x, u_y, u_z, w, yaw)`` histories, the
        # observer's own clock, frames to replay
        self.motion_hist = {j: SignalHistory(angle_index=4) for j in self.running}
        self._sfm_t: dict[int, float] = {}
        self._sfm_frames: dict[int, deque[tuple[float, Vec3]]] = {
            j: deque(maxlen=64) for j in self.running
        }
        # peer data kept beyond the table's latest payload
        self.sfm_in: dict[int, tuple[float, float]] = {}  # j -> (stamp, chihat_ij)
        self._e_folds_in: dict[int, float] = {}  # j -> e-foldings of edge (j, self)
        self.cons_in: dict[str, dict[int, tuple[float, list[float], list[float]]]] = {}
        self._jumps = JumpGate()  # keys (j, consensus name) and (j, "localization")
        self.lam_table: dict[tuple[int, int], tuple[float, float]] = {}  # edge -> (stamp, lambda)
        # the excitation table's keys: the fleet's reciprocal edges, run by their lower id
        edges = set(graph.edges)
        self.known_edges = frozenset((i, j) for i, j in edges if i < j and (j, i) in edges)
        self._consensus: dict[str, PIConsensus] = {}
        self._cons_out: list[ConsensusEntry] = []
        self.rel: dict[int, tuple[float, Vec3]] = {}
        """Reciprocal edge ``j`` -> ``(psi_ij, u_ij)`` of this step (eq. 7)."""
        self.team_chi: dict[int, float] = {}
        """Reciprocal neighbour -> inverse distance on the fused team scale (``[sfm]
        team_scale``), recomputed at each own camera frame; empty when off or undetermined."""
        self._team_chi_s = -math.inf
        self.lambda_bar = 0.0
        self.e_index = 0.0
        self.dlam_dwl = 0.0
        self.p_bar: Vec3 = (0.0, 0.0, 0.0)

    # ----------------------------------------------------------------- inbox
    def _take_motion(self, j: int, msg: MotionShare) -> bool:
        hist = self.motion_hist.get(j)
        if hist is not None:
            hist.add(msg.stamp_s, (*msg.v_body, msg.yaw_rate_rad_s, msg.yaw_rad))
        return True

    def _take_sfm(self, j: int, msg: SfmEstimate) -> bool:
        for e in msg.edges:
            if e.peer == self.id:
                self.sfm_in[j] = (msg.stamp_s, e.chi_hat_inv_m)
                self._e_folds_in[j] = e.e_folds
        return True

    def _take_excitation(self, j: int, msg: ExcitationTable) -> bool:
        table, known = self.lam_table, self.known_edges
        ahead = False
        for entry in msg.entries:
            a, b, lam, stamp = entry.first, entry.second, entry.excitation, entry.stamp_s
            if (a, b) not in known:  # only the fleet's edges: the table stays bounded
                self._drops.count(DropReason.UNKNOWN_EDGE)
                continue
            if stamp > msg.stamp_s + STAMP_FUTURE_MAX_S:  # measured after it was sent
                ahead = True
                continue
            prev = table.get((a, b))
            if prev is None or stamp > prev[0]:
                table[(a, b)] = (stamp, lam)
        if ahead:
            self._drops.count(DropReason.FUTURE_STAMP)
        return True

    def _take_localization(self, j: int, msg: LocalizationState) -> bool | None:
        """Keep ``j``'s estimate unless it jumped (:data:`LOC_STEP_MAX_M`,
        :data:`LOC_STEP_MAX_RAD`) and is not confirmed yet (counted ``implausible_jump``)."""
        m, rad = LOC_STEP_MAX_M, LOC_STEP_MAX_RAD
        values = (msg.yaw_hat_rad, *msg.p_hat_ned)
        if self._jumps.admit((j, "localization"), values, (rad, m, m, m), (True,)):
            return True
        self._drops.count(DropReason.IMPLAUSIBLE_JUMP)
        return None

    def _take_consensus(self, j: int, msg: ConsensusState) -> bool:
        for entry in msg.states:
            if entry.name not in CONSENSUS_NAMES:
                self._drops.count(DropReason.UNKNOWN_NAME)
                continue
            step_max = (
                E_STEP_MAX_HIGHS * self.gains.e_high
                if entry.name == "e_index"
                else CONSENSUS_STEP_MAX[entry.name]
            )
            values = (*entry.x, *entry.z)
            if not self._jumps.admit((j, entry.name), values, (step_max,) * len(values)):
                self._drops.count(DropReason.IMPLAUSIBLE_JUMP)
                continue
            self.cons_in.setdefault(entry.name, {})[j] = (msg.stamp_s, entry.x, entry.z)
        return True

    def shared(self, name: str, t_s: float) -> list[list[float]]:
        """The neighbours' fresh shared values ``x`` of consensus quantity ``name``."""
        fresh = self.peers.is_fresh
        return [x for stamp, x, _ in self.cons_in.get(name, {}).values() if fresh(stamp, t_s)]

    # ------------------------------------------------------------------ step
    def step(self, own: Own, outbox: list[Payload]) -> Command | None:
        """Relative velocities, SfM observers, localization, consensus."""
        t_s, u_i = own.t_s, own.v_body
        peers = self.peers
        frames = self._sfm_frames
        for target, s, beta in self.bearings.new_frames:
            if target in frames:
                frames[target].append((s, beta))

        # relative velocity on reciprocal edges: u_ij = iR_j u_j - u_i (eq. 7)
        rel: dict[int, tuple[float, Vec3]] = {}
        yaw_edges = self.bearings.yaw_edges
        for j in self.reciprocal:
            m = peers.latest_fresh(MotionShare, j, t_s)
            if m is None:
                continue
            yaw_j = m.yaw_rad + m.yaw_rate_rad_s * (t_s - m.stamp_s)
            psi = yaw_edges[j].psi(own.yaw_rad, yaw_j)
            if psi is None:
                continue
            uj = rotz(psi, m.v_body)
            rel[j] = (psi, (uj[0] - u_i[0], uj[1] - u_i[1], uj[2] - u_i[2]))
        self.rel = rel

        # SfM observers (eq. 8) on the edges this agent runs, time-aligned with the peer
        ran = [(j, edge) for j, edge in self.sfm.items() if self._advance_sfm(j, edge, t_s)]
        if ran:
            timeout = peers.timeout_s
            outbox.append(
                SfmEstimate(
                    sender=self.id,
                    seq=own.seq,
                    stamp_s=t_s,
                    edges=[
                        SfmEdgeEstimate(
                            j, e.chi_at(t_s, timeout), e.excitation, e.e_index, e.e_folds
                        )
                        for j, e in ran
                    ],
                )
            )
        if self.gains.sfm_team_scale and self.bearings.new_frames:
            self._fuse_team_scale(t_s)
        self._cons_out = []
        self._localize(own)
        self._run_consensus(own, outbox)
        return None

    def _advance_sfm(self, j: int, edge: SfmEdge, t_s: float) -> bool:
        """Advance the observer of edge ``(self, j)`` to the newest instant ``tau`` at which
        every input is known: ``j``'s motion, the own odometry and a camera frame of ``j``.
        It replays own samples and camera frames in between with ``u_j`` interpolated at the
        same instants (:mod:`onboard.estimation.time_alignment`), so a frame is always taken
        at its capture time, however late it arrives. ``False`` while any input is stale or
        the relative yaw unknown."""
        peer, own, frames = self.motion_hist[j], self.bearings.own_hist, self._sfm_frames[j]
        yaw_edge = self.bearings.yaw_edges[j]
        newest_frame_s = max(frames[-1][0] if frames else -math.inf, edge.last_frame_s)
        tau1 = min(t_s, peer.newest_s, own.newest_s, newest_frame_s)
        if not self.peers.is_fresh(tau1, t_s) or yaw_edge.offset_rad is None:
            return False
        tau0 = self._sfm_t.get(j, tau1)
        if tau0 == tau1 and j in self._sfm_t:  # no new instant (9 steps in 10 at 50 Hz frames)
            return True
        if tau1 - tau0 > self.peers.timeout_s:  # after a gap: restart, do not integrate
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
                    self._drops.count(DropReason.SFM_HOLE)  # the frames inside it are not used
                edge.resync()
                while frames and frames[0][0] <= s:
                    frames.popleft()
                continue
            psi = yaw_edge.psi(mine[4], theirs[4])
            assert psi is not None
            uj = rotz(psi, (theirs[0], theirs[1], theirs[2]))
            u_ij = (uj[0] - mine[0], uj[1] - mine[1], uj[2] - mine[2])
            while frames and frames[0][0] <= s:
                stamp, beta = frames.popleft()
                edge.new_bearing(beta, stamp, s, u_ij, mine[3])
            edge.step(s, ds, u_ij, mine[3])
        return True

    def _fuse_team_scale(self, t_s: float) -> None:
        """Every reciprocal pair's distance on one team scale (:func:`fused_distances`,
        docs/equations.md "Fused team scale"): the SfM distances this agent runs or receives
        (:class:`messages.peer.SfmEstimate`, every edge its neighbours run), weighted by their
        excitation, through the triangles whose three vertex angles are known (own bearings,
        the neighbours' fresh :class:`messages.peer.BearingShare`)."""
        peers, me = self.peers, self.id
        chi_min, timeout = self.gains.chi_min_inv_m, peers.timeout_s
        dist: dict[tuple[int, int], float] = {}
        weight: dict[tuple[int, int], float] = {}
        for j, edge in self.sfm.items():
            c = edge.chi_at(t_s, timeout)
            if c >= chi_min:
                dist[(me, j)] = 1.0 / c
                weight[(me, j)] = edge.excitation + TEAM_SCALE_WEIGHT_FLOOR
        seen: dict[int, dict[int, tuple[float, float, float]]] = {}
        own = {
            k: b for k, (stamp, b) in self.bearings.beta_out.items() if peers.is_fresh(stamp, t_s)
        }
        seen[me] = own
        for j, msg in peers.fresh(SfmEstimate, t_s):
            for e in msg.edges:
                pair = (j, e.peer)
                if pair in self.known_edges and e.chi_hat_inv_m >= chi_min:
                    dist[pair] = 1.0 / e.chi_hat_inv_m
                    weight[pair] = max(e.excitation, 0.0) + TEAM_SCALE_WEIGHT_FLOOR
        for j, bmsg in peers.fresh(BearingShare, t_s):
            seen[j] = {b.target: b.beta_body for b in bmsg.bearings}
        pairs = sorted(self.known_edges)
        known = self.known_edges
        triangles = []
        for a, b in pairs:
            for c in range(b + 1, self.n_agents):
                if (a, c) not in known or (b, c) not in known:
                    continue
                try:
                    angles = (
                        vertex_angle(seen[a][b], seen[a][c]),
                        vertex_angle(seen[b][a], seen[b][c]),
                        vertex_angle(seen[c][a], seen[c][b]),
                    )
                except KeyError:
                    continue
                shape = triangle_log_shape(angles)
                if shape is not None:  # sides opposite a, b, c: (b, c), (a, c), (a, b)
                    triangles.append((((b, c), (a, c), (a, b)), shape))
        fused = fused_distances(pairs, dist, weight, triangles)
        self.team_chi = {
            (e[1] if e[0] == me else e[0]): 1.0 / d for e, d in fused.items() if me in e and d > 0
        }
        self._team_chi_s = t_s

    def chi_hat(self, j: int) -> float | None:
        """Inverse-distance estimate on reciprocal edge ``(self, j)`` now: with ``[sfm]
        team_scale``, the fused team scale's (:meth:`_fuse_team_scale`) while it is fresh;
        otherwise an own observer's carried to the core's time (:meth:`SfmEdge.chi_at`), a
        received one as its sender carried it, while it is fresh (``peer_timeout_s``: a silent
        neighbour's last estimate is not kept)."""
        t = self.peers.t_s or 0.0
        if j in self.team_chi and self.peers.is_fresh(self._team_chi_s, t):
            return self.team_chi[j]
        if j in self.sfm:
            return self.sfm[j].chi_at(t, self.peers.timeout_s)
        m = self.sfm_in.get(j)
        return None if m is None or not self.peers.is_fresh(m[0], t) else m[1]

    def distances(self) -> dict[int, float]:
        """SfM distance per reciprocal edge whose estimate is at least ``chi_min_inv_m`` (the
        rigidity layer's scale; the localization and the formation's distances use the same
        rule). A received ``chihat`` of 1e-158, finite and within the codec's range, was a
        distance of 1e158 m (issue 23's bit-flip campaign)."""
        chi_min = self.gains.chi_min_inv_m
        return {j: 1.0 / c for j in self.reciprocal if (c := self.chi_hat(j)) and c >= chi_min}

    def _localize(self, own: Own) -> None:
        t_s = own.t_s
        peers, bearings = self.peers, self.bearings
        out_edges = []
        for j in bearings.out_targets:
            loc, b = peers.latest_fresh(LocalizationState, j, t_s), bearings.beta_out.get(j)
            if loc is not None and b is not None:
                out_edges.append((loc.p_hat_ned, b[1]))
        in_edges = []
        for j in bearings.in_sources:
            loc, b = peers.latest_fresh(LocalizationState, j, t_s), bearings.beta_in.get(j)
            if loc is not None and b is not None:
                in_edges.append((loc.p_hat_ned, loc.yaw_hat_rad, b[1]))
        distances = []
        for j in self.reciprocal:
            chi, loc = self.chi_hat(j), peers.latest(LocalizationState, j)
            if chi is not None and chi >= self.gains.chi_min_inv_m and loc is not None:
                distances.append((loc.p_hat_ned, 1.0 / chi))
        self.localization.step(
            own.dt_s, own.v_body, own.yaw_rate_rad_s, out_edges, in_edges, distances
        )

    # ------------------------------------------------------------ consensus
    def _consensus_step(self, name: str, dt: float, t_s: float, phi: list[float]) -> list[float]:
        g = self.gains
        est = self._consensus.get(name)
        if est is None:
            est = PIConsensus(list(phi), gamma=g.consensus_gamma, k_p=g.consensus_k_p,
                              k_i=g.consensus_k_i)  # fmt: skip
            self._consensus[name] = est
        fresh = self.peers.is_fresh
        nbrs = [
            (x, z)
            for stamp, x, z in self.cons_in.get(name, {}).values()
            if fresh(stamp, t_s) and len(x) == len(phi) and len(z) == len(phi)
        ]
        x = est.step(dt, phi, nbrs)
        self.share(name, x, est.z)
        return x

    def share(self, name: str, x: list[float], z: list[float]) -> None:
        """Add ``name``'s state to this step's :class:`messages.peer.ConsensusState`."""
        self._cons_out.append(ConsensusEntry(name, x, z))

    def _run_consensus(self, own: Own, outbox: list[Payload]) -> None:
        g = self.gains
        dt, t_s = own.dt_s, own.t_s
        n = self.n_agents
        fresh_at = self.peers.is_fresh
        for j, edge in self.sfm.items():
            if edge.beta_pred is not None:
                self.lam_table[(self.id, j)] = (t_s, edge.excitation)
        fresh = [(k, v) for k, v in self.lam_table.items() if fresh_at(v[0], t_s)]
        self.lambda_bar = act.lambda_bar([v[1] for _, v in fresh], g.p_norm)
        # own edges every step, the relayed rest of the table every few steps
        if own.seq % g.excitation_relay_every:
            fresh = [(k, v) for k, v in fresh if k[0] == self.id]
        if fresh:
            outbox.append(
                ExcitationTable(
                    sender=self.id,
                    seq=own.seq,
                    stamp_s=t_s,
                    entries=[EdgeExcitation(a, b, lam, s) for (a, b), (s, lam) in fresh],
                )
            )
        e_sum = sum(
            e.e_index + (g.e_high if e.e_folds < g.converged_e_folds else 0.0)
            for e in self.sfm.values()
        )
        x = self._consensus_step("e_index", dt, t_s, [e_sum])
        self.e_index = max(n * x[0], 0.0)
        if not self.rotation_terms:
            return
        loc = self.pose
        pb = self._consensus_step("p_bar", dt, t_s, list(loc.p_hat_ned))
        self.p_bar = (pb[0], pb[1], pb[2])
        grad = act.lambda_bar_gradient(self.excitation_terms(), self.lambda_bar, g.p_norm)
        n3 = act.rotation_velocity_body(loc.p_hat_ned, loc.yaw_hat_rad, self.p_bar)
        delta = grad[0] * n3[0] + grad[1] * n3[1] + grad[2] * n3[2]
        x = self._consensus_step("dlam_dwl", dt, t_s, [delta])
        self.dlam_dwl = n * x[0]

    def excitation_terms(self) -> list[tuple[Vec3, Vec3, float]]:
        """``(beta_ij, u_ij, lambda_ij)`` for reciprocal edges with a bearing and a relative yaw."""
        terms = []
        beta_out = self.bearings.beta_out
        for j, (_, u_ij) in self.rel.items():
            b = beta_out.get(j)
            if b is not None:
                terms.append((b[1], u_ij, excitation(b[1], u_ij)))
        return terms

    # ---------------------------------------------------------------- finish
    def finish(self, own: Own, outbox: list[Payload]) -> None:
        """Publish the consensus states, the own motion and the localization estimate."""
        seq, t_s = own.seq, own.t_s
        outbox.append(ConsensusState(sender=self.id, seq=seq, stamp_s=t_s, states=self._cons_out))
        outbox.append(
            MotionShare(
                sender=self.id,
                seq=seq,
                stamp_s=own.odometry_stamp_s,
                v_body=own.v_body,
                yaw_rate_rad_s=own.yaw_rate_rad_s,
                yaw_rad=own.yaw_rad,
            )
        )
        loc = self.localization
        outbox.append(
            LocalizationState(
                sender=self.id,
                seq=seq,
                stamp_s=t_s,
                p_hat_ned=loc.p_hat_ned,
                yaw_hat_rad=loc.yaw_hat_rad,
            )
        )

    def forget_time(self) -> None:
        """Histories, frames, observer clocks and stamped peer data go; estimates stay."""
        self.motion_hist = {j: SignalHistory(angle_index=4) for j in self.running}
        self._sfm_t.clear()
        for frames in self._sfm_frames.values():
            frames.clear()
        for edge in self.sfm.values():
            edge.resync()
            edge.last_frame_s = edge.t_s = -math.inf
            edge.window = WindowAverage(self.gains.e_window_s)
        for table in (self.sfm_in, self._e_folds_in, self.cons_in, self.lam_table):
            table.clear()
        self._jumps.clear()
        self.team_chi = {}
        self._team_chi_s = -math.inf

    # ---------------------------------------------------------------- status
    def scale_converged(self) -> bool:
        """Whether the metric scale can be trusted, from onboard information only: the network's
        convergence index ``E`` (eq. 10) is below ``e_low`` and every SfM edge this agent runs has
        been excited enough (:attr:`SfmEdge.e_folds`; shared in
        :class:`messages.peer.SfmEstimate` for the edges a neighbour runs), since ``E`` is also
        small before any motion."""
        g = self.gains
        if not self.reciprocal or self.e_index >= g.e_low:
            return False
        folds = [
            self.sfm[j].e_folds if j in self.sfm else self.received_e_folds(j)
            for j in self.reciprocal
        ]
        return min(folds) >= g.converged_e_folds

    def received_e_folds(self, j: int) -> float:
        """E-foldings of edge ``(j, self)`` as ``j`` last shared them; 0 once its SfM estimate
        is stale (a neighbour that went silent no longer vouches for the scale)."""
        m = self.sfm_in.get(j)
        if m is None or not self.peers.is_fresh(m[0], self.peers.t_s or 0.0):
            return 0.0
        return self._e_folds_in.get(j, 0.0)

    def status(self) -> dict[str, Any]:
        loc = self.localization
        return {
            "p_hat_ned": loc.p_hat_ned,
            "yaw_hat_rad": loc.yaw_hat_rad,
            "chi_hat_inv_m": {j: c for j in self.reciprocal if (c := self.chi_hat(j)) is not None},
            "e_index": self.e_index,
            "lambda_bar": self.lambda_bar,
            "scale_converged": self.scale_converged(),
        }
