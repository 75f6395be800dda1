"""The motion laws as layers: hold, the random-motion baseline, paper 000's active perception
(eq. 12 unconstrained, eq. 13-16 bearing-constrained) and the bearing formation law (paper 002
eq. 20) with yaw alignment.

Each returns the mode's velocity / yaw-rate command; the estimates it needs come from the scale
layer (:class:`onboard.core.scale.Scale`) and the camera layer
(:class:`onboard.core.bearings.Bearings`) it is built on. Explicit Euler with the step's ``dt``.

The formation laws take a new desired formation in flight (:meth:`Formation.adopt`, paper 002's
formation changes): its bearings ``beta*_ij`` and, when it holds its distances, the ``d*_ij`` of
eq. 23 (a scale change; the ``f_D`` terms use each agent's distance estimates, off by default).
The desired formation moves from the flown one to the new one over ``change_ramp_s`` (3 s by
default; :meth:`Formation.desired_now`), so the command changes without a step, and the status
says how far the switch has come (``formation_ramp``). A *leader* (paper 002, "leader" option of
:func:`onboard.distributed.flow.apply_leaders`) is not moved by the law: it holds, or flies the
external velocity the operator gives it (:class:`onboard.control.leader.LeaderPlan`: a velocity
or waypoints), and the others follow its bearings; in ``formation-active`` the active rotation
``w_l`` pauses meanwhile (a formation cannot turn about its centroid around a vehicle that holds).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, ClassVar

import msgspec
import numpy as np
from numpy.typing import NDArray

from messages.codec import Payload
from messages.peer import LocalizationState
from onboard.control import active_scale as act
from onboard.control.formation import (
    formation_distance_velocity,
    formation_velocity,
    ramp_fraction,
    slerp_bearing,
    yaw_alignment_rate,
)
from onboard.control.leader import LeaderPlan, ned_to_body
from onboard.control.random_motion import RandomMotion
from onboard.core.bearings import Bearings
from onboard.core.config import ActiveGains, FormationGains, Graph
from onboard.core.layer import Command, Own, Vec3
from onboard.core.peers import Route
from onboard.core.scale import Scale
from onboard.distributed.reshaping import ReshapeD
from onboard.geometry import bearings_body
from onboard.seeded import active_start_direction

FloatArray = NDArray[np.float64]

_ZERO: Vec3 = (0.0, 0.0, 0.0)


class _Controller:
    """What the controllers share: no peer payloads, nothing to publish or forget."""

    routes: ClassVar[Mapping[type, Route]] = MappingProxyType({})
    u_cmd: Vec3 = _ZERO
    """The velocity state of the active and random laws (zero for the others)."""
    k_e = 0.0
    w_l = 0.0

    def finish(self, own: Own, outbox: list[Payload]) -> None:
        return None

    def forget_time(self) -> None:
        return None

    def status(self) -> dict[str, Any]:
        return {}


def _speed(gains: ActiveGains) -> float:
    """The excitation speed ``sqrt(2 nu*)`` of eq. 12's set point."""
    return math.sqrt(2.0 * gains.nu_star)


class Hold(_Controller):
    """Zero command."""

    def step(self, own: Own, outbox: list[Payload]) -> Command | None:
        return Command(_ZERO, 0.0)


class Random(_Controller):
    """The random-motion baseline: an Ornstein-Uhlenbeck velocity at the active speed."""

    def __init__(self, graph: Graph, gains: ActiveGains) -> None:
        self._random = RandomMotion(
            seed=graph.seed * 1000 + graph.agent_id, speed_m_s=_speed(gains),
            tau_s=gains.random_tau_s,
        )  # fmt: skip

    def step(self, own: Own, outbox: list[Payload]) -> Command | None:
        self.u_cmd = self._random.step(own.dt_s)
        return Command(self.u_cmd, 0.0)


