"""Paper 002's distributed gradient localization layer (onboard/core/localization002.py) with
fakes for the camera and scale layers: it converges to the true shape and metric scale from
exact bearings and one range, exchanging only its payload; bad shares are counted and
dropped; a non-finite estimate never leaves it; the fleet file and the core select it."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from messages.agent import OwnMeasurements
from messages.codec import MessageError, decode, encode
from messages.peer import GradientLocalizationShare, PeerPayload, ScaledBearing
from messages.vocabulary import DropReason
from onboard.core.agent import AgentCore
from onboard.core.config import AgentConfig, GradientLocalizationGains, Graph
from onboard.core.layer import Own
from onboard.core.localization002 import GradientLocalization
from onboard.core.modes import LayerKind, layer_kinds
from onboard.core.peers import Drops, PeerTable
from onboard.geometry import bearings_body

# four agents, a directed graph with one reciprocal pair (0, 1): its SfM distance is the range
EDGES = ((0, 1), (1, 0), (0, 2), (1, 2), (2, 3), (3, 0), (1, 3))
P_TRUE = np.array([[0.0, 0.0, -5.0], [4.0, 0.5, -5.5], [2.0, 3.5, -4.0], [-1.5, 2.5, -6.0]])
YAW_TRUE = np.array([0.3, -1.2, 2.0, 0.8])
DT_S = 0.01
STEPS = 1500


def _fake_scale(i: int, yaw: float, ranges: dict[int, float], converged: bool = False):
    """What the layer reads from paper 000's scale layer: the filter's yaw (the known rotation),
    the SfM inverse distances of the reciprocal edges and whether they have converged."""
    return SimpleNamespace(
        scale_converged=lambda: converged,
        localization=SimpleNamespace(yaw_hat_rad=yaw),
        reciprocal=sorted(ranges),
        chi_hat=lambda j: 1.0 / ranges[j] if j in ranges else None,
        gains=SimpleNamespace(chi_min_inv_m=0.02),
    )


def _fake_bearings(i: int, edges, p, yaw):
    beta, _ = bearings_body(p, yaw, np.array(edges))
    out = {j: (0.0, tuple(b)) for (a, j), b in zip(edges, beta.tolist(), strict=True) if a == i}
    return SimpleNamespace(
        out_targets=sorted(j for a, j in edges if a == i),
        in_sources=sorted(a for a, j in edges if j == i),
        beta_out=out,
        range_out={},
    )


def _team(p_prior: np.ndarray, ranges: dict[tuple[int, int], float], edges=EDGES,
          sfm_converged: bool = False, measured_weight: float = 1.0):  # fmt: skip
    n = len(P_TRUE)
    layers, tables = [], []
    for i in range(n):
        graph = Graph(agent_id=i, n_agents=n, edges=edges,
                      p_hat0_ned=tuple(map(tuple, p_prior.tolist())))  # fmt: skip
        nbrs = frozenset({j for e in edges if i in e for j in e} - {i})
        peers = PeerTable(nbrs, 0.5, Drops())
        mine = {b: d for (a, b), d in ranges.items() if a == i}
        mine.update({a: d for (a, b), d in ranges.items() if b == i})
        layer = GradientLocalization(
            graph, GradientLocalizationGains(localization="paper002",
                                             gradloc_measured_range_weight=measured_weight),
            peers, _fake_bearings(i, edges, P_TRUE, YAW_TRUE),  # type: ignore[arg-type]
            _fake_scale(i, float(YAW_TRUE[i]), mine, sfm_converged),  # type: ignore[arg-type]
            peers.drops,
        )  # fmt: skip
        for kind, route in layer.routes.items():
            peers.route(kind, route)
        layers.append(layer)
        tables.append(peers)
    return layers, tables


def _own(k: int, dt: float = DT_S) -> Own:
    t = k * DT_S
    raw = OwnMeasurements(t_s=t, yaw_rad=0.0, v_body=(0.0, 0.0, 0.0), yaw_rate_rad_s=0.0)
    return Own(t_s=t, dt_s=dt if k else 0.0, seq=k, v_body=(0.0, 0.0, 0.0), yaw_rate_rad_s=0.0,
               yaw_rad=0.0, odometry_stamp_s=t, raw=raw)  # fmt: skip


def _fly(layers, tables, steps: int, new_ranges: bool = True) -> None:
    """Synchronous steps; every share reaches its neighbours at the next step (through the
    codec, as between daemons); a new camera frame every step (its ranges too unless not
    ``new_ranges``)."""
    inbox: list = []
    for k in range(steps):
        own = _own(k)
        for peers in tables:
            peers.t_s = own.t_s
            for m in inbox:
                if m.sender in peers.neighbours:
                    peers.receive(m, own.t_s)
        inbox = []
        for layer in layers:  # a camera frame every step
            b = layer.bearings.beta_out
            b.update({j: (own.t_s, beta) for j, (_, beta) in b.items()})
            r = layer.bearings.range_out  # and its ranges, if it measures any
            if new_ranges:
                r.update({j: (own.t_s, d) for j, (_, d) in r.items()})
            out: list = []
            layer.step(own, out)
            inbox += [decode(encode(m), PeerPayload) for m in out]


def _size_error(est: np.ndarray, true: np.ndarray) -> float:
    a, b = est - est.mean(axis=0), true - true.mean(axis=0)
    return float(np.sqrt(np.sum(a * a) / np.sum(b * b)) - 1.0)


def test_converges_to_the_true_shape_and_scale_from_bearings_and_one_range() -> None:
    rng = np.random.default_rng(0)
    c = P_TRUE.mean(axis=0)
    prior = c + 0.6 * (P_TRUE - c) + rng.normal(0.0, 0.5, P_TRUE.shape)  # demo-like prior
    d01 = float(np.linalg.norm(P_TRUE[1] - P_TRUE[0]))
    layers, tables = _team(prior, {(0, 1): d01})
    t_hat = np.array([layer.p_hat_ned for layer in layers])
    start = np.linalg.norm((t_hat - t_hat.mean(0)) - (P_TRUE - c), axis=1).max()
    _fly(layers, tables, STEPS)
    t_hat = np.array([layer.p_hat_ned for layer in layers])
    # the frame is the known rotations' (here NED): only a translation is free
    err = np.linalg.norm((t_hat - t_hat.mean(0)) - (P_TRUE - c), axis=1).max()
    assert start > 1.0 and err < 1e-3, (start, err)
    assert abs(_size_error(t_hat, P_TRUE)) < 1e-4
    for i, layer in enumerate(layers):  # every scale is the edge's length
        for j, lam in layer.lam.items():
            assert lam == pytest.approx(np.linalg.norm(P_TRUE[j] - P_TRUE[i]), abs=1e-3)
    assert all(not peers.drops for peers in tables)
    assert all(layer.rounds == STEPS - 1 for layer in layers)


def test_without_the_range_only_the_scale_is_left_free() -> None:
    # same team, no range anywhere: eq. 17's lambda >= 1 holds and the shape is still found
    edges = tuple(e for e in EDGES if e != (1, 0))  # no reciprocal pair: no SfM range at all
    c = P_TRUE.mean(axis=0)
    layers, tables = _team(c + 0.6 * (P_TRUE - c) + 0.3, {}, edges)
    assert all(layer.lambda_min == 1.0 for layer in layers)
    _fly(layers, tables, STEPS)
    t_hat = np.array([layer.p_hat_ned for layer in layers])
    a = t_hat - t_hat.mean(0)
    s = float(np.sum(a * (P_TRUE - c)) / np.sum(a * a))
    assert np.linalg.norm(s * a - (P_TRUE - c), axis=1).max() < 0.05 * np.linalg.norm(P_TRUE - c)
    assert min(lam for layer in layers for lam in layer.lam.values()) >= 1.0


def _one(i: int = 2):
    layers, tables = _team(P_TRUE.copy(), {(0, 1): 4.0})
    return layers[i], tables[i]


def _share(sender: int, **kw) -> GradientLocalizationShare:
    fields = {"t_ned": (0.0, 0.0, -5.0), "v_ned": (0.0, 0.0, 0.0), "edges": [], **kw}
    return GradientLocalizationShare(sender=sender, stamp_s=0.0, **fields)


def test_bad_shares_are_counted_and_dropped() -> None:
    layer, peers = _one(2)  # agent 2: in-edges from 0 and 1, out-edge to 3
    peers.t_s = 0.0
    before = layer._w_in.copy()
    for bad in (
        _share(0, t_ned=(math.nan, 0.0, 0.0)),
        _share(1, v_ned=(0.0, math.inf, 0.0)),
        _share(0, t_ned=(1e300, 0.0, 0.0)),  # finite, but no place on Earth
        _share(1, edges=[ScaledBearing(2, (math.nan, 0.0, 0.0))]),
    ):
        peers.receive(bad, 0.0)
    assert peers.drops == {DropReason.MALFORMED: 4}
    assert peers.latest(GradientLocalizationShare, 0) is None and layer._w_in == before
    # an entry about an edge this agent does not have: counted, the rest of the share kept
    peers.receive(_share(3, edges=[ScaledBearing(2, (1.0, 0.0, 0.0))]), 0.0)
    assert peers.drops[DropReason.UNKNOWN_EDGE] == 1 and 3 not in layer._w_in
    assert peers.latest(GradientLocalizationShare, 3) is not None
    peers.receive(_share(0, edges=[ScaledBearing(2, (1.0, 2.0, 0.5))]), 0.0)
    assert layer._w_in[0] == (1.0, 2.0, 0.5)
    # on the wire the codec's bounds stop them first (messages.limits)
    with pytest.raises(MessageError) as info:
        decode(encode(_share(0, t_ned=(1e300, 0.0, 0.0))), PeerPayload)
    assert info.value.reason == DropReason.OUT_OF_RANGE


def test_a_non_finite_estimate_never_leaves_the_layer() -> None:
    layer, peers = _one(2)
    t0 = layer.p_hat_ned
    out: list = []
    own = _own(1, dt=1e308)  # a step that would throw T_i to infinity
    fields = {f: getattr(own, f) for f in own.__struct_fields__}
    layer.step(Own(**{**fields, "v_body": (50.0, 0.0, 0.0)}), out)
    assert peers.drops == {DropReason.NONFINITE: 1}
    assert layer.p_hat_ned == t0 and all(math.isfinite(x) for x in layer.lam.values())
    (share,) = out
    assert decode(encode(share), PeerPayload) == share  # what goes out is always valid
    assert all(math.isfinite(x) for x in layer.status()["p_hat_ned"])
    # an own velocity no share may carry (the core checks only finiteness) is not flown on
    out = []
    layer.step(Own(**{**fields, "dt_s": 0.01, "v_body": (1e3, 0.0, 0.0)}), out)
    assert peers.drops[DropReason.NONFINITE_OWN] == 1 and out[0].v_ned == (0.0, 0.0, 0.0)
    assert decode(encode(out[0]), PeerPayload) == out[0]


# --------------------------------------------------------------- selection in the core
TRIANGLE = ((0, 1), (1, 0), (1, 2), (2, 1), (0, 2), (2, 0))


def _config(localization: str, mode: str = "formation-active") -> AgentConfig:
    from onboard.core.config import FormationGains

    desired = tuple((i, j, (1.0, 0.0, 0.0)) for i, j in TRIANGLE)
    return AgentConfig(
        graph=Graph(agent_id=0, n_agents=3, edges=TRIANGLE,
                    p_hat0_ned=((0, 0, -5), (4, 0, -5), (0, 4, -5))),
        mode=mode,  # type: ignore[arg-type]
        formation=FormationGains(desired_beta_body=desired),
        gradloc=GradientLocalizationGains(localization=localization),  # type: ignore[arg-type]
    )  # fmt: skip


def test_the_core_flies_on_it_when_selected() -> None:
    assert LayerKind.GRADIENT_LOCALIZATION not in layer_kinds(_config("paper000"))
    kinds = layer_kinds(_config("paper002"))
    assert kinds.index(LayerKind.GRADIENT_LOCALIZATION) == kinds.index(LayerKind.SCALE_ROTATION) + 1
    plain = AgentCore(_config("paper000"))
    assert plain.gradient_localization is None and plain.pose is plain.localization
    core = AgentCore(_config("paper002"))
    layer = core.gradient_localization
    assert layer is not None and core.pose is layer and core.scale.pose is layer  # type: ignore[union-attr]
    own = OwnMeasurements(t_s=0.0, yaw_rad=0.0, v_body=(0.5, 0.0, 0.0), yaw_rate_rad_s=0.0)
    core.step(0.0, own)
    _, out = core.step(0.1, msgspec_replace(own, t_s=0.1))
    shares = [m for m in out if isinstance(m, GradientLocalizationShare)]
    assert len(shares) == 1 and shares[0].t_ned == layer.p_hat_ned
    assert core.status().p_hat_ned == layer.p_hat_ned
    assert layer.p_hat_ned[0] == pytest.approx(0.05)  # carried by odometry, yaw 0
    with pytest.raises(ValueError, match="localization"):
        _config("paper003")
    with pytest.raises(ValueError, match="scale layer"):
        _config("paper002", "rigidity-tracking")


def msgspec_replace(own: OwnMeasurements, **kw) -> OwnMeasurements:
    import msgspec

    return msgspec.structs.replace(own, **kw)


def test_the_fleet_file_selects_it_and_refuses_a_bad_value(tmp_path) -> None:
    from groundstation.demo import DemoPorts, plan_formation, write_demo_files
    from onboard.daemon.config import ConfigError, load_fleet
    from onboard.daemon.loop import agent_config

    ports = DemoPorts(zenoh=7447, mavlink=14540, gcs=14550)
    plan = plan_formation(3, seed=0)
    path = write_demo_files(tmp_path, plan, ports, "t", "formation-active")
    assert "[core]" not in path.read_text()  # the default writes nothing new
    assert agent_config(load_fleet(path), 0).gradloc.localization == "paper000"
    path = write_demo_files(tmp_path, plan, ports, "t", "formation-active",
                            localization="paper002")  # fmt: skip
    assert agent_config(load_fleet(path), 1).gradloc.localization == "paper002"
    path.write_text(path.read_text().replace('"paper002"', '"paper003"'))
    with pytest.raises(ConfigError) as info:
        load_fleet(path)
    msg = str(info.value)
    assert "\n" not in msg and "core.localization" in msg and "paper003" in msg, msg


# --------------------------------------------------------------- measured ranges (eq. 22)
NO_SFM = tuple(e for e in EDGES if e != (1, 0))  # no reciprocal pair: no SfM distance anywhere


def _true_range(i: int, j: int) -> float:
    return float(np.linalg.norm(P_TRUE[j] - P_TRUE[i]))


def test_measured_ranges_alone_give_the_true_scale() -> None:
    """No SfM edge at all: the camera's ranges on two out-edges fix the metric scale, and eq.
    17's constraint goes as soon as an agent uses one."""
    c = P_TRUE.mean(axis=0)
    layers, tables = _team(c + 0.6 * (P_TRUE - c) + 0.3, {}, NO_SFM)
    assert all(layer.lambda_min == 1.0 for layer in layers)
    layers[0].bearings.range_out[1] = (0.0, _true_range(0, 1))
    layers[2].bearings.range_out[3] = (0.0, _true_range(2, 3))
    _fly(layers, tables, STEPS)
    t_hat = np.array([layer.p_hat_ned for layer in layers])
    err = np.linalg.norm((t_hat - t_hat.mean(0)) - (P_TRUE - c), axis=1).max()
    assert err < 1e-3 and abs(_size_error(t_hat, P_TRUE)) < 1e-4, err
    for i, layer in enumerate(layers):
        for j, lam in layer.lam.items():
            assert lam == pytest.approx(_true_range(i, j), abs=1e-3)
    assert layers[0].range_terms == layers[2].range_terms == STEPS - 1
    assert layers[0].status()["range_terms"] == STEPS - 1  # AgentStatus.range_terms
    assert layers[1].range_terms == layers[3].range_terms == 0
    assert layers[0].lambda_min is None and layers[1].lambda_min == 1.0
    assert all(not peers.drops for peers in tables)


