"""The agent core: one vehicle's estimators and controllers, composed of layers, with no I/O.

``AgentCore.step(t_s, own, inbox) -> (setpoint, outbox)`` sees only the vehicle's own
measurements (:class:`messages.agent.OwnMeasurements`) and the peer payloads it received
(:mod:`messages.peer`, :mod:`messages.rigidity`); it never sees simulator truth. Per step:

1. the peer table (:class:`onboard.core.peers.PeerTable`) checks every payload (sender, stamp)
   and hands it to the layer that takes its kind;
2. the own measurements are checked finite (else: zero setpoint, nothing published);
3. the mode's layers (:data:`onboard.core.modes.MODE_LAYERS`) step in order: the camera
   (:mod:`onboard.core.bearings`), paper 000's scale estimation (:mod:`onboard.core.scale`), a
   motion law (:mod:`onboard.core.motion`), paper 003's rigidity maintenance
   (:mod:`onboard.core.rigidity`); their velocity / yaw-rate contributions add up, and the sum
   is saturated (``v_max_m_s``, ``yaw_rate_max_rad_s``);
4. the layers publish what depends on the whole step (:meth:`onboard.core.layer.Layer.finish`);
   the outbox goes out in the fixed kind order :data:`OUTBOX_ORDER`.

Explicit Euler with the step's ``dt`` everywhere (paper 000's loop is 2 ms).
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from messages.agent import AgentStatus, OwnMeasurements, Setpoint
from messages.codec import Payload
from messages.limits import STAMP_FUTURE_MAX_S
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
from messages.vocabulary import DropReason
from onboard.control.leader import LeaderPlan
from onboard.core.bearings import finite
from onboard.core.config import AgentConfig
from onboard.core.layer import Command, Own, Vec3
from onboard.core.modes import compose
from onboard.core.motion import FloatArray, Formation
from onboard.core.peers import Drops, PeerTable, Route
from onboard.core.scale import Pose
from onboard.estimation.localization import LocalizationFilter

OUTBOX_ORDER: tuple[type, ...] = (
    BearingShare,
    SfmEstimate,
    AngleLocalizationShare,
    RigidityEigenShare,
    ExcitationTable,
    ConsensusState,
    MotionShare,
    LocalizationState,
    GradientLocalizationShare,
)
"""The peer payload kinds, in the order a step's outbox lists them (at most one of each per
step): a lossy link drops them in a reproducible order whatever the layers' order."""
_RANK = {kind: r for r, kind in enumerate(OUTBOX_ORDER)}
HEARD_WINDOW_S = 1.0
"""A neighbour heard from within this long is listed in the status."""


def _saturate(v: Vec3, limit: float) -> Vec3:
    n = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    if n <= limit:
        return v
    k = limit / n
    return (k * v[0], k * v[1], k * v[2])


def _add(a: Command, b: Command) -> Command:
    u, v = a.v_body, b.v_body
    return Command((u[0] + v[0], u[1] + v[1], u[2] + v[2]), a.yaw_rate_rad_s + b.yaw_rate_rad_s)


