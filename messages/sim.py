"""Payloads the simulator publishes (and the one it listens to in lockstep).

* :class:`CameraBearings` — what vehicle ``sender``'s virtual camera sees: unit bearings in its
  body frame (FRD, camera axis = body x) to the vehicles inside its field of view and range.
  Agents use it exactly like a real camera pipeline's output.
* :class:`Truth` — the simulator's ground truth for one vehicle. For the recorder and the
  evaluation only; estimators must never subscribe to it (docs/design.md, "No truth leaks").
* :class:`SimClock` — the simulation time, published by the simulator (``use_sim_time``).
* :class:`SimStep` — in lockstep mode, "advance simulation time up to ``until_s``".

Keys: ``bf/<fleet>/<id>/camera/bearings``, ``bf/<fleet>/<id>/truth`` (messages.keys), and
:func:`clock_key` / :func:`step_key` for the fleet-wide clock topics.
"""

from __future__ import annotations

from typing import Annotated

import msgspec

from messages.codec import Payload
from messages.keys import PREFIX, key
from messages.limits import (
    LIST_MAX,
    Angle,
    Bearing3,
    IdList,
    PositionVec3,
    Rate,
    Seq,
    Speedup,
    SpeedVec3,
    Stamp,
)

CAMERA_TOPIC = "camera/bearings"
TRUTH_TOPIC = "truth"
SIM_SENDER = 0
"""The ``sender`` of the simulator's fleet-wide payloads (:class:`SimClock`)."""


class CameraBearings(Payload, tag="camera_bearings"):
    """Body-frame unit bearings from ``sender`` to each vehicle in ``targets`` (same order)."""

    targets: IdList
    beta_body: Annotated[list[Bearing3], msgspec.Meta(max_length=LIST_MAX)]


class Truth(Payload, tag="truth"):
    """Ground truth of vehicle ``sender``: NED position (m), velocity (m/s), yaw (rad), yaw rate."""

    p_ned: PositionVec3
    v_ned: SpeedVec3
    yaw_rad: Angle
    yaw_rate_rad_s: Rate


class SimClock(Payload, tag="sim_clock"):
    """Simulation time ``t_s`` after ``step`` world steps; ``lockstep`` says who drives it."""

    t_s: Stamp
    step: Seq
    speedup: Speedup
    lockstep: bool


class SimStep(Payload, tag="sim_step"):
    """Lockstep driver to simulator: run until simulation time ``until_s``."""

    until_s: Stamp


def camera_key(fleet: str, agent_id: int) -> str:
    return key(fleet, agent_id, CAMERA_TOPIC)


def truth_key(fleet: str, agent_id: int) -> str:
    return key(fleet, agent_id, TRUTH_TOPIC)


def clock_key(fleet: str) -> str:
    """``bf/<fleet>/sim/clock``: where the simulator publishes :class:`SimClock`."""
    key(fleet, 0, "clock")  # validates the fleet name
    return f"{PREFIX}/{fleet}/sim/clock"


def step_key(fleet: str) -> str:
    """``bf/<fleet>/sim/step``: where a lockstep driver publishes :class:`SimStep`."""
    key(fleet, 0, "step")
    return f"{PREFIX}/{fleet}/sim/step"
