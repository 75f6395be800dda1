"""The rigidity layer's eigen payload: what one agent packs, a neighbour reads back unchanged
(through the codec too), and a payload of the wrong layout is refused."""

from __future__ import annotations

import numpy as np

from messages.agent import BearingMeasurement, OwnMeasurements
from messages.codec import decode, encode
from messages.rigidity import AngleLocalizationShare, RigidityEigenShare
from onboard.agent import AgentConfig
from onboard.geometry import bearings_body
from onboard.graph import complete_graph
from onboard.rigidity_layer import RigidityLayer

N = 4
P = np.array([[0.0, 0.0, -5.0], [3.0, 1.0, -5.5], [2.5, -2.0, -6.0], [4.0, 0.5, -4.0]])
_C = P.mean(axis=0)
YAW = np.arctan2(_C[1] - P[:, 1], _C[0] - P[:, 0])  # cameras toward the barycenter


def _layers() -> list[RigidityLayer]:
    edges = tuple((int(i), int(j)) for i, j in complete_graph(N))
    prior = tuple(tuple(float(x) for x in row) for row in P)
    out = []
    for i in range(N):
        cfg = AgentConfig(
            agent_id=i, n_agents=N, edges=edges, mode="rigidity-tracking", p_hat0_ned=prior
        )
        others = [j for j in range(N) if j != i]
        out.append(RigidityLayer(cfg, others, others))
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
                assert layer.receive(msg.sender, msg)
            out: list = []
            layer.step(t, 0.01, _own(i, t), float(YAW[i]), (0.0, 0.0, 0.0), {}, r, out)
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
    m = share.targets.index(0)
    assert mv.shape == (3, wire.k)
    np.testing.assert_allclose(mv[:, 0], share.mv[m])
    np.testing.assert_allclose(form, share.form_grad_ned[m])
    assert s_part > 0.0
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


def test_wrong_layout_is_malformed() -> None:
    layers = _layers()
    inbox = _exchange(layers, 2)
    share = next(m for m in inbox[0] if isinstance(m, RigidityEigenShare))
    short = RigidityEigenShare(
        sender=share.sender, seq=share.seq, stamp_s=share.stamp_s, v=share.v, x=share.x[:-1],
        z=share.z, lambda_hat=share.lambda_hat, targets=share.targets, mv=share.mv,
        form_grad_ned=share.form_grad_ned,
    )  # fmt: skip
    assert not layers[0].receive(share.sender, short)
    loc = next(m for m in inbox[0] if isinstance(m, AngleLocalizationShare))
    assert layers[0].receive(loc.sender, loc)
