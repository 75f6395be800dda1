"""The motion laws as layers: hold, the random-motion baseline, paper 000's active perception
(eq. 12 unconstrained, eq. 13-16 bearing-constrained) and the bearing formation law (paper 002
eq. 20) with yaw alignment.

Each returns the mode's velocity / yaw-rate command; the estimates it needs come from the scale
layer (:class:`onboard.core.scale.Scale`) and the camera layer
(:class:`onboard.core.bearings.Bearings`) it is built on. Explicit Euler with the step's ``dt``.

The formation laws take a new desired formation in flight (:meth:`Formation.adopt`, paper 002's
formation changes): the gradient flow simply descends towards the new ``beta*_ij`` from where the
team is, so the switch is continuous in position (the link saturates the velocity step). A
*leader* (paper 002, "leader" option of :func:`onboard.distributed.flow.apply_leaders` with a zero
external velocity) is not moved by the law: it holds, and the others follow its bearings; in
``formation-active`` the active rotation ``w_l`` pauses meanwhile (a formation cannot turn about
its centroid around a vehicle that holds).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any, ClassVar

import msgspec
import numpy as np
from numpy.typing import NDArray

from messages.codec import Payload
from messages.peer import LocalizationState
from onboard.control import active_scale as act
from onboard.control.formation import formation_velocity, yaw_alignment_rate
from onboard.control.random_motion import RandomMotion
from onboard.core.bearings import Bearings
from onboard.core.config import ActiveGains, FormationGains, Graph
from onboard.core.layer import Command, Own, Vec3
from onboard.core.peers import Route
from onboard.core.scale import Scale
from onboard.geometry import bearings_body

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
        d = np.random.default_rng(graph.seed * 1000 + graph.agent_id + 500).standard_normal(3)
        self.u_cmd = tuple((_speed(gains) * d / np.linalg.norm(d)).tolist())  # type: ignore[assignment]

    def step(self, own: Own, outbox: list[Payload]) -> Command | None:
        g, sc = self.gains, self.scale
        grad = act.lambda_bar_gradient(sc.excitation_terms(), sc.lambda_bar, sc.gains.p_norm)
        du = act.active_velocity_rate(self.u_cmd, grad, g.k_nu, g.nu_star, g.k_lambda)
        u, dt = self.u_cmd, own.dt_s
        self.u_cmd = (u[0] + dt * du[0], u[1] + dt * du[1], u[2] + dt * du[2])
        return Command(self.u_cmd, 0.0)


class Formation(_Controller):
    """``(u^F, w^F)``: the bearing formation law (paper 002 eq. 20) and yaw alignment."""

    def __init__(self, graph: Graph, gains: FormationGains, bearings: Bearings,
                 scale: Scale) -> None:  # fmt: skip
        self.id = graph.agent_id
        self.gains = gains
        self.bearings = bearings
        self.scale = scale
        self.neighbours = sorted(set(bearings.out_targets) | set(bearings.in_sources))
        self.desired = {(i, j): tuple(b) for i, j, b in gains.desired_beta_body}
        self.leader: int | None = None

    def adopt(self, p_ned: FloatArray, yaw_rad: FloatArray, leader: int | None) -> None:
        """Fly a new desired formation: vertex ``k`` of ``p_ned`` ``(N, 3)`` and ``yaw_rad``
        ``(N,)`` is agent ``k``; ``beta*_ij`` is recomputed on this agent's sensing edges."""
        edges = np.array(sorted(self.desired), dtype=np.int64).reshape(-1, 2)
        beta, _ = bearings_body(p_ned, yaw_rad, edges)
        self.desired = {
            (int(i), int(j)): tuple(b.tolist()) for (i, j), b in zip(edges, beta, strict=True)
        }
        self.gains = msgspec.structs.replace(
            self.gains, desired_yaw_rad=tuple(float(y) for y in yaw_rad)
        )
        self.leader = leader

    def step(self, own: Own, outbox: list[Payload]) -> Command | None:
        if self.leader == self.id:
            return Command(_ZERO, 0.0)
        return Command(*self.formation(own.t_s))

    def formation(self, t_s: float) -> tuple[Vec3, float]:
        g, me, b = self.gains, self.id, self.bearings
        yaw_i = self.scale.localization.yaw_hat_rad
        out_edges = [
            (b.beta_out[j][1], self.desired[(me, j)])
            for j in b.out_targets
            if j in b.beta_out and (me, j) in self.desired
        ]
        in_edges = []
        yaws = []
        peers = self.scale.peers
        for j in self.neighbours:
            loc = peers.latest_fresh(LocalizationState, j, t_s)
            if loc is None:
                continue
            if g.desired_yaw_rad:
                yaws.append((loc.yaw_hat_rad, g.desired_yaw_rad[j] - g.desired_yaw_rad[me]))
            bj = b.beta_in.get(j)
            if bj is not None and (j, me) in self.desired:
                in_edges.append((loc.yaw_hat_rad - yaw_i, bj[1], self.desired[(j, me)]))
        u_f = formation_velocity(out_edges, in_edges, g.k_formation)
        w_f = yaw_alignment_rate(yaw_i, yaws, g.k_yaw)
        return u_f, w_f


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
