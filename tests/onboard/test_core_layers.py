"""The agent core's pieces: the peer table (sender check, stamps, latest per kind, freshness),
the grouped configuration (flat names routed to their group, same defaults), and a mode as a
composition of layers (the table, what each composition publishes and takes)."""

from __future__ import annotations

import math

import msgspec
import pytest

from messages.agent import OwnMeasurements
from messages.peer import (
    BearingShare,
    ConsensusState,
    GradientLocalizationShare,
    LocalizationState,
    MotionShare,
)
from messages.rigidity import AngleLocalizationShare, RigidityEigenShare
from onboard.core.agent import OUTBOX_ORDER, AgentCore
from onboard.core.bearings import Bearings
from onboard.core.config import (
    FIELD_GROUP,
    MODES,
    AgentConfig,
    Graph,
    RigidityGains,
    build_config,
    field_types,
    replace_fields,
)
from onboard.core.modes import MODE_LAYERS, LayerKind, layer_kinds
from onboard.core.motion import Active, Formation, FormationActive, Hold, Random
from onboard.core.peers import Drops, PeerTable, Route
from onboard.core.rigidity import RigidityLayer
from onboard.core.scale import Scale

TRIANGLE = ((0, 1), (1, 0), (1, 2), (2, 1), (0, 2), (2, 0))
DESIRED = tuple((i, j, (1.0, 0.0, 0.0)) for i, j in TRIANGLE)


def _loc(sender: int, stamp_s: float, x: float = 0.0) -> LocalizationState:
    return LocalizationState(sender=sender, stamp_s=stamp_s, p_hat_ned=(x, 0.0, 0.0),
                             yaw_hat_rad=0.0)  # fmt: skip


def _table(take=lambda j, m: True) -> PeerTable:
    peers = PeerTable(frozenset({1, 2}), 0.5, Drops())
    peers.route(LocalizationState, Route(frozenset({1, 2}), take))
    peers.route(MotionShare, Route(frozenset({1})))  # known, taken by no layer
    return peers


# ------------------------------------------------------------------ peer table
def test_peer_table_keeps_the_latest_payload_of_each_sender_and_ages_it() -> None:
    peers = _table()
    peers.receive(_loc(1, 0.0, x=1.0), 0.0)
    peers.receive(_loc(2, 0.1, x=2.0), 0.1)
    peers.receive(_loc(1, 0.2, x=3.0), 0.2)
    assert peers.latest(LocalizationState, 1).p_hat_ned[0] == 3.0  # type: ignore[union-attr]
    assert list(peers.all(LocalizationState)) == [1, 2]  # first-heard order
    assert peers.latest_fresh(LocalizationState, 2, 0.6) is not None  # 0.5 s old: still fresh
    assert peers.latest_fresh(LocalizationState, 2, 0.61) is None
    assert [j for j, _ in peers.fresh(LocalizationState, 0.65)] == [1]
    assert peers.heard == {1: 0.2, 2: 0.1} and peers.heard_within(1.15, 1.0) == [1]
    assert peers.drops == {}
    peers.clear()
    assert peers.all(LocalizationState) == {} and peers.heard == {}


def test_peer_table_checks_sender_kind_and_stamp_before_the_layer_sees_it() -> None:
    seen: list[int] = []
    peers = _table(take=lambda j, m: seen.append(j) or m.p_hat_ned[0] >= 0.0)
    peers.receive(_loc(0, 0.0), 0.0)  # itself: not a neighbour
    peers.receive(_loc(7, 0.0), 0.0)  # a stranger
    peers.receive(_loc(1, 5.0), 0.0)  # from the future
    peers.receive(MotionShare(sender=2, v_body=(0.0, 0.0, 0.0), yaw_rate_rad_s=0.0, yaw_rad=0.0),
                  0.0)  # fmt: skip
    peers.receive(MotionShare(sender=1, v_body=(0.0, 0.0, 0.0), yaw_rate_rad_s=0.0, yaw_rad=0.0),
                  0.0)  # fmt: skip
    peers.receive(ConsensusState(sender=1, states=[]), 0.0)  # no route at all
    peers.receive(_loc(2, 0.0, x=-1.0), 0.0)  # the layer finds it malformed
    assert peers.drops == {
        "not_neighbour": 3,  # 0, 7 and MotionShare from 2 (route senders: {1})
        "future_stamp": 1,
        "unknown_type": 2,  # MotionShare (no layer), ConsensusState (no route)
        "malformed": 1,
    }
    assert seen == [2] and peers.all(LocalizationState) == {}
    assert peers.heard == {1: 0.0, 2: 0.0}  # past the checks, even if no layer kept it
    with pytest.raises(ValueError, match="already has a route"):
        peers.route(MotionShare, Route(frozenset()))