def test_a_measured_range_replaces_an_unconverged_sfm_distance() -> None:
    """Edge (0, 1) has an SfM distance 20% long, not converged yet, and a measured range that
    is right: the scale follows the measurement."""
    c = P_TRUE.mean(axis=0)
    d01 = _true_range(0, 1)
    layers, tables = _team(c + 0.6 * (P_TRUE - c), {(0, 1): 1.2 * d01})
    layers[0].bearings.range_out[1] = (0.0, d01)
    layers[1].bearings.range_out[0] = (0.0, d01)
    _fly(layers, tables, STEPS)
    t_hat = np.array([layer.p_hat_ned for layer in layers])
    assert abs(_size_error(t_hat, P_TRUE)) < 1e-4
    assert layers[0].lam[1] == pytest.approx(d01, abs=1e-3)


def test_a_stale_range_is_not_used() -> None:
    layers, tables = _team(P_TRUE.copy(), {}, NO_SFM)
    layers[0].bearings.range_out[1] = (-10.0, 1.0)  # measured 10 s ago (peer_timeout 0.5 s)
    before = layers[0].lam[1]
    _fly(layers, tables, 50, new_ranges=False)
    assert layers[0].range_terms == 0 and layers[0].lambda_min == 1.0
    assert layers[0].lam[1] == pytest.approx(before, abs=1e-6)  # prior = truth: nothing moves


