"""What enters and leaves one agent core besides peer messages: its own measurements, the
setpoint it commands, and the status it reports to the ground station.

Frames: body is FRD, velocities in m/s, angles in rad, times in s (``docs/design.md``).
"""

from __future__ import annotations

from typing import Annotated

import msgspec

from messages.codec import Payload
from messages.limits import AgentId, Name, Seq
from messages.vocabulary import Phase

Vec3 = tuple[float, float, float]


class BearingMeasurement(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """One camera detection: unit bearing to ``target`` in the measuring vehicle's body frame,
    captured at ``stamp_s``."""

    target: int
    beta_body: Vec3
    stamp_s: float


class RangeMeasurement(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A measured distance to another vehicle (e.g. a UWB radio): fixes the scale of
    angle-based localization (paper 003 eq. 10)."""

    target: int
    range_m: float
    stamp_s: float


class TargetMeasurement(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A mission target as the tracking algorithm reports it: body-frame unit bearing and
    distance (paper 003 sec. 5.1 assumes both are provided)."""

    target: int
    beta_body: Vec3
    range_m: float
    stamp_s: float


class OwnMeasurements(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Everything the vehicle itself measures at ``t_s``: odometry yaw (own arbitrary reference),
    body-frame velocity, yaw rate, and the bearings of its latest camera frame; optionally
    ranges to other vehicles and mission targets."""

    t_s: float
    yaw_rad: float
    v_body: Vec3
    yaw_rate_rad_s: float
    bearings: tuple[BearingMeasurement, ...] = ()
    ranges: tuple[RangeMeasurement, ...] = ()
    targets: tuple[TargetMeasurement, ...] = ()
    odometry_stamp_s: float | None = None
    """When the autopilot measured ``yaw_rad``, ``v_body`` and ``yaw_rate_rad_s`` (same clock as
    ``t_s``; ``None``: at ``t_s``). An autopilot streams them at 20-50 Hz and they reach the core
    tens of milliseconds later; the SfM observers pair them with camera frames by time."""
    position_ned: Vec3 | None = None
    """Odometry position from the autopilot's local origin (its estimator's frame, never
    shared): only a leader flying waypoints (:class:`messages.command.LeaderDrive`) uses it."""


class Setpoint(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Body-frame velocity and yaw-rate command (saturated by the core)."""

    v_body: Vec3
    yaw_rate_rad_s: float


class AgentStatus(Payload, tag="agent.status"):
    """Per-agent health and estimates for the ground station monitor."""

    mode: str
    p_hat_ned: Vec3
    yaw_hat_rad: float
    chi_hat_inv_m: dict[int, float]
    """Inverse distance estimate per reciprocal neighbour (own or received)."""
    e_index: float
    """Network convergence index ``E`` (eq. 10) as estimated by consensus."""
    lambda_bar: float
    """Network observability index ``lambdabar`` (eq. 11) as estimated by consensus."""
    neighbours: list[int]
    """Neighbours heard from in the last second."""
    rigidity_eigenvalue: float | None = None
    """Weighted angle-rigidity eigenvalue (paper 003), when the agent estimates it."""
    rigidity_eigenvalue_uncertainty: float | None = None
    """How far the true eigenvalue may be from the estimate (its lag behind a fast-changing
    framework, ``onboard.core.rigidity.lag_uncertainty``); ``rigidity_uncertain`` alarms above
    10% of the estimate."""
    scale_converged: bool = False
    """Every SfM observer this agent knows has ``E`` below the convergence threshold."""
    range_terms: Annotated[int, msgspec.Meta(ge=0)] = 0
    """Measured-range terms (paper 002 eq. 22: the camera's disc ranges) paper 002's
    localization has used so far, one per out-edge and step (0 without that layer)."""
    formation_ramp: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)] = 1.0
    """How far the switch to the newest desired formation has come (0 at the change, 1 done;
    :meth:`onboard.core.motion.Formation.adopt`)."""
    distance_terms: Annotated[int, msgspec.Meta(ge=0)] = 0
    """Edges whose distance term (paper 002 eq. 23, ``f_D``) the last formation command had (0:
    bearings only: the formation has no distances, or no distance estimate yet)."""
    leader_drive: Name = ""
    """What this leader flies (``velocity``, ``velocity done``, ``waypoint 2/5``, ``waypoints
    done``); empty when it is no driven leader."""


class VehicleStatus(Payload, tag="vehicle.status"):
    """What an onboard daemon publishes for the ground station (``bf/<fleet>/<id>/status``):
    its agent core's status plus the autopilot link and the daemon's own health."""

    agent: AgentStatus
    autopilot_mode: str
    armed: bool
    in_air: bool
    altitude_m: float
    speed_m_s: float
    battery_pct: float | None
    heartbeat_age_s: float
    """Age of the autopilot's last HEARTBEAT as the daemon sees it."""
    phase: Phase
    """Daemon phase (:class:`messages.vocabulary.Phase`: connecting, waiting, ready, flying,
    holding, pilot, failsafe, landing, stopped); its value is the wire string."""
    alarms: list[str] = msgspec.field(default_factory=list)
    """Active alarms (:class:`messages.vocabulary.Alarm`), e.g. ``peer_lost:3``,
    ``peer_clock:3``, ``rigidity_lost``, ``estimate_diverging``, ``autopilot_lost``,
    ``failsafe``, ``pilot_takeover``, ``altitude_floor``."""
    dropped: dict[str, int] = msgspec.field(default_factory=dict)
    """Counters of dropped input by reason (malformed, version, nonfinite, unknown_sender, ...)."""
    formation_id: Seq = 0
    """The desired formation the agent flies: 0 the fleet file's, else the ``formation_id`` of
    the last :class:`messages.command.FormationChange` it adopted (the ground station's ack)."""
    formation_leader: AgentId | None = None
    """The vehicle that holds its position in that formation (``None``: no leader)."""
    formation_name: Name = ""
    """That formation's name (the fleet file's formation: empty)."""
    formation_distances: bool = False
    """Whether that formation holds its distances too (paper 002 eq. 23; a scale change)."""
    leader_drive_id: Seq = 0
    """The ``drive_id`` of the last :class:`messages.command.LeaderDrive` this leader took (0:
    none; the ground station's ack)."""