# ---------------------------------------------------------------------- config
def test_flat_fields_go_to_their_group_with_the_same_defaults() -> None:
    cfg = build_config(agent_id=1, n_agents=3, edges=TRIANGLE, k_formation=0.7, lambda_safe=0.3,
                       peer_timeout_s=0.4, seed=5, mode="hold")  # fmt: skip
    assert cfg.graph == Graph(agent_id=1, n_agents=3, edges=TRIANGLE, seed=5)
    assert cfg.formation.k_formation == 0.7 and cfg.rigidity.lambda_safe == 0.3
    assert cfg.safety.peer_timeout_s == 0.4 and cfg.mode == "hold"
    assert cfg.scale.alpha == 10.0 and cfg.active.nu_star == 0.25 and cfg.safety.v_max_m_s == 3.0
    assert cfg.rigidity == msgspec.structs.replace(RigidityGains(), lambda_safe=0.3)
    again = replace_fields(cfg, agent_id=2, k_yaw=2.0)
    assert again.graph.agent_id == 2 and again.formation.k_yaw == 2.0
    assert again.formation.k_formation == 0.7 and cfg.graph.agent_id == 1  # frozen original
    with pytest.raises(TypeError, match="no_such_gain"):
        build_config(agent_id=0, n_agents=3, edges=TRIANGLE, no_such_gain=1.0)
    assert set(field_types()) == {*FIELD_GROUP, "mode"}
    with pytest.raises(ValueError, match="bad edge"):
        build_config(agent_id=0, n_agents=3, edges=TRIANGLE, rigidity_edges=((0, 3),))
    with pytest.raises(msgspec.ValidationError):  # a group is a typed struct
        msgspec.convert({"graph": {"agent_id": 0, "n_agents": 1, "edges": []}, "scale": {"alpha": "x"}},
                        AgentConfig)  # fmt: skip


PAPER_DEFAULTS = {
    "seed": 0, "alpha": 10.0, "h_other": 10.0, "h_floor": 0.001, "e_window_s": 1.0,
    "sfm_bias_speed_m_s": 0.1, "sfm_folds_forget_s": 0.0, "sfm_wander_window_s": 2.0,
    "sfm_wander_max": 0.02, "chi_min_inv_m": 0.02, "k_loc_bearing": 100.0, "k_loc_distance": 1.0,
    "consensus_gamma": 50.0, "consensus_k_p": 1.0, "consensus_k_i": 1.0, "k_w_l_coupling": 2.0,
    "w_l_max_rad_s": 0.3, "w_l_start_rad_s": 0.0, "excitation_relay_every": 5, "p_norm": -5.0, "k_nu": 10.0,
    "nu_star": 0.25, "k_lambda": 15.0, "k_w": 1.0, "gamma": 0.05, "k_lambda0": 2.0,
    "e_low": 0.0001, "e_high": 0.001, "converged_e_folds": 5.0, "k_formation": 0.5, "k_yaw": 1.0,
    "random_tau_s": 1.0, "v_max_m_s": 3.0, "yaw_rate_max_rad_s": 1.5, "peer_timeout_s": 0.5,
    "rigidity_maintenance": False, "rigidity_eigen": "distributed",
    "rigidity_scale_from_sfm": False, "fov_deg": 120.0, "range_m": 15.0, "lambda_min": 0.02,
    "lambda_safe": 0.2, "k_rigidity": 0.05, "r_coll_m": 0.6, "r_safe_m": 1.5, "k_collision": 1.0,
    "track_target": -1, "r_track_m": 2.0, "k_track_range": 0.15, "k_track_camera": 0.4,
    "k_angle_loc": 4.0, "k_distance_loc": 1.0, "k_vertical_loc": 4.0,
    "rigidity_softmin_tau": 0.01, "eigen_columns": 3, "eigen_step": 1.5, "eigen_k_t": 0.3,
    "eigen_k_n": 0.2, "rigidity_period_s": 0.0, "rigidity_warmup_s": 0.0,
}  # fmt: skip
"""The flat configuration's defaults before it was split into groups (issue 21)."""
ADDED_DEFAULTS = {"localization": "paper000", "gradloc_range_weight": 1.0,
                  "gradloc_measured_range_weight": 1.0, "gradloc_yaw_from_bearings": False,
                  "sfm_bias_gain": 0.0, "sfm_bias_max_m_s": 0.1, "sfm_team_scale": False,
                  "change_ramp_s": 3.0, "distance_weight": 0.25,
                  "distance_delta_m": 2.0}  # fmt: skip
"""Fields added since, each off by default (issue 25: paper 002's localization and its yaw-only
rotation estimate from reciprocal bearings, and the in-flight formation switch and distance
term, which act only on a formation change; issue 22: the SfM relative-velocity-bias
estimate)."""