class Active(_Controller):
    """Unconstrained active perception (paper 000 eq. 12): the velocity climbs the gradient of
    ``lambdabar`` (eq. 11) at constant speed."""

    def __init__(self, graph: Graph, gains: ActiveGains, scale: Scale) -> None:
        self.gains = gains
        self.scale = scale
        d = active_start_direction(graph.seed, graph.agent_id)  # no numpy.random: 6.8 MB
        self.u_cmd = tuple((_speed(gains) * d).tolist())  # type: ignore[assignment]

    def step(self, own: Own, outbox: list[Payload]) -> Command | None:
        g, sc = self.gains, self.scale
        grad = act.lambda_bar_gradient(sc.excitation_terms(), sc.lambda_bar, sc.gains.p_norm)
        du = act.active_velocity_rate(self.u_cmd, grad, g.k_nu, g.nu_star, g.k_lambda)
        u, dt = self.u_cmd, own.dt_s
        self.u_cmd = (u[0] + dt * du[0], u[1] + dt * du[1], u[2] + dt * du[2])
        return Command(self.u_cmd, 0.0)


Edge = tuple[int, int]


@dataclass
class _Ramp:
    """A formation switch in progress (:meth:`Formation.adopt`): what was flown at the change."""

    ramp_s: float
    beta_from: dict[Edge, Vec3]
    d_from: dict[Edge, float]
    yaw_from: tuple[float, ...]
    t0_s: float | None = None
    """The first step after the change (its distance estimates fill ``d_from``'s gaps)."""


