"""Peer payloads of angle-based localization and distributed rigidity maintenance (paper 003).

An agent that runs the rigidity layer publishes both payloads every step to its
communication neighbours. Vectors are in the team's *estimated* frame (the frame angle
localization builds; NED-like, no agent knows its relation to the true NED). Per-neighbour
entries are meant for one target agent and carry the sender's contribution to that agent's
sums (each angle ``(i, j, k)`` is evaluated by the agent ``i`` that measures it, which sends
the blocks of ``j`` and ``k`` to them).
"""

from __future__ import annotations

from typing import Annotated

import msgspec

from messages.codec import F64Array, Payload
from messages.limits import LIST_MAX, AgentId, Angle, Dimensionless, IdList, PositionVec3

Vec3 = tuple[float, float, float]


class GradientBlock(msgspec.Struct, frozen=True, array_like=True, forbid_unknown_fields=True):
    """The sender's angles' part of ``dJ/dphat`` for agent ``target`` (estimated frame)."""

    target: AgentId
    grad_ned: PositionVec3


_GradientBlocks = Annotated[list[GradientBlock], msgspec.Meta(max_length=LIST_MAX)]


class AngleLocalizationShare(Payload, tag="peer.angle_localization"):
    """Angle localization state (paper 003 eq. 10-11): the sender's estimate ``phat``, the yaw
    of its body frame in the estimated frame (``yaw_known`` false until it has seen someone),
    and one gradient block per agent it sees."""

    p_hat_ned: PositionVec3
    yaw_hat_rad: Angle
    yaw_known: bool
    blocks: _GradientBlocks


class RigidityEigenShare(Payload, tag="peer.rigidity_eigen"):
    """One round of the distributed subspace iteration (``onboard.estimation.distributed_eigen``,
    ``k`` vectors per agent): the sender's eigenvalue estimate, the round it has taken
    (receivers wait for their neighbours' previous round) and two float64 vectors, laid out by
    ``onboard.core.rigidity.EigenWire``:

    * ``state``: ``[x (n_c) | z (n_c) | V_i (3 k, row-major) | degree | sbar]``: the PI-consensus
      state of the averaged quantities, the sender's block of the ``k`` vectors, how many
      neighbours it heard and its max-consensus state;
    * ``per_target``: for each ``targets[m]``, ``[M_w V block (3 k) | weighted-degree part |
      form-gradient block (3)]``: the sender's angles' contributions to that agent's sums
      (``d(y^T M_w y)/dp`` for the blended Ritz vectors, in the estimated frame).

    A share whose lengths do not match the receiver's ``k`` is malformed."""

    lambda_hat: Dimensionless
    targets: IdList
    state: F64Array
    per_target: F64Array
    round: int = 0


RigidityPayload = AngleLocalizationShare | RigidityEigenShare
RIGIDITY_KINDS = ("angle_localization", "rigidity_eigen")
"""Their kinds (the tags without ``peer.``: :func:`messages.envelope.kind_of`), which a daemon
keeps from the envelopes of agents outside its formation graph (``PeerLink(listen_kinds=...)``)."""
