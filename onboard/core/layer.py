"""The protocol every layer of the agent core follows, and what the core hands it each step.

A layer (:mod:`onboard.core.bearings`, :mod:`onboard.core.scale`, :mod:`onboard.core.motion`,
:mod:`onboard.core.rigidity`) owns its state. Per core step, in the order of its mode's
composition (:data:`onboard.core.modes.MODE_LAYERS`), it

1. takes the peer payloads of the kinds it declares (:attr:`Layer.routes`: who may send each
   kind and the layer's handler; :class:`onboard.core.peers.PeerTable` checks the sender and
   the stamp, the handler the contents);
2. steps with the vehicle's own measurements (:class:`Own`) and returns its velocity /
   yaw-rate contribution (:class:`Command`, or ``None`` for an estimator), appending the
   payloads it publishes;
3. after every layer stepped, :meth:`Layer.finish` publishes what depends on the whole step
   (paper 000's states, which include the controller's ``w_l``);
4. reports its part of :class:`messages.agent.AgentStatus` (:meth:`Layer.status`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NamedTuple, Protocol

import msgspec

from messages.agent import OwnMeasurements
from messages.codec import Payload
from onboard.core.peers import Route

Vec3 = tuple[float, float, float]


class Own(msgspec.Struct, frozen=True):
    """One step's own measurements, checked finite and converted to plain floats."""

    t_s: float
    dt_s: float
    """Time since the previous core step (0 on the first and after the clock went back)."""
    seq: int
    """The core's step counter (every payload of a step carries it)."""
    v_body: Vec3
    yaw_rate_rad_s: float
    yaw_rad: float
    odometry_stamp_s: float
    """When the odometry was measured (``t_s`` if unknown or implausible)."""
    raw: OwnMeasurements
    """The measurements as received (camera frame, ranges, mission targets)."""


class Command(NamedTuple):
    """A layer's contribution to the setpoint, body frame."""

    v_body: Vec3
    yaw_rate_rad_s: float


class Layer(Protocol):
    """One job of the agent core (module docstring)."""

    routes: Mapping[type, Route]
    """Peer payload kinds this layer takes: who may send each, and its handler
    (``take(sender, msg) -> bool``, False if malformed: counted, not kept)."""

    def step(self, own: Own, outbox: list[Payload]) -> Command | None:
        """Advance to ``own.t_s``; the contribution to the setpoint (``None``: none)."""
        ...

    def finish(self, own: Own, outbox: list[Payload]) -> None:
        """Publish what depends on the whole step (after every layer stepped)."""
        ...

    def forget_time(self) -> None:
        """The clock went back: drop everything kept "newest by stamp" (estimates stay)."""
        ...

    def status(self) -> dict[str, Any]:
        """This layer's fields of :class:`messages.agent.AgentStatus`."""
        ...