class AgentCore:
    """One vehicle's agent core (module docstring)."""

    def __init__(self, config: AgentConfig) -> None:
        self.config = config
        g = config.graph
        me = g.agent_id
        self.id = me
        self.neighbours = sorted({j for e in g.edges if me in e for j in e} - {me})
        """Communication neighbours on the sensing graph (both directions of every edge)."""
        self.dropped = Drops()
        """Counts of dropped inputs by reason."""
        self.peers = PeerTable(frozenset(self.neighbours), config.safety.peer_timeout_s,
                               self.dropped)  # fmt: skip
        comp = compose(config, self.peers, self.dropped)
        self.layers = comp.layers
        self.bearings = comp.bearings
        self.scale = comp.scale
        """Paper 000's scale estimation (``None`` in ``rigidity-tracking``)."""
        self.controller = comp.controller
        self.rigidity = comp.rigidity
        """Paper 003's rigidity layer (``None`` unless the mode or maintenance needs it)."""
        self.gradient_localization = comp.gradient_localization
        """Paper 002's localization layer (``None`` unless ``localization = "paper002"``)."""
        self.rigidity_neighbours: frozenset[int] = (
            frozenset() if self.rigidity is None else frozenset(self.rigidity.neighbours)
        )
        for layer in self.layers:
            for kind, route in layer.routes.items():
                self.peers.route(kind, route)
        for kind in OUTBOX_ORDER:  # known kinds no layer takes: counted as unknown_type
            if kind not in self.peers.routes:
                self.peers.route(kind, Route(self.peers.neighbours))
        self._prior = LocalizationFilter(g.p0(me), g.yaw0(me), config.scale.k_loc_bearing,
                                         config.scale.k_loc_distance)  # fmt: skip
        self._t: float | None = None
        self._seq = 0

    # ------------------------------------------------------------ estimates
    @property
    def localization(self) -> LocalizationFilter:
        """Paper 000's localization filter (eq. 6); without the scale layer, the prior (angle
        localization's estimate is ``rigidity.loc``)."""
        return self._prior if self.scale is None else self.scale.localization

    @property
    def pose(self) -> Pose:
        """The position estimate the core flies on: :attr:`localization`, or paper 002's
        (:mod:`onboard.core.localization002`) when selected."""
        return self._prior if self.scale is None else self.scale.pose

    @property
    def lambda_bar(self) -> float:
        """``lambdabar`` (eq. 11) as this agent knows it (0 without the scale layer)."""
        return 0.0 if self.scale is None else self.scale.lambda_bar

    @property
    def e_index(self) -> float:
        """Network convergence index ``E`` (eq. 10) by consensus (0 without the scale layer)."""
        return 0.0 if self.scale is None else self.scale.e_index

    @property
    def k_e(self) -> float:
        """Convergence gate ``k_E(E)`` of eq. 16 (formation-active; 0 otherwise)."""
        return 0.0 if self.controller is None else self.controller.k_e

    @property
    def w_l(self) -> float:
        """Active rotation rate ``w_l`` of eq. 13-15 (formation-active; 0 otherwise)."""
        return 0.0 if self.controller is None else self.controller.w_l

    def chi_hat(self, j: int) -> float | None:
        """Inverse-distance estimate on reciprocal edge ``(self, j)``
        (:meth:`onboard.core.scale.Scale.chi_hat`; ``None`` without the scale layer)."""
        return None if self.scale is None else self.scale.chi_hat(j)

    def scale_converged(self) -> bool:
        """Whether the metric scale can be trusted
        (:meth:`onboard.core.scale.Scale.scale_converged`; never without the scale layer)."""
        return self.scale is not None and self.scale.scale_converged()

    # ----------------------------------------------------------------- step
    def step(
        self, t_s: float, own: OwnMeasurements, inbox: Iterable[Payload] = ()
    ) -> tuple[Setpoint, list[Payload]]:
        """Advance the core to ``t_s`` and return the setpoint and the payloads to publish."""
        cfg = self.config
        dt = 0.0 if self._t is None else t_s - self._t
        if dt < 0.0:
            self.dropped.count(DropReason.TIME_BACKWARDS)
            if dt < -STAMP_FUTURE_MAX_S:  # the clock was reset (a restarted simulator)
                self._forget_time()
            dt = 0.0
        self._t = self.peers.t_s = t_s
        for msg in inbox:
            self.peers.receive(msg, t_s)

        try:  # plain floats: numpy scalars must not leak into payloads
            v = own.v_body
            u_i = (float(v[0]), float(v[1]), float(v[2]))
            w_i = float(own.yaw_rate_rad_s)
            yaw_own = float(own.yaw_rad)
        except (TypeError, ValueError, IndexError):
            u_i, w_i, yaw_own = (math.nan,) * 3, math.nan, math.nan
        if not (finite(u_i) and math.isfinite(w_i) and math.isfinite(yaw_own)):
            self.dropped.count(DropReason.NONFINITE_OWN)
            return Setpoint(v_body=(0.0, 0.0, 0.0), yaw_rate_rad_s=0.0), []
        odo_s = own.odometry_stamp_s
        if odo_s is None or not math.isfinite(odo_s) or odo_s > t_s + cfg.safety.peer_timeout_s:
            odo_s = t_s
        now = Own(t_s=t_s, dt_s=dt, seq=self._seq, v_body=u_i, yaw_rate_rad_s=w_i,
                  yaw_rad=yaw_own, odometry_stamp_s=odo_s, raw=own)  # fmt: skip

        outbox: list[Payload] = []
        cmd: Command | None = None
        for layer in self.layers:
            c = layer.step(now, outbox)
            if c is not None:
                cmd = c if cmd is None else _add(cmd, c)
        for layer in self.layers:
            layer.finish(now, outbox)
        outbox.sort(key=lambda m: _RANK[type(m)])
        self._seq += 1
        if cmd is None:
            return Setpoint(v_body=(0.0, 0.0, 0.0), yaw_rate_rad_s=0.0), outbox
        lim = cfg.safety
        v_out = _saturate(cmd.v_body, lim.v_max_m_s)
        w = max(-lim.yaw_rate_max_rad_s, min(lim.yaw_rate_max_rad_s, cmd.yaw_rate_rad_s))
        return Setpoint(v_body=v_out, yaw_rate_rad_s=w), outbox

    def _forget_time(self) -> None:
        """Resynchronize after the clock went back by more than
        :data:`messages.limits.STAMP_FUTURE_MAX_S` (a restarted simulator, a stepped wall
        clock): everything kept "newest by stamp" now lies in the future and would never be
        replaced, so the peer table, histories, frames and relative yaws are dropped and
        rebuilt from the next samples. Estimates (``phat``, ``chihat``, consensus) are kept."""
        self.peers.clear()
        for layer in self.layers:
            layer.forget_time()

    # ------------------------------------------------------------ formation changes
    def adopt_formation(
        self,
        p_ned: FloatArray,
        yaw_rad: FloatArray,
        leader: int | None = None,
        distances: bool = False,
        ramp_s: float | None = None,
    ) -> bool:
        """Fly a new desired formation (agent ``k`` at ``p_ned[k]`` with yaw ``yaw_rad[k]``;
        ``leader`` holds its position or flies :meth:`drive_leader`'s drive; ``distances``: its
        distances too, paper 002 eq. 23; reached over ``ramp_s``,
        :meth:`onboard.core.motion.Formation.adopt`): ``False`` when this mode flies no
        formation."""
        if not isinstance(self.controller, Formation):
            return False
        self.controller.adopt(p_ned, yaw_rad, leader, distances, ramp_s)
        return True

    def drive_leader(self, plan: LeaderPlan | None) -> bool:
        """Fly ``plan`` (an external velocity or waypoints, :mod:`onboard.control.leader`;
        ``None``: hold) as the formation's leader: ``False`` unless this agent is the leader of
        the formation it flies."""
        if not isinstance(self.controller, Formation):
            return False
        return self.controller.drive_leader(plan)

    # -------------------------------------------------------------- status
    def status(self) -> AgentStatus:
        """Health and estimates for the ground station (each layer's fields)."""
        t = self._t or 0.0
        loc = self._prior
        fields: dict[str, object] = {
            "p_hat_ned": loc.p_hat_ned,
            "yaw_hat_rad": loc.yaw_hat_rad,
            "chi_hat_inv_m": {},
            "e_index": 0.0,
            "lambda_bar": 0.0,
        }
        for layer in self.layers:
            fields.update(layer.status())
        return AgentStatus(
            sender=self.id,
            seq=self._seq,
            stamp_s=t,
            mode=self.config.mode,
            neighbours=self.peers.heard_within(t, HEARD_WINDOW_S),
            **fields,  # type: ignore[arg-type]
        )