def test_bad_ranges_are_counted_in_the_core_and_never_reach_the_state() -> None:
    """Through the real camera layer: NaN, infinite, negative, absurd and NaN-stamped ranges are
    counted (``bad_range``) and dropped; a good one reaches the layer; the estimate stays
    finite."""
    import msgspec

    from messages.agent import RangeMeasurement

    core = AgentCore(_config("paper002"))
    layer = core.gradient_localization
    assert layer is not None
    bad = (
        RangeMeasurement(1, math.nan, 0.05),
        RangeMeasurement(1, math.inf, 0.05),
        RangeMeasurement(2, -3.0, 0.05),
        RangeMeasurement(2, 1e300, 0.05),
        RangeMeasurement(1, 4.0, math.nan),
    )
    own = OwnMeasurements(t_s=0.0, yaw_rad=0.0, v_body=(0.2, 0.0, 0.0), yaw_rate_rad_s=0.0)
    core.step(0.0, own)
    core.step(0.05, msgspec.structs.replace(own, t_s=0.05, ranges=bad))
    core.step(0.06, msgspec.structs.replace(own, t_s=0.06, ranges=bad))  # seen: counted once
    # counted once each, but the NaN stamp (never "seen before") at every step
    assert core.dropped.get("bad_range") == 6, core.dropped
    assert core.bearings.range_out == {}
    good = (RangeMeasurement(1, 4.0, 0.07), RangeMeasurement(3, 4.0, 0.07))  # 3: no such edge
    core.step(0.07, msgspec.structs.replace(own, t_s=0.07, ranges=good))
    assert core.bearings.range_out == {1: (0.07, 4.0)}
    assert all(math.isfinite(x) for x in layer.p_hat_ned)
    assert all(math.isfinite(x) for x in layer.lam.values())
    # and a NaN that got past the camera layer (a core fed directly) is no range term
    core.bearings.range_out[1] = (0.08, math.nan)
    core.step(0.08, msgspec.structs.replace(own, t_s=0.08))
    assert layer.range_terms == 0
    assert all(math.isfinite(x) for x in (*layer.p_hat_ned, *layer.lam.values()))


