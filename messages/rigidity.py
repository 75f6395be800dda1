"""Peer payloads of angle-based localization and distributed rigidity maintenance (paper 003).

An agent that runs the rigidity layer publishes both payloads every step to its
communication neighbours. Vectors are in the team's *estimated* frame (the frame angle
localization builds; NED-like, no agent knows its relation to the true NED). Per-neighbour
lists are parallel to ``targets``: entry ``m`` is meant for agent ``targets[m]`` and carries
the sender's contribution to that agent's sums (each angle ``(i, j, k)`` is evaluated by the
agent ``i`` that measures it, which sends the blocks of ``j`` and ``k`` to them).
"""

from __future__ import annotations

from messages.codec import Payload

Vec3 = tuple[float, float, float]


class AngleLocalizationShare(Payload, tag="peer.angle_localization"):
    """Angle localization state (paper 003 eq. 10-11): the sender's estimate ``phat``, the yaw
    of its body frame in the estimated frame (``yaw_known`` false until it has seen someone),
    and ``grad_ned[m]``, its angles' part of ``dJ/dphat`` for agent ``targets[m]``."""

    p_hat_ned: Vec3
    yaw_hat_rad: float
    yaw_known: bool
    targets: list[int]
    grad_ned: list[Vec3]


class RigidityEigenShare(Payload, tag="peer.rigidity_eigen"):
    """Distributed power iteration (``onboard.estimation.distributed_eigen``): the sender's
    eigenvector block ``v``, its PI-consensus state ``(x, z)`` of the averaged quantities, its
    eigenvalue estimate, and per target its angles' blocks of ``M_w v`` (``mv``) and of
    ``d(v^T M_w v)/dp`` (``form_grad_ned``); ``round``: how many rounds the sender has taken
    (receivers wait for their neighbours' previous round)."""

    v: Vec3
    x: list[float]
    z: list[float]
    lambda_hat: float
    targets: list[int]
    mv: list[Vec3]
    form_grad_ned: list[Vec3]
    round: int = 0


RigidityPayload = AngleLocalizationShare | RigidityEigenShare
RIGIDITY_KINDS = ("angle_localization", "rigidity_eigen")
"""Their key kinds (``bf/<fleet>/<id>/peer/<kind>``, the tags without ``peer.``)."""
