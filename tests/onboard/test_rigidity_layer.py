"""The rigidity layer's eigen payload: what one agent packs, a neighbour reads back unchanged
(through the codec too), and a payload of the wrong layout is refused."""

from __future__ import annotations

import msgspec
import numpy as np
import pytest

from messages.agent import BearingMeasurement, OwnMeasurements
from messages.codec import decode, encode
from messages.rigidity import AngleLocalizationShare, RigidityEigenShare
from onboard.core.config import AgentConfig, build_config
from onboard.core.peers import Drops, PeerTable
from onboard.core.rigidity import ROUND_TIMEOUT_S, RigidityLayer
from onboard.daemon.replay import SeqWindow
from onboard.geometry import bearings_body
from onboard.graph import complete_graph

N = 4
P = np.array([[0.0, 0.0, -5.0], [3.0, 1.0, -5.5], [2.5, -2.0, -6.0], [4.0, 0.5, -4.0]])
_C = P.mean(axis=0)
YAW = np.arctan2(_C[1] - P[:, 1], _C[0] - P[:, 0])  # cameras toward the barycenter


def _layer(cfg: AgentConfig) -> RigidityLayer:
    """Agent ``cfg``'s rigidity layer on a peer table of its own."""
    me = cfg.graph.agent_id
    peers = PeerTable(frozenset(range(N)) - {me}, cfg.safety.peer_timeout_s, Drops())
    layer = RigidityLayer(cfg.graph, cfg.rigidity, peers)
    for kind, route in layer.routes.items():
        peers.route(kind, route)
    return layer


def _give(layer: RigidityLayer, msg: object) -> bool:
    """Deliver ``msg`` through the layer's peer table; whether it was kept."""
    peers = layer.peers
    before = sum(peers.drops.values())
    peers.receive(msg, msg.stamp_s)  # type: ignore[arg-type, attr-defined]
    return sum(peers.drops.values()) == before


def _layers(**overrides: object) -> list[RigidityLayer]:
    edges = tuple((int(i), int(j)) for i, j in complete_graph(N))
    prior = tuple(tuple(float(x) for x in row) for row in P)
    out = []
    for i in range(N):
        cfg = build_config(
            agent_id=i,
            n_agents=N,
            edges=edges,
            mode="rigidity-tracking",
            p_hat0_ned=prior,
            **overrides,  # type: ignore[arg-type]
        )
        out.append(_layer(cfg))
    return out


def _own(i: int, t_s: float) -> OwnMeasurements:
    edges = complete_graph(N)
    beta, _ = bearings_body(P, YAW, edges)
    rows = [e for e in range(len(edges)) if edges[e, 0] == i]
    return OwnMeasurements(
        t_s=t_s,
        yaw_rad=float(YAW[i]),
        v_body=(0.0, 0.0, 0.0),
        yaw_rate_rad_s=0.0,
        bearings=tuple(
            BearingMeasurement(int(edges[e, 1]), tuple(float(x) for x in beta[e]), t_s)
            for e in rows
        ),
    )


def _exchange(layers: list[RigidityLayer], rounds: int) -> list[list]:
    inbox: list[list] = [[] for _ in layers]
    for r in range(rounds):
        t = 0.01 * r
        outs = []
        for i, layer in enumerate(layers):
            for msg in inbox[i]:
                assert _give(layer, msg)
            out: list = []
            layer.advance(t, 0.01, _own(i, t), float(YAW[i]), (0.0, 0.0, 0.0), {}, r, out)
            outs.append(out)
        inbox = [[m for j, out in enumerate(outs) if j != i for m in out] for i in range(N)]
    return inbox


def test_eigen_payload_round_trips_through_the_wire_and_the_codec() -> None:
    layers = _layers()
    inbox = _exchange(layers, 3)
    sender = layers[1]
    share = next(m for m in inbox[0] if isinstance(m, RigidityEigenShare) and m.sender == 1)
    share = decode(encode(share), RigidityEigenShare)  # the packed layout is a valid payload
    wire = layers[0].wire
    nb, v = wire.unpack([share])
    np.testing.assert_allclose(v[0], sender.eigen.v)  # all k columns of V_1
    x, z = sender.eigen.share()
    np.testing.assert_allclose(nb.x[0], x)
    np.testing.assert_allclose(nb.z[0], z)
    assert nb.degree[0] == sender.eigen.degree == N - 1
    assert nb.s_bar[0] == sender.eigen.s_bar > 0.0
    mv, s_part, form = wire.addressed_to([share], 0)
    assert mv.shape == (3, wire.k) and form.shape == (3,)
    assert s_part > 0.0 and np.abs(mv).max() > 0.0
    # a share not addressed to this agent contributes nothing
    assert wire.addressed_to([share], 99)[1] == 0.0