@pytest.mark.parametrize(("w_measured", "expected"), [(1.0, 1.1), (3.0, 1.05)])
def test_with_a_converged_sfm_distance_both_terms_count_by_their_weights(w_measured, expected):
    """Both on edge (0, 1) in both directions: lambda settles at the weighted mean of the SfM
    distance (1.2 d, weight 1) and the measured range (d, weight ``w_measured``)."""
    c = P_TRUE.mean(axis=0)
    d01 = _true_range(0, 1)
    layers, tables = _team(c + 0.6 * (P_TRUE - c), {(0, 1): 1.2 * d01}, sfm_converged=True,
                           measured_weight=w_measured)  # fmt: skip
    layers[0].bearings.range_out[1] = (0.0, d01)
    layers[1].bearings.range_out[0] = (0.0, d01)
    _fly(layers, tables, STEPS)
    t_hat = np.array([layer.p_hat_ned for layer in layers])
    assert _size_error(t_hat, P_TRUE) == pytest.approx(expected - 1.0, abs=1e-3)
    assert layers[0].lam[1] == pytest.approx(expected * d01, rel=1e-3)


# ------------------------------------------- the yaw-only rotation estimate (eq. 13-15, SO(2))
EDGES_R = ((0, 1), (1, 0), (1, 2), (2, 1), (2, 3), (3, 2), (3, 0), (0, 3), (0, 2))
"""Four reciprocal pairs (a ring) and one more bearing: every agent has a relative yaw."""


