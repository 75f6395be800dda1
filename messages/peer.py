"""Peer payloads: what one agent core sends its neighbours (paper 000, Sect. III-IV).

Every payload is a flat, small :class:`messages.codec.Payload`; the header's ``stamp_s`` is the
sender's clock when the content was valid (for :class:`BearingShare`: the camera capture time).
Vectors are plain tuples of floats in the frame their name states. A receiver keeps the latest
payload of each kind from each neighbour, so a lost message only makes data one period older.

Per 2 ms step an agent publishes :class:`MotionShare`, :class:`LocalizationState`,
:class:`ConsensusState`, :class:`ExcitationTable` and, if it runs reciprocal edges,
:class:`SfmEstimate`; :class:`BearingShare` goes out at the camera rate (50 Hz). On the wire, a
publish tick's newest payload of each kind travels in one :class:`messages.envelope.PeerEnvelope`
(issue 27); a receiver unpacks it into these payloads, each checked on its own.
"""

from __future__ import annotations

from typing import Annotated

import msgspec

from messages.codec import Payload
from messages.limits import (
    LIST_MAX,
    AgentId,
    Angle,
    Bearing3,
    Dimensionless,
    InvDistance,
    Name,
    PositionVec3,
    Rate,
    SpeedVec3,
    Stamp,
)
from messages.rigidity import AngleLocalizationShare, RigidityEigenShare

Vec3 = tuple[float, float, float]
# bounded lists of bounded values (messages.limits): a huge finite number is out_of_range
_Values = Annotated[list[Dimensionless], msgspec.Meta(max_length=LIST_MAX)]


class Entry(msgspec.Struct, frozen=True, array_like=True, forbid_unknown_fields=True):
    """One entry of a payload's list (encoded as a short array; decoding checks its arity and
    every field's bounds, so a receiver never meets a half entry)."""


class TargetBearing(Entry):
    """One bearing of a camera frame: body-frame unit vector toward agent ``target``."""

    target: AgentId
    beta_body: Bearing3


class SfmEdgeEstimate(Entry):
    """The inverse-depth observer (eq. 8) of reciprocal edge ``(sender, peer)``: ``chihat``,
    ``lambda_ij = u_ij^T P_ij u_ij``, ``E_ij`` of eq. 10 (window average of ``|xi|^2``) and
    ``int sqrt(alpha lambda_ij) dt`` (how far the observer has converged)."""

    peer: AgentId
    chi_hat_inv_m: InvDistance
    excitation: Dimensionless
    e_index: Dimensionless
    e_folds: Dimensionless


class EdgeExcitation(Entry):
    """The freshest excitation ``lambda_k`` of reciprocal edge ``k = (first, second)``, measured
    at ``stamp_s``."""

    first: AgentId
    second: AgentId
    excitation: Dimensionless
    stamp_s: Stamp


class ConsensusEntry(Entry):
    """The state ``(x, z)`` of one PI average-consensus estimator: ``x`` estimates the network
    average of the local inputs of quantity ``name``, ``z`` is its integral state (empty for
    plain neighbour averaging, e.g. of ``w_l``)."""

    name: Name
    x: _Values
    z: _Values


class ScaledBearing(Entry):
    """Paper 002's ``lambda_ij u_ij`` of the sender's out-edge ``(sender, target)``: its scale
    ``lambda_ij`` times its world bearing ``u_ij = R_z(psi_i) beta_ij`` in the shared estimated
    frame (m)."""

    target: AgentId
    w_ned: PositionVec3


_TargetBearings = Annotated[list[TargetBearing], msgspec.Meta(max_length=LIST_MAX)]
_SfmEdges = Annotated[list[SfmEdgeEstimate], msgspec.Meta(max_length=LIST_MAX)]
_EdgeExcitations = Annotated[list[EdgeExcitation], msgspec.Meta(max_length=LIST_MAX)]
_ConsensusEntries = Annotated[list[ConsensusEntry], msgspec.Meta(max_length=LIST_MAX)]
_ScaledBearings = Annotated[list[ScaledBearing], msgspec.Meta(max_length=LIST_MAX)]


class MotionShare(Payload, tag="peer.motion"):
    """The sender's own measured motion, needed by a neighbour to form ``u_ij = iR_j u_j - u_i``
    (eq. 7). ``yaw_rad`` is the sender's yaw in its *own* arbitrary reference (an odometry
    angle; agents share no common frame): receivers only use its changes over time."""

    v_body: SpeedVec3
    yaw_rate_rad_s: Rate
    yaw_rad: Angle


class BearingShare(Payload, tag="peer.bearings"):
    """The sender's body-frame bearings captured at ``stamp_s`` (one camera frame), with its own
    odometry yaw at that instant. Used for relative yaw on reciprocal edges (paper 002 fig. 6)
    and for the in-edge terms of the localization filter (eq. 6) and of the formation law."""

    yaw_rad: Angle
    bearings: _TargetBearings


class SfmEstimate(Payload, tag="peer.sfm"):
    """Results of the inverse-depth observers (eq. 8) the sender runs, one entry per reciprocal
    edge ``(sender, peer)`` (the lower id runs the edge and shares it with the other end)."""

    edges: _SfmEdges


class ExcitationTable(Payload, tag="peer.excitation"):
    """The freshest excitation the sender knows for each reciprocal edge; receivers keep the
    newest value per edge and relay it, so every agent knows every ``lambda_k`` within a few
    hops and computes ``lambdabar`` (eq. 11) exactly."""

    entries: _EdgeExcitations


class LocalizationState(Payload, tag="peer.localization"):
    """The sender's estimate ``(phat_i, psihat_i)`` in the team's shared estimated frame (eq. 6)."""

    p_hat_ned: PositionVec3
    yaw_hat_rad: Angle


class GradientLocalizationShare(Payload, tag="peer.gradloc"):
    """Paper 002's distributed localization state of the sender (eq. 16-17 and 22,
    :mod:`onboard.core.localization002`): its translation ``T_i`` and velocity in the shared
    estimated frame (receivers carry ``T_i`` to their own time with it), and ``lambda_ij u_ij``
    per out-edge: what a neighbour needs for the gradient of the edges it shares with it.
    ``yaw_hat_rad`` is the sender's yaw-only rotation estimate ``psihat_i`` (paper 002 eq. 13-15
    on SO(2), ``gradloc_yaw_from_bearings``; ``None`` when it flies on paper 000's filter yaw)
    and ``yaw_rate_rad_s`` its odometry yaw rate (receivers carry ``psihat_i`` with it)."""

    t_ned: PositionVec3
    v_ned: SpeedVec3
    edges: _ScaledBearings
    yaw_hat_rad: Angle | None = None
    yaw_rate_rad_s: Rate = 0.0


class ConsensusState(Payload, tag="peer.consensus"):
    """States of the sender's PI average-consensus estimators, one entry per named quantity
    (Freeman, Yang, Lynch 2006; ACE blocks of paper 000 fig. 1)."""

    states: _ConsensusEntries


PeerPayload = (
    MotionShare
    | BearingShare
    | SfmEstimate
    | ExcitationTable
    | LocalizationState
    | ConsensusState
    | GradientLocalizationShare
    | AngleLocalizationShare
    | RigidityEigenShare
)
"""Everything an agent core accepts in its inbox (decode with ``codec.decode(data, PeerPayload)``)."""
