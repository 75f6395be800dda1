"""The agent core's configuration: small frozen groups, one per layer, with paper 000's values as
defaults (paper 003's rigidity scenarios' for the rigidity group).

Each layer of :mod:`onboard.core` takes only the group(s) it needs: the bearings and the peer
table take :class:`Graph` and :class:`Safety`, paper 000's scale estimation
(:mod:`onboard.core.scale`) :class:`ScaleGains`, the motion laws (:mod:`onboard.core.motion`)
:class:`ActiveGains` and :class:`FormationGains`, paper 003's rigidity maintenance
(:mod:`onboard.core.rigidity`) :class:`RigidityGains`, paper 002's distributed localization
(:mod:`onboard.core.localization002`) :class:`GradientLocalizationGains`.

Field names are unique across the groups, so a flat ``name=value`` (a sweep parameter, a scenario
override) still names one field: :func:`build_config` and :func:`replace_fields` route them to
their group, :data:`FIELD_GROUP` says which group holds a name.
"""

from __future__ import annotations

import math
import typing
from typing import Any, Literal

import msgspec

from messages.vocabulary import LOCALIZATIONS, MODES, Localization, Mode
from onboard.graph import reciprocal_components

Vec3 = tuple[float, float, float]


class Graph(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Who this agent is, whom it senses and talks to, and the shared prior."""

    agent_id: int
    n_agents: int
    edges: tuple[tuple[int, int], ...]
    """Directed sensing graph of the fleet: ``(i, j)`` means ``i`` measures the bearing to ``j``.
    Agents communicate along every edge in both directions."""
    p_hat0_ned: tuple[Vec3, ...] = ()
    """Initial localization guess of every agent (the shared prior of paper 000 Sect. V; it also
    initializes the SfM observers, ``chihat_ij = 1 / |phat_j - phat_i|``)."""
    yaw_hat0_rad: tuple[float, ...] = ()
    seed: int = 0
    """Seeds the agent's random draws (random motion, the active start, the eigen-estimate)."""

    def __post_init__(self) -> None:
        n = self.n_agents
        if not 0 <= self.agent_id < n:
            raise ValueError(f"agent_id {self.agent_id} outside 0..{n - 1}")
        _check_edges(self.edges, n)
        if len(self.p_hat0_ned) not in (0, n) or len(self.yaw_hat0_rad) not in (0, n):
            raise ValueError("p_hat0_ned and yaw_hat0_rad need one entry per agent")

    def p0(self, i: int) -> Vec3:
        """Agent ``i``'s prior position (the origin without a prior)."""
        return tuple(self.p_hat0_ned[i]) if self.p_hat0_ned else (0.0, 0.0, 0.0)  # type: ignore[return-value]

    def yaw0(self, i: int) -> float:
        """Agent ``i``'s prior yaw (0 without a prior)."""
        return self.yaw_hat0_rad[i] if self.yaw_hat0_rad else 0.0


class Safety(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Limits of the setpoint and of the peer data's age."""

    v_max_m_s: float = 3.0
    yaw_rate_max_rad_s: float = 1.5
    peer_timeout_s: float = 0.5
    """Peer data older than this is not used (the peer table's freshness)."""


class ScaleGains(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Paper 000's scale estimation: SfM observers (eq. 8, 10), localization (eq. 6), the
    consensus estimators (fig. 1) and the excitation index ``lambdabar`` (eq. 11)."""

    # SfM observer (eq. 8) and convergence index (eq. 10)
    alpha: float = 10.0
    h_other: float = 10.0
    h_floor: float = 1e-3
    e_window_s: float = 1.0
    sfm_bias_speed_m_s: float = 0.1
    """Odometry velocity error the SfM observers tolerate (:func:`~onboard.estimation.\
sfm_observer.excitation_gate`): they correct their inverse depth only where the relative
    velocity normal to the bearing exceeds it (fully above twice it). Real autopilots' velocity
    is off by 1-5 cm/s (ArduCopter SITL, docs/sim.md), and a hovering team whose formation
    control flies against that bias let the observers walk away (issue 22). 0: paper 000's
    observer (the paper reproductions, ``sim/scenarios.py``). Not in the paper."""
    sfm_folds_forget_s: float = 0.0
    """The e-foldings of excitation (:attr:`SfmEdge.e_folds`) are forgotten over this time
    (0: never, paper 000): without recent excitation the scale is no longer claimed converged,
    and the active motion (gate of eq. 16, :attr:`converged_e_folds`) resumes. Not in the
    paper."""
    sfm_wander_window_s: float = 2.0
    sfm_wander_max: float = 0.02
    """While an observer's corrections moved its ``chihat`` by more than this fraction within
    the last ``sfm_wander_window_s`` its e-foldings are held below :attr:`converged_e_folds`:
    an estimate that wanders is not converged (0: not watched, paper 000). Not in the paper."""
    sfm_bias_gain: float = 0.0
    """Gain ``gamma`` (1/s^2) of each SfM observer's estimate of its edge's relative velocity
    bias, which it then subtracts (:func:`~onboard.estimation.sfm_observer.bias_rate`,
    docs/equations.md "Relative velocity bias of an SfM edge"; 0: not estimated, paper 000's
    observer). Not in the paper; an experiment (issue 22, docs/sim.md)."""
    sfm_bias_max_m_s: float = 0.1
    """Largest relative velocity bias an SfM observer may estimate."""
    sfm_team_scale: bool = False
    """Report and use every reciprocal pair's distance on ONE team scale: the SfM distances
    fused through the shape the bearings fix (:mod:`onboard.estimation.team_scale`,
    docs/equations.md "Fused team scale"; False: each edge's own SfM estimate, paper 000). Not
    in the paper; an experiment (issue 22)."""
    chi_min_inv_m: float = 0.02
    """SfM estimates below this (distance above 50 m) are not used as virtual measurements."""
    # localization (eq. 6)
    k_loc_bearing: float = 100.0
    k_loc_distance: float = 1.0
    # consensus (PI estimator) and the sharing of w_l between neighbours. Peer values arrive one
    # network delay ``tau`` late, and a delayed consensus ``x' = -k L x(t - tau)`` is stable only
    # while ``k mu_max tau < pi/2`` (Olfati-Saber & Murray 2004; ``mu_max`` the largest Laplacian
    # eigenvalue, 6-8 in the demo graphs). ``k_p = 20`` failed at 60 ms; ``k_p = k_i = 1`` holds
    # past 200 ms with 10% loss, at the price of a slower case 4 (6.5 s -> 7-9 s to converge;
    # the case 4 scenario runs k_p = k_i = 3, sim.scenarios.CASE4_GAINS, README).
    consensus_gamma: float = 50.0
    consensus_k_p: float = 1.0
    consensus_k_i: float = 1.0
    excitation_relay_every: int = 5
    """Steps between relays of the whole excitation table (own edges go out every step)."""
    p_norm: float = -5.0
    """Exponent of the soft minimum ``lambdabar`` (eq. 11)."""
    e_low: float = 1e-4
    e_high: float = 1e-3
    """The convergence gate ``k_E(E)`` of eq. 16 runs from ``e_low`` to ``e_high``."""
    converged_e_folds: float = 5.0
    """An SfM edge counts as excited once ``int sqrt(alpha lambda) dt`` (the e-foldings of its
    error, :attr:`SfmEdge.e_folds`) reaches this (``exp(-5)``: under 1% of the initial error
    left). Until every edge is, each of its owners adds ``e_high`` to its share of ``E``, so the
    gate ``k_E(E)`` of eq. 16 keeps the active motion on: ``E`` alone is also small while an edge
    that was barely excited is still wrong (demo runs stalled at 4% this way). Not in the paper."""

    def __post_init__(self) -> None:
        if self.excitation_relay_every < 1:
            raise ValueError("excitation_relay_every must be >= 1")
        if self.p_norm >= 0.0:
            raise ValueError("p_norm must be negative (a soft minimum)")
        for name in (
            "sfm_bias_speed_m_s",
            "sfm_folds_forget_s",
            "sfm_wander_max",
            "sfm_bias_gain",
            "sfm_bias_max_m_s",
        ):
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if not self.sfm_wander_window_s > 0.0:
            raise ValueError(f"sfm_wander_window_s must be > 0, got {self.sfm_wander_window_s}")


class ActiveGains(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Paper 000's active perception (eq. 11-16) and the random-motion baseline."""

    # unconstrained active perception (eq. 11-12)
    k_nu: float = 10.0
    nu_star: float = 0.25
    k_lambda: float = 15.0
    # bearing-constrained active perception (eq. 13-16)
    k_w: float = 1.0
    gamma: float = 0.05
    k_lambda0: float = 2.0
    k_w_l_coupling: float = 2.0
    """Gain of the coupling of ``w_l`` to the neighbours' shared values."""
    w_l_max_rad_s: float = 0.3
    """Bound of the active rotation rate ``w_l`` of eq. 13-15 (anti-windup, not in the paper)."""
    w_l_start_rad_s: float = 0.0
    """The damping of eq. 15 pulls ``w_l`` towards ``k_E(E)`` times this instead of 0
    (:func:`onboard.control.active_scale.rotation_rate_derivative`): the active rotation starts
    while the formation converges. 0: paper 000's eq. 15. Not in the paper."""
    # random-motion baseline
    random_tau_s: float = 1.0


class FormationGains(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """The desired formation and the gains of its law (paper 002 eq. 20) and yaw alignment."""

    desired_beta_body: tuple[tuple[int, int, Vec3], ...] = ()
    """Desired formation: body-frame bearing ``beta*_ij`` per edge ``(i, j, beta)``."""
    desired_yaw_rad: tuple[float, ...] = ()
    """Desired yaws (only their differences matter)."""
    k_formation: float = 0.5
    k_yaw: float = 1.0
    change_ramp_s: float = 3.0
    """A new desired formation (:meth:`onboard.core.motion.Formation.adopt`) replaces the flown
    one over this time (smoothstep, :func:`onboard.control.formation.ramp_fraction`); a
    :class:`messages.command.FormationChange` may ask for another."""
    distance_weight: float = 0.25
    """``w`` of the formation's ``f_D`` (paper 002 eq. 23; pseudo-Huber
    :class:`onboard.distributed.reshaping.ReshapeD`), 1/m: a desired-distance error ``x`` adds
    ``k_formation w x`` m/s per edge while ``|x|`` is well below ``distance_delta_m``."""
    distance_delta_m: float = 2.0
    """``delta`` of that pseudo-Huber: each edge adds at most ``k_formation w delta`` m/s
    (0.25 m/s by default), so a large scale change is flown at a bounded speed."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.change_ramp_s) and self.change_ramp_s >= 0.0):
            raise ValueError(f"change_ramp_s must be >= 0, got {self.change_ramp_s}")
        if not (math.isfinite(self.distance_weight) and self.distance_weight >= 0.0):
            raise ValueError(f"distance_weight must be >= 0, got {self.distance_weight}")
        if not (math.isfinite(self.distance_delta_m) and self.distance_delta_m > 0.0):
            raise ValueError(f"distance_delta_m must be > 0, got {self.distance_delta_m}")


class RigidityGains(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Paper 003's rigidity maintenance; defaults are the rigidity scenarios' values."""

    rigidity_maintenance: bool = False
    """Add the rigidity-maintenance action (eq. 19-23) and collision avoidance to the mode's
    command. Mode ``rigidity-tracking`` without it is the paper's "maintenance off" baseline."""
    rigidity_edges: tuple[tuple[int, int], ...] = ()
    """The rigidity layer's graph (default: ``edges``): ``(i, j)`` when ``i``'s camera may see
    ``j``. Its angles make the weighted rigidity matrix, and its out-neighbours are the
    candidates of the eigen-estimate; the sensing weights drop the ones out of view. With an
    all-round camera the complete graph is the graph the cameras actually sense, and the
    formation's own (sparser) edges would understate the rigidity the team has."""
    rigidity_eigen: Literal["distributed", "centralized"] = "distributed"
    """Where ``lambda`` and its gradient come from: the distributed power iteration, or every
    agent's shared estimate (needs all-to-all communication)."""
    rigidity_scale_from_sfm: bool = False
    """Use SfM distances (paper 000) as the scale of angle localization besides ranges."""
    fov_deg: float = 120.0
    range_m: float = 15.0
    lambda_min: float = 0.02
    lambda_safe: float = 0.2
    k_rigidity: float = 0.05
    r_coll_m: float = 0.6
    r_safe_m: float = 1.5
    k_collision: float = 1.0
    track_target: int = -1
    """Mission target this agent tracks (-1: none)."""
    r_track_m: float = 2.0
    k_track_range: float = 0.15
    k_track_camera: float = 0.4
    k_angle_loc: float = 4.0
    k_distance_loc: float = 1.0
    k_vertical_loc: float = 4.0
    """Gain of the gravity (bearing elevation) term of angle localization; 0 = angles only."""
    rigidity_softmin_tau: float = 0.01
    """The rigidity action follows the gradient of a smooth minimum of the tracked modes' eigenvalues
    at this temperature (:func:`onboard.control.rigidity.softmin_weights`; 0: the smallest
    mode alone, as in paper 003)."""
    eigen_columns: int = 3
    eigen_step: float = 1.5
    eigen_k_t: float = 0.3
    eigen_k_n: float = 0.2
    """Distributed eigen-estimation (:class:`onboard.estimation.distributed_eigen.EigenGains`):
    vectors tracked, power step over the degree bound, per-round consensus gains."""
    rigidity_period_s: float = 0.0
    """The rigidity layer steps at most this often (0: every core step), integrating over the
    time since its last step. It is a slow outer loop and costs several times the rest of the
    core; the daemons' 6 x 100 Hz of it did not fit on two cores."""
    rigidity_warmup_s: float = 0.0
    """Seconds after the first step during which the rigidity layer's actions are zero, so
    angle localization and the eigen-estimate converge before the team moves."""


class GradientLocalizationGains(msgspec.Struct, frozen=True, kw_only=True,
                                forbid_unknown_fields=True):  # fmt: skip
    """Which localization the core flies on, and paper 002's (eq. 16-17 and 22) gains."""

    localization: Localization = "paper000"
    """``"paper002"``: the distributed gradient localization layer
    (:class:`onboard.core.localization002.GradientLocalization`) runs after the scale layer and
    its ``T_i`` replaces paper 000's ``phat_i`` for the controllers and the status (paper 000's
    filter still runs: its yaw is the known rotation). Needs the scale layer."""
    gradloc_range_weight: float = 1.0
    """``w`` of ``f_D(x) = w x^2`` (eq. 22) on the edges with an SfM distance: the relative
    weight of a range against a bearing residual (both in metres)."""
    gradloc_measured_range_weight: float = 1.0
    """``w`` of ``f_D(x) = w x^2`` (eq. 22) on the out-edges with a fresh *measured* range
    (``own.ranges``: the camera's disc ranges); it replaces the SfM distance there until the
    SfM scale has converged, then both count, each with its weight
    (:mod:`onboard.core.localization002`). It expresses the noise of a range against a
    bearing's: with bearing noise ``sigma_b`` (rad) at distance ``d`` and range noise
    ``sigma_r`` (m), ``w ~ (sigma_b d / sigma_r)^2`` (:mod:`onboard.distributed.reshaping`);
    against the SfM distance's term the ratio of the two weights is that of the inverse
    variances. 1: as the SfM distances. Measured in the camera e2e flight (3 vehicles about
    7 m apart, rendered discs): ``lambda_ij`` median 0.2-0.6% off the true distance from the
    first second the vehicles see each other, 0.2-0.4% once combined with the converged SfM distance
    (SfM alone: 42% off, the prior's, until ~2 s after take-off, then 0.1-0.2%); 0.3 gave
    0.5-1.1% before and 0.13-0.26% after, 0.1 4% in the first second. Lower it for noisier
    ranges (a disc's range from its apparent size errs ~ ``d^2 / (f r)`` x the radius error in
    pixels)."""
    gradloc_yaw_from_bearings: bool = False
    """The layer's known rotation ``R_i = R_z(psihat_i)``: paper 000's filter yaw (``False``) or
    paper 002's yaw-only rotation estimation (``True``: eq. 13-15 on SO(2) over the camera
    layer's relative yaws from reciprocal bearings, :mod:`onboard.distributed.yaw`; one gradient
    round per core step, :mod:`onboard.core.localization002`). Needs ``localization =
    "paper002"`` and reciprocal edges that connect the team (:class:`AgentConfig` refuses it
    otherwise). Headless demo, 3 / 4 vehicles, 40 s: yaws within 0.0006 / 0.007 deg of the truth
    modulo the global yaw, against 1.66 / 2.60 with paper 000's filter yaw (docs/distributed.md).
    """

    def __post_init__(self) -> None:
        if self.localization not in LOCALIZATIONS:
            raise ValueError(
                f"unknown localization {self.localization!r}; choose from "
                f"{', '.join(LOCALIZATIONS)}"
            )
        if not (self.gradloc_range_weight > 0.0 and self.gradloc_range_weight < 1e6):
            raise ValueError(f"gradloc_range_weight must be in (0, 1e6), got "
                             f"{self.gradloc_range_weight}")  # fmt: skip
        if not (0.0 < self.gradloc_measured_range_weight < 1e6):
            raise ValueError(f"gradloc_measured_range_weight must be in (0, 1e6), got "
                             f"{self.gradloc_measured_range_weight}")  # fmt: skip
        if self.gradloc_yaw_from_bearings and self.localization != "paper002":
            raise ValueError("gradloc_yaw_from_bearings needs localization 'paper002'")


class AgentConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Everything one agent core needs: its mode and one group per layer."""

    graph: Graph
    mode: Mode = "active"
    """The layers the core composes (:data:`onboard.core.modes.MODE_LAYERS`)."""
    safety: Safety = Safety()
    scale: ScaleGains = ScaleGains()
    active: ActiveGains = ActiveGains()
    formation: FormationGains = FormationGains()
    rigidity: RigidityGains = RigidityGains()
    gradloc: GradientLocalizationGains = GradientLocalizationGains()

    def __post_init__(self) -> None:
        _check_edges(self.rigidity.rigidity_edges, self.graph.n_agents)
        if self.mode not in MODES:
            raise ValueError(f"unknown mode {self.mode!r}; choose from {', '.join(MODES)}")
        if self.mode in ("formation", "formation-active") and not self.formation.desired_beta_body:
            raise ValueError(f"mode {self.mode!r} needs desired_beta_body")
        if self.gradloc.localization == "paper002" and self.mode == "rigidity-tracking":
            raise ValueError(
                "localization 'paper002' needs the scale layer (not rigidity-tracking)"
            )
        if self.gradloc.gradloc_yaw_from_bearings:
            comps = reciprocal_components(self.graph.edges, self.graph.n_agents)
            if len(comps) > 1:
                raise ValueError(yaw_components_message(comps))


def yaw_components_message(comps: list[list[int]]) -> str:
    """Why ``gradloc_yaw_from_bearings`` is refused for a graph whose reciprocal pairs leave the
    team in ``comps``."""
    groups = " ".join("{" + ", ".join(map(str, c)) + "}" for c in comps)
    return (
        f"gradloc_yaw_from_bearings needs reciprocal edges that connect the team (relative yaws "
        f"come from reciprocal pairs only); they split it into {groups}"
    )


def _check_edges(edges: tuple[tuple[int, int], ...], n: int) -> None:
    for i, j in edges:
        if not (0 <= i < n and 0 <= j < n) or i == j:
            raise ValueError(f"bad edge ({i}, {j}) for {n} agents")


GROUPS: dict[str, type[msgspec.Struct]] = {
    "graph": Graph,
    "safety": Safety,
    "scale": ScaleGains,
    "active": ActiveGains,
    "formation": FormationGains,
    "rigidity": RigidityGains,
    "gradloc": GradientLocalizationGains,
}
"""The groups of :class:`AgentConfig`, by attribute name."""
FIELD_GROUP: dict[str, str] = {
    name: group for group, cls in GROUPS.items() for name in cls.__struct_fields__
}
"""Flat field name -> the :class:`AgentConfig` attribute of the group holding it."""


def field_types() -> dict[str, Any]:
    """Flat field name -> its type (every group's fields, and ``mode``)."""
    out: dict[str, Any] = {"mode": Mode}
    for cls in GROUPS.values():
        out.update(typing.get_type_hints(cls))
    return out


def _split(fields: dict[str, Any]) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
    top: dict[str, Any] = {}
    groups: dict[str, dict[str, Any]] = {}
    for name, value in fields.items():
        if name == "mode":
            top[name] = value
        elif name in FIELD_GROUP:
            groups.setdefault(FIELD_GROUP[name], {})[name] = value
        else:
            raise TypeError(f"unknown agent config field {name!r}")
    return top, groups


def build_config(**fields: Any) -> AgentConfig:
    """An :class:`AgentConfig` from flat fields (``agent_id=..., edges=..., k_formation=...``):
    each goes to the group that holds it; :class:`TypeError` for a name no group has."""
    top, groups = _split(fields)
    made = {g: GROUPS[g](**kw) for g, kw in groups.items()}
    return AgentConfig(**top, **made)


def replace_fields(config: AgentConfig, **fields: Any) -> AgentConfig:
    """``config`` with flat fields replaced (:func:`build_config`'s names)."""
    top, groups = _split(fields)
    made = {g: msgspec.structs.replace(getattr(config, g), **kw) for g, kw in groups.items()}
    return msgspec.structs.replace(config, **top, **made)