class Formation(_Controller):
    """``(u^F, w^F)``: the bearing formation law (paper 002 eq. 20), the distance terms of a
    formation with distances (eq. 23) and yaw alignment; a leader flies its drive instead."""

    def __init__(self, graph: Graph, gains: FormationGains, bearings: Bearings,
                 scale: Scale) -> None:  # fmt: skip
        self.id = graph.agent_id
        self.gains = gains
        self.bearings = bearings
        self.scale = scale
        self.neighbours = sorted(set(bearings.out_targets) | set(bearings.in_sources))
        self.desired = {(i, j): tuple(b) for i, j, b in gains.desired_beta_body}
        """The newest desired bearings ``beta*_ij`` (the ramp's end)."""
        self.desired_distance: dict[Edge, float] = {}
        """The newest desired distances ``d*_ij`` on this agent's edges (empty: bearings only)."""
        self.leader: int | None = None
        self.drive: LeaderPlan | None = None
        """This leader's external velocity (``None``: it holds)."""
        self.f_d = ReshapeD(w=gains.distance_weight, delta=gains.distance_delta_m)
        self._ramp: _Ramp | None = None
        self._flown: tuple[dict[Edge, Vec3], dict[Edge, float], tuple[float, ...]] = (
            self.desired, self.desired_distance, gains.desired_yaw_rad,
        )  # fmt: skip
        self.ramp_progress = 1.0
        self.distance_terms = 0
        self.drive_state = ""

    def adopt(self, p_ned: FloatArray, yaw_rad: FloatArray, leader: int | None,
              distances: bool = False, ramp_s: float | None = None) -> None:  # fmt: skip
        """Fly a new desired formation: vertex ``k`` of ``p_ned`` ``(N, 3)`` and ``yaw_rad``
        ``(N,)`` is agent ``k``; ``beta*_ij`` is recomputed on this agent's sensing edges, and
        with ``distances`` ``d*_ij = |p_j - p_i|`` on those incident to it (paper 002 eq. 23).

        The flown formation moves from the one flown now to the new one over ``ramp_s``
        (default ``gains.change_ramp_s``; :meth:`desired_now`). A drive is kept only while this
        agent stays the leader."""
        edges = np.array(sorted(self.desired), dtype=np.int64).reshape(-1, 2)
        beta, _ = bearings_body(p_ned, yaw_rad, edges)
        beta_from, d_from, yaw_from = self._flown
        self.desired = {
            (int(i), int(j)): tuple(b.tolist()) for (i, j), b in zip(edges, beta, strict=True)
        }
        me = self.id
        self.desired_distance = (
            {
                (int(i), int(j)): float(np.linalg.norm(p_ned[j] - p_ned[i]))
                for i, j in edges
                if me in (i, j)
            }
            if distances
            else {}
        )
        self.gains = msgspec.structs.replace(
            self.gains, desired_yaw_rad=tuple(float(y) for y in yaw_rad)
        )
        ramp = self.gains.change_ramp_s if ramp_s is None else ramp_s
        self._ramp = (
            _Ramp(ramp, dict(beta_from), dict(d_from), tuple(yaw_from)) if ramp > 0.0 else None
        )
        self._flown = (self.desired, self.desired_distance, self.gains.desired_yaw_rad)
        if leader != me or self.leader != me:
            self.drive = None
        self.leader = leader

    def drive_leader(self, plan: LeaderPlan | None) -> bool:
        """Fly ``plan`` (``None``: hold) if this agent is the formation's leader."""
        if self.leader != self.id:
            return False
        self.drive = plan
        return True

    def _distance(self, j: int, t_s: float) -> float | None:
        """This agent's estimate of its distance to ``j``: a fresh measured range (the camera's,
        :attr:`Bearings.range_out`), else the SfM distance of the edge
        (:meth:`onboard.core.scale.Scale.chi_hat`), else the distance between the localization
        estimates (eq. 6's ``phat``, whose scale the SfM distances fix); ``None`` without any."""
        sc = self.scale
        rng = self.bearings.range_out.get(j)
        if rng is not None and sc.peers.is_fresh(rng[0], t_s):
            return rng[1]
        chi = sc.chi_hat(j)
        if chi is not None and chi >= sc.gains.chi_min_inv_m:
            return 1.0 / chi
        loc = sc.peers.latest_fresh(LocalizationState, j, t_s)
        if loc is None:
            return None
        return math.dist(sc.localization.p_hat_ned, loc.p_hat_ned)

    def desired_now(
        self, t_s: float
    ) -> tuple[dict[Edge, Vec3], dict[Edge, float], tuple[float, ...]]:
        """The desired bearings, distances and yaws flown at ``t_s``: during a switch, a
        fraction ``s`` (:func:`ramp_fraction`) of the way from the old to the new formation:
        bearings along great circles (:func:`slerp_bearing`), distances and yaws linearly. An
        edge the old formation had no distance for starts from its estimate at the change."""
        r = self._ramp
        if r is None:
            self.ramp_progress = 1.0
            return self._flown
        if r.t0_s is None:
            r.t0_s = t_s
            for e in self.desired_distance:
                if e not in r.d_from:
                    d = self._distance(e[1] if e[0] == self.id else e[0], t_s)
                    if d is not None:
                        r.d_from[e] = d
        s = ramp_fraction(t_s - r.t0_s, r.ramp_s)
        self.ramp_progress = s
        if s >= 1.0:
            self._ramp = None
            self._flown = (self.desired, self.desired_distance, self.gains.desired_yaw_rad)
            return self._flown
        beta = {e: slerp_bearing(r.beta_from.get(e, b), b, s) for e, b in self.desired.items()}
        dist = {
            e: d + (1.0 - s) * (r.d_from[e] - d) if e in r.d_from else d
            for e, d in self.desired_distance.items()
        }
        yaw_to = self.gains.desired_yaw_rad
        yaw = yaw_to
        if len(r.yaw_from) == len(yaw_to):
            pairs = zip(r.yaw_from, yaw_to, strict=True)
            yaw = tuple(a + s * math.remainder(b - a, math.tau) for a, b in pairs)
        self._flown = (beta, dist, yaw)
        return self._flown

    def step(self, own: Own, outbox: list[Payload]) -> Command | None:
        if self.leader == self.id:
            self.desired_now(own.t_s)
            self.distance_terms = 0
            return Command(self.lead(own), 0.0)
        self.drive_state = ""
        return Command(*self.formation(own.t_s))

    def lead(self, own: Own) -> Vec3:
        """The leader's body-frame velocity: its drive's (NED in its odometry frame, turned by
        the odometry yaw), zero without one."""
        if self.drive is None:
            self.drive_state = "hold"
            return _ZERO
        p = own.raw.position_ned
        p_ok = p is not None and all(math.isfinite(x) for x in p)
        v_ned, self.drive_state = self.drive.step(own.t_s, p if p_ok else None)  # type: ignore[arg-type]
        return ned_to_body(v_ned, own.yaw_rad)

    def formation(self, t_s: float) -> tuple[Vec3, float]:
        g, me, b = self.gains, self.id, self.bearings
        desired, d_des, yaw_des = self.desired_now(t_s)
        yaw_i = self.scale.localization.yaw_hat_rad
        out_edges = [
            (b.beta_out[j][1], desired[(me, j)])
            for j in b.out_targets
            if j in b.beta_out and (me, j) in desired
        ]
        in_edges = []
        yaws = []
        psi: dict[int, float] = {}
        peers = self.scale.peers
        for j in self.neighbours:
            loc = peers.latest_fresh(LocalizationState, j, t_s)
            if loc is None:
                continue
            if yaw_des:
                yaws.append((loc.yaw_hat_rad, yaw_des[j] - yaw_des[me]))
            bj = b.beta_in.get(j)
            psi[j] = loc.yaw_hat_rad - yaw_i
            if bj is not None and (j, me) in desired:
                in_edges.append((psi[j], bj[1], desired[(j, me)]))
        u_f = formation_velocity(out_edges, in_edges, g.k_formation)
        w_f = yaw_alignment_rate(yaw_i, yaws, g.k_yaw)
        self.distance_terms = 0
        if d_des:
            u_d = self._distance_velocity(t_s, desired, d_des, psi)
            u_f = (u_f[0] + u_d[0], u_f[1] + u_d[1], u_f[2] + u_d[2])
        return u_f, w_f

    def _distance_velocity(self, t_s: float, desired: dict[Edge, Vec3],
                           d_des: dict[Edge, float], psi: dict[int, float]) -> Vec3:  # fmt: skip
        """Eq. 23's terms on the edges with a desired distance and a distance estimate."""
        me, b = self.id, self.bearings
        out_d = []
        in_d = []
        for j in self.neighbours:
            d = self._distance(j, t_s)
            if d is None:
                continue
            if (me, j) in d_des and j in b.beta_out:
                out_d.append((b.beta_out[j][1], desired[(me, j)], d, d_des[(me, j)]))
            bj = b.beta_in.get(j)
            if (j, me) in d_des and bj is not None and j in psi:
                in_d.append((psi[j], bj[1], desired[(j, me)], d, d_des[(j, me)]))
        self.distance_terms = len(out_d) + len(in_d)
        return formation_distance_velocity(out_d, in_d, self.gains.k_formation, self.f_d)

    def forget_time(self) -> None:
        """After the clock went back: a switch in progress and a drive restart their clocks."""
        if self._ramp is not None:
            self._ramp.t0_s = None
        if self.drive is not None:
            self.drive.t0_s = None

    def status(self) -> dict[str, Any]:
        return {
            "formation_ramp": self.ramp_progress,
            "distance_terms": self.distance_terms,
            "leader_drive": self.drive_state,
        }