def _yaw_team(yaw_prior: np.ndarray, own_yaw: bool):
    """Agents whose paper 000 filter yaw (the fake's) stays at the wrong prior; the camera
    layer's relative yaws (the fake scale's ``rel``) are exact."""
    n = len(P_TRUE)
    d = {e: float(np.linalg.norm(P_TRUE[e[1]] - P_TRUE[e[0]])) for e in EDGES_R}
    layers, tables = [], []
    for i in range(n):
        graph = Graph(agent_id=i, n_agents=n, edges=EDGES_R,
                      p_hat0_ned=tuple(map(tuple, P_TRUE.tolist())),
                      yaw_hat0_rad=tuple(yaw_prior.tolist()))  # fmt: skip
        nbrs = frozenset({j for e in EDGES_R if i in e for j in e} - {i})
        peers = PeerTable(nbrs, 0.5, Drops())
        recip = {j: d[(i, j)] for j in range(n) if (i, j) in d and (j, i) in d}
        scale = _fake_scale(i, float(yaw_prior[i]), recip, converged=True)
        scale.rel = {j: (float(YAW_TRUE[j] - YAW_TRUE[i]), (0.0, 0.0, 0.0)) for j in recip}
        gains = GradientLocalizationGains(
            localization="paper002", gradloc_yaw_from_bearings=own_yaw
        )
        layer = GradientLocalization(graph, gains, peers,
                                     _fake_bearings(i, EDGES_R, P_TRUE, YAW_TRUE),  # type: ignore[arg-type]
                                     scale, peers.drops)  # type: ignore[arg-type]  # fmt: skip
        for kind, route in layer.routes.items():
            peers.route(kind, route)
        layers.append(layer)
        tables.append(peers)
    return layers, tables