def test_the_groups_keep_every_name_and_default_of_the_flat_config() -> None:
    cfg = build_config(agent_id=0, n_agents=1, edges=())
    got = {name: getattr(getattr(cfg, group), name) for name, group in FIELD_GROUP.items()}
    structural = {"agent_id", "n_agents", "edges", "p_hat0_ned", "yaw_hat0_rad",
                  "desired_beta_body", "desired_yaw_rad", "rigidity_edges"}  # fmt: skip
    assert set(got) == set(PAPER_DEFAULTS) | set(ADDED_DEFAULTS) | structural
    assert {k: got[k] for k in PAPER_DEFAULTS} == PAPER_DEFAULTS
    assert {k: got[k] for k in ADDED_DEFAULTS} == ADDED_DEFAULTS
    assert cfg.mode == "active"


# ----------------------------------------------------------------------- modes
def _core(mode: str, **kw: object) -> AgentCore:
    return AgentCore(build_config(agent_id=0, n_agents=3, edges=TRIANGLE, mode=mode,
                                  desired_beta_body=DESIRED, **kw))  # fmt: skip


def test_every_mode_is_a_composition_of_layers() -> None:
    assert set(MODE_LAYERS) == set(MODES)
    expected = {
        "hold": (Bearings, Scale, Hold),
        "random": (Bearings, Scale, Random),
        "active": (Bearings, Scale, Active),
        "formation": (Bearings, Scale, Formation),
        "formation-active": (Bearings, Scale, FormationActive),
        "rigidity-tracking": (Bearings, RigidityLayer),
    }
    for mode, types in expected.items():
        core = _core(mode)
        assert tuple(type(layer) for layer in core.layers) == types, mode
        on = _core(mode, rigidity_maintenance=True)
        assert tuple(type(layer) for layer in on.layers)[-1] is RigidityLayer
        assert len(on.layers) == len(types) + (mode != "rigidity-tracking")
    cfg = build_config(agent_id=0, n_agents=3, edges=TRIANGLE, rigidity_maintenance=True)
    assert layer_kinds(cfg)[-1] is LayerKind.RIGIDITY
    fa = _core("formation-active")
    assert fa.scale is not None and fa.scale.rotation_terms
    assert not _core("formation").scale.rotation_terms  # type: ignore[union-attr]


def test_a_composition_takes_and_publishes_only_its_layers_kinds() -> None:
    own = OwnMeasurements(t_s=0.0, yaw_rad=0.0, v_body=(0.0, 0.0, 0.0), yaw_rate_rad_s=0.0)
    for mode in MODES:
        core = _core(mode)
        taken = {kind for kind, route in core.peers.routes.items() if route.take is not None}
        rigid = {AngleLocalizationShare, RigidityEigenShare}
        if mode == "rigidity-tracking":
            assert taken == {BearingShare, *rigid} and core.scale is None
            assert core.chi_hat(1) is None and core.lambda_bar == 0.0 and core.w_l == 0.0
            assert not core.scale_converged()
        else:
            assert taken == set(OUTBOX_ORDER) - rigid - {GradientLocalizationShare}
            assert core.rigidity is None
            p002 = _core(mode, localization="paper002")  # paper 002's localization on top
            p002_taken = {k for k, r in p002.peers.routes.items() if r.take is not None}
            assert p002_taken == taken | {GradientLocalizationShare}
            p002_out = [type(m) for m in p002.step(0.0, own)[1]]
            assert p002_out[-2:] == [LocalizationState, GradientLocalizationShare]
        assert set(core.peers.routes) == set(OUTBOX_ORDER)  # the rest: counted unknown_type
        _, out = core.step(0.0, own)
        kinds = [type(m) for m in out]
        assert kinds == sorted(kinds, key=OUTBOX_ORDER.index)
        if mode == "rigidity-tracking":
            assert set(kinds) <= {BearingShare, *rigid}
        else:
            assert kinds[-3:] == [ConsensusState, MotionShare, LocalizationState]
            states = next(m for m in out if isinstance(m, ConsensusState)).states
            names = [e.name for e in states]
            assert ("w_l" in names) == (mode == "formation-active")


def test_layer_contributions_add_up_then_saturate() -> None:
    """Hold plus the rigidity layer: the hold's zero plus the rigidity action (zero during the
    warm-up), saturated to v_max."""
    core = _core("hold", rigidity_maintenance=True, rigidity_warmup_s=10.0)
    own = OwnMeasurements(t_s=0.0, yaw_rad=0.0, v_body=(0.0, 0.0, 0.0), yaw_rate_rad_s=0.0)
    sp, _ = core.step(0.0, own)
    assert sp.v_body == (0.0, 0.0, 0.0) and sp.yaw_rate_rad_s == 0.0
    fast = _core("random", v_max_m_s=0.01, yaw_rate_max_rad_s=0.0, nu_star=50.0)
    sp, _ = fast.step(0.0, own)
    sp, _ = fast.step(0.1, msgspec.structs.replace(own, t_s=0.1))
    assert math.isclose(math.hypot(*sp.v_body), 0.01) and sp.yaw_rate_rad_s == 0.0