class FormationActive(Formation):
    """The formation law plus the bearing-constrained active rotation ``w_l`` of paper 000
    eq. 13-16, coupled to the neighbours' ``w_l`` and shared through the scale layer's
    consensus payload."""

    def __init__(self, graph: Graph, formation: FormationGains, active: ActiveGains,
                 bearings: Bearings, scale: Scale) -> None:  # fmt: skip
        super().__init__(graph, formation, bearings, scale)
        self.active = active

    def step(self, own: Own, outbox: list[Payload]) -> Command | None:
        if self.leader is not None:
            # a formation cannot turn about its centroid around a vehicle that holds: with a
            # leader the active rotation pauses and every follower flies the plain law
            return super().step(own, outbox)
        t_s, dt = own.t_s, own.dt_s
        u_f, w_f = self.formation(t_s)
        g, sc = self.active, self.scale
        self.k_e = act.convergence_gain(sc.e_index, sc.gains.e_low, sc.gains.e_high)
        dw = act.rotation_rate_derivative(
            self.w_l,
            sc.dlam_dwl,
            sc.lambda_bar,
            self.k_e,
            g.k_w,
            g.k_lambda0,
            g.gamma,
            g.w_l_start_rad_s,
        )
        shared = [x[0] for x in sc.shared("w_l", t_s) if len(x) == 1]
        dw += g.k_w_l_coupling * sum(w - self.w_l for w in shared)
        # anti-windup: the vehicle cannot turn the formation faster than this, so integrating
        # past it only stores error (with delayed lambdabar it ran away to 1e35 otherwise)
        self.w_l = max(-g.w_l_max_rad_s, min(g.w_l_max_rad_s, self.w_l + dt * dw))
        sc.share("w_l", [self.w_l], [])
        loc = sc.pose
        n3 = act.rotation_velocity_body(loc.p_hat_ned, loc.yaw_hat_rad, sc.p_bar)
        wl = self.w_l
        return Command((u_f[0] + wl * n3[0], u_f[1] + wl * n3[1], u_f[2] + wl * n3[2]), w_f + wl)