def _aligned_errors(layers) -> tuple[float, float]:
    """Largest yaw error (deg) after the best global yaw, and the largest position error (m)
    after that yaw and the best translation (the gauge of the estimated frame)."""
    from onboard.distributed.yaw import yaw_error_deg
    from onboard.geometry import rot_z

    psi = np.array([layer.yaw_hat_rad for layer in layers])
    t = np.array([layer.p_hat_ned for layer in layers])
    d = YAW_TRUE - psi
    g = math.atan2(np.sin(d).sum(), np.cos(d).sum())
    a = (t - t.mean(0)) @ rot_z(g).T
    c = P_TRUE - P_TRUE.mean(0)
    return yaw_error_deg(psi, YAW_TRUE), float(np.linalg.norm(a - c, axis=1).max())


def test_the_yaw_only_estimate_replaces_paper000s_yaw_and_fixes_the_positions() -> None:
    rng = np.random.default_rng(7)
    prior = YAW_TRUE + 0.4 + rng.uniform(-0.6, 0.6, len(YAW_TRUE))  # 34 deg off each, at most
    own, own_tables = _yaw_team(prior, own_yaw=True)
    borrowed, borrowed_tables = _yaw_team(prior, own_yaw=False)
    yaw0, _ = _aligned_errors(own)
    _fly(own, own_tables, 600)
    _fly(borrowed, borrowed_tables, 600)
    yaw_own, pos_own = _aligned_errors(own)
    yaw_borrowed, pos_borrowed = _aligned_errors(borrowed)
    assert yaw0 > 10.0 and yaw_own < 1e-6, (yaw0, yaw_own)
    assert pos_own < 1e-3 < 0.1 < pos_borrowed, (pos_own, pos_borrowed)
    assert yaw_borrowed == pytest.approx(yaw0)  # the fake filter yaw never moves
    assert all(layer.yaw_rounds == 599 for layer in own)
    assert all(not peers.drops for peers in own_tables)
    # the gauge: the yaws' sum is the prior's (synchronous rounds, both ends of each edge)
    s = sum(layer.yaw_hat_rad for layer in own)
    assert abs(math.remainder(s - prior.sum(), math.tau)) < 1e-6