def test_per_target_blocks_reach_their_target_and_sum() -> None:
    """Known blocks packed for targets (2, 0) by two senders come out summed at agent 0."""
    wire = _layers()[0].wire
    k, rng = wire.k, np.random.default_rng(5)
    x, z = rng.standard_normal(wire.n_c), rng.standard_normal(wire.n_c)
    mv, s_parts, form = rng.standard_normal((2, 2, 3, k)), rng.random((2, 2)), rng.random((2, 2, 3))
    shares = []
    for n in range(2):
        state, per = wire.pack(
            x, z, rng.standard_normal((3, k)), 3, 0.5, mv[n], s_parts[n], form[n]
        )
        share = RigidityEigenShare(
            sender=n + 1, lambda_hat=0.1, targets=[2, 0], state=state, per_target=per
        )
        shares.append(decode(encode(share), RigidityEigenShare))
    got_mv, got_s, got_form = wire.addressed_to(shares, 0)
    np.testing.assert_allclose(got_mv, mv[:, 1].sum(axis=0))
    assert got_s == pytest.approx(s_parts[:, 1].sum())
    np.testing.assert_allclose(got_form, form[:, 1].sum(axis=0))
    # a share not addressed to this agent contributes nothing
    assert wire.addressed_to([share], 99)[1] == 0.0


def test_distributed_estimate_on_a_hovering_team_matches_the_centralized_value() -> None:
    from onboard.rigidity.angle import weighted_angle_rigidity_eigenvalue

    layers = _layers()
    _exchange(layers, 150)
    lam = weighted_angle_rigidity_eigenvalue(P, YAW, complete_graph(N), layers[0].model)[0]
    assert lam > 0.02
    for layer in layers:
        assert abs(layer.lambda_hat - lam) < 0.02 * lam
        assert np.all(np.isfinite(layer.grad_lambda_p))


@pytest.mark.parametrize("eigen", ["distributed", "centralized"])
def test_gradient_is_the_smooth_minimum_gradient(eigen: str) -> None:
    """Each agent's blended gradient (distributed: its own form terms plus what its neighbours
    sent) is its part of ``sum_m pi_m grad lambda_m`` over the tracked modes."""
    from onboard.control.rigidity import softmin_weights
    from onboard.rigidity.angle import weighted_eigenvalues_gradients

    model = _layers()[0].model
    lams, gp, _ = weighted_eigenvalues_gradients(P, YAW, complete_graph(N), model, 3)
    tau = float(lams[1] - lams[0])  # a real blend: the second mode weighs e^-1 of the first
    layers = _layers(rigidity_softmin_tau=tau, rigidity_eigen=eigen)
    _exchange(layers, 300)
    pi = softmin_weights(lams, tau)
    assert pi[1] > 0.2
    blended = np.einsum("m,mnd->nd", pi, gp)
    scale = np.abs(blended).max()
    assert np.abs(blended - gp[0]).max() > 0.1 * scale  # not the smallest mode alone
    for i, layer in enumerate(layers):
        np.testing.assert_allclose(layer.grad_lambda_p, blended[i], atol=0.02 * scale)


def test_wrong_layout_is_malformed() -> None:
    layers = _layers()
    inbox = _exchange(layers, 2)
    share = next(m for m in inbox[0] if isinstance(m, RigidityEigenShare))
    short = msgspec.structs.replace(share, state=share.state[:-1])
    assert not _give(layers[0], short)
    short = msgspec.structs.replace(share, targets=share.targets[:-1])
    assert not _give(layers[0], short)
    loc = next(m for m in inbox[0] if isinstance(m, AngleLocalizationShare))
    assert _give(layers[0], loc)


def _exchange_late(layers: list[RigidityLayer], ticks: int, lag: int) -> None:
    """Every payload arrives ``lag`` ticks after it was sent (a 10 ms tick)."""
    pending: dict[int, list[list]] = {}
    for k in range(ticks):
        t = 0.01 * k
        inbox = pending.pop(k, [[] for _ in layers])
        for i, layer in enumerate(layers):
            for msg in inbox[i]:
                assert _give(layer, msg)
            out: list = []
            layer.advance(t, 0.01, _own(i, t), float(YAW[i]), (0.0, 0.0, 0.0), {}, k, out)
            box = pending.setdefault(k + lag, [[] for _ in layers])
            for r in range(N):
                if r != i:
                    box[r].extend(out)


def test_late_messages_slow_the_rounds_but_not_the_estimate() -> None:
    """Messages 4 ticks late: every round waits for the neighbours' previous one, so the
    estimate converges to the same value (stepped at every tick on 4-round-old states it blew
    up, the delayed-consensus limit ``k mu_max d < pi / 2``)."""
    from onboard.rigidity.angle import weighted_angle_rigidity_eigenvalue

    layers = _layers()
    _exchange_late(layers, 1000, lag=4)
    lam = weighted_angle_rigidity_eigenvalue(P, YAW, complete_graph(N), layers[0].model)[0]
    for layer in layers:
        # one round per message trip (plus one per tick before the first messages arrive)
        assert 240 <= layer.rounds <= 1000 // 4 + 4 + 1
        assert abs(layer.lambda_hat - lam) < 0.02 * lam
        assert layer.agreed