def test_yaw_shares_are_bounded_and_bad_ones_dropped() -> None:
    layers, tables = _yaw_team(YAW_TRUE.copy(), own_yaw=True)
    layer, peers = layers[2], tables[2]
    out: list = []
    layer.step(_own(1), out)
    (share,) = out
    assert share.yaw_hat_rad == pytest.approx(YAW_TRUE[2])
    assert decode(encode(share), PeerPayload) == share
    # without the option nothing new goes out
    plain, _ = _yaw_team(YAW_TRUE.copy(), own_yaw=False)
    out = []
    plain[2].step(_own(1), out)
    assert out[0].yaw_hat_rad is None and plain[2].yaw_hat_rad == pytest.approx(YAW_TRUE[2])
    peers.t_s = 0.0
    for bad in (_share(1, yaw_hat_rad=math.nan), _share(3, yaw_rate_rad_s=math.inf),
                _share(1, yaw_hat_rad=1e300)):  # fmt: skip
        peers.receive(bad, 0.0)
    assert peers.drops == {DropReason.MALFORMED: 3}
    with pytest.raises(MessageError) as info:
        decode(encode(_share(1, yaw_rate_rad_s=1e3)), PeerPayload)
    assert info.value.reason == DropReason.OUT_OF_RANGE
    # a spinning own yaw rate no share may carry is not integrated
    fields = {f: getattr(_own(2), f) for f in _own(2).__struct_fields__}
    before = layer.yaw_hat_rad
    out = []
    layer.step(Own(**{**fields, "yaw_rate_rad_s": 1e3}), out)
    assert out[0].yaw_rate_rad_s == 0.0 and abs(layer.yaw_hat_rad - before) < 0.01


def test_yaw_from_bearings_needs_paper002() -> None:
    with pytest.raises(ValueError, match="paper002"):
        GradientLocalizationGains(gradloc_yaw_from_bearings=True)


def test_the_fleet_file_selects_the_yaw_only_estimate(tmp_path) -> None:
    from groundstation.demo import DemoPorts, plan_formation, write_demo_files
    from onboard.daemon.config import ConfigError, load_fleet
    from onboard.daemon.loop import agent_config

    ports = DemoPorts(zenoh=7447, mavlink=14540, gcs=14550)
    plan = plan_formation(3, seed=0)
    path = write_demo_files(tmp_path, plan, ports, "t", "formation-active",
                            localization="paper002")  # fmt: skip
    assert not agent_config(load_fleet(path), 0).gradloc.gradloc_yaw_from_bearings
    text = path.read_text().replace('localization = "paper002"',
                                    'localization = "paper002"\nyaw_from_bearings = true')  # fmt: skip
    path.write_text(text)
    core = AgentCore(agent_config(load_fleet(path), 1))
    layer = core.gradient_localization
    assert layer is not None and layer.own_yaw and core.pose is layer
    path.write_text(text.replace('"paper002"', '"paper000"'))
    with pytest.raises(ConfigError) as info:
        load_fleet(path)
    msg = str(info.value)
    assert "\n" not in msg and "yaw_from_bearings" in msg, msg


def test_the_yaw_only_estimate_is_refused_when_reciprocal_pairs_split_the_team(tmp_path) -> None:
    """The 6-vehicle demo's graph has reciprocal pairs {0, 1}, {2, 3}, {4, 5} only: relative
    yaws cannot tie the three pairs together (flown anyway, the yaws stayed 4.5 degrees off)."""
    from groundstation.demo import DemoPorts, plan_formation, write_demo_files
    from onboard.core.config import build_config
    from onboard.daemon.config import ConfigError, load_fleet
    from onboard.graph import reciprocal_components

    plan = plan_formation(6, seed=0)
    assert reciprocal_components(plan.edges, 6) == [[0, 1], [2, 3], [4, 5]]
    assert reciprocal_components(EDGES, 4) == [[0, 1], [2], [3]]
    assert reciprocal_components(EDGES_R, 4) == [[0, 1, 2, 3]]
    ports = DemoPorts(zenoh=7447, mavlink=14540, gcs=14550)
    path = write_demo_files(tmp_path, plan, ports, "t", "formation-active",
                            localization="paper002")  # fmt: skip
    path.write_text(path.read_text().replace('localization = "paper002"',
                                             'localization = "paper002"\nyaw_from_bearings = true'))  # fmt: skip
    with pytest.raises(ConfigError) as info:
        load_fleet(path)
    msg = str(info.value)
    assert "\n" not in msg and "{0, 1} {2, 3} {4, 5}" in msg, msg
    with pytest.raises(ValueError, match="connect the team"):
        build_config(agent_id=0, n_agents=4, edges=EDGES, localization="paper002",
                     gradloc_yaw_from_bearings=True)  # fmt: skip
    build_config(agent_id=0, n_agents=4, edges=EDGES_R, localization="paper002",
                 gradloc_yaw_from_bearings=True)  # fmt: skip