def test_a_round_waits_for_every_candidate_then_times_out() -> None:
    layers = _layers()
    inbox = _exchange(layers, 3)  # everyone has taken 3 rounds
    a = layers[0]
    assert a.rounds == 3
    for msg in inbox[0]:
        _give(a, msg)
    out: list = []
    a.advance(0.03, 0.01, _own(0, 0.03), float(YAW[0]), (0.0, 0.0, 0.0), {}, 3, out)
    assert a.rounds == 4  # the neighbours' round 3 was there
    first = [m for m in out if isinstance(m, RigidityEigenShare)]
    out = []
    a.advance(0.04, 0.01, _own(0, 0.04), float(YAW[0]), (0.0, 0.0, 0.0), {}, 4, out)
    assert a.rounds == 4  # waiting: it sends round 4 again (a lost copy costs one step)
    again = [m for m in out if isinstance(m, RigidityEigenShare)]
    assert [m.round for m in again] == [4]
    # the copy is numbered by this step, so a receiver that has the first one takes it as
    # new instead of counting it as a replay (it was ~1,000 ``seq_replay`` per demo)
    window = SeqWindow()
    assert window.admit(0, RigidityEigenShare, first[0].seq, first[0].stamp_s, 0.04) is None
    assert window.admit(0, RigidityEigenShare, again[0].seq, again[0].stamp_s, 0.04) is None
    assert np.array_equal(again[0].state, first[0].state)
    assert again[0].stamp_s == first[0].stamp_s
    t = 0.03 + ROUND_TIMEOUT_S + 0.01  # nobody answered: go on with what it has
    a.advance(t, 0.01, _own(0, t), float(YAW[0]), (0.0, 0.0, 0.0), {}, 5, out)
    assert a.rounds == 5 and any(isinstance(m, RigidityEigenShare) for m in out)


def test_a_restarted_agent_joins_at_its_neighbours_round() -> None:
    layers = _layers()
    inbox = _exchange(layers, 20)
    fresh = _layers()[0]  # agent 0 restarted
    for msg in inbox[0]:
        _give(fresh, msg)
    fresh.advance(0.2, 0.01, _own(0, 0.2), float(YAW[0]), (0.0, 0.0, 0.0), {}, 0, [])
    assert fresh.rounds == 21


def test_maintenance_does_not_act_on_an_estimate_its_neighbours_disagree_with() -> None:
    """One agent's estimate at 0 while the others' are not: the barrier would command
    thousands of m/s; the layer waits for agreement instead."""
    edges = tuple((int(i), int(j)) for i, j in complete_graph(N))
    prior = tuple(tuple(float(x) for x in row) for row in P)
    layers = []
    for i in range(N):
        cfg = build_config(
            agent_id=i, n_agents=N, edges=edges, mode="active", p_hat0_ned=prior,
            rigidity_maintenance=True, lambda_safe=1.0, lambda_min=0.1,
        )  # fmt: skip
        layers.append(_layer(cfg))
    inbox = _exchange(layers, 150)
    a = layers[0]
    assert a.agreed and np.linalg.norm(a.u_rigidity) > 0.0  # below "safe": it acts
    lam = a.lambda_hat
    for msg in inbox[0]:
        if isinstance(msg, RigidityEigenShare) and msg.sender == 1:  # neighbour 1 collapsed
            msg = msgspec.structs.replace(msg, lambda_hat=0.0, stamp_s=1.5, round=a.rounds)
        _give(a, msg)
    a.advance(1.5, 0.01, _own(0, 1.5), float(YAW[0]), (0.0, 0.0, 0.0), {}, 150, [])
    assert a.lambda_hat > 0.5 * lam and not a.agreed
    assert np.linalg.norm(a.u_rigidity) == 0.0  # collision avoidance: nobody within r_safe


def test_a_restarted_estimator_sends_nothing_until_it_has_a_state() -> None:
    """The divergence guard restarts the iteration and drops its consensus state; the share of
    that round used to carry an empty state, which every neighbour counted as malformed."""
    layers = _layers()
    inbox = _exchange(layers, 5)
    a = layers[0]
    for msg in inbox[0]:
        assert _give(a, msg)
    a.eigen.v = np.full_like(a.eigen.v, 1e30)  # diverged
    out: list = []
    a.advance(0.05, 0.01, _own(0, 0.05), float(YAW[0]), (0.0, 0.0, 0.0), {}, 5, out)
    assert a.eigen.restarts == 1
    assert not any(isinstance(m, RigidityEigenShare) for m in out)
    out = []
    t = 0.05 + 0.31  # nobody has its round: it times out, then shares a whole state again
    a.advance(t, 0.01, _own(0, t), float(YAW[0]), (0.0, 0.0, 0.0), {}, 6, out)
    shares = [m for m in out if isinstance(m, RigidityEigenShare)]
    assert len(shares) == 1 and a.wire.fits(shares[0])
    assert _give(layers[1], shares[0])
