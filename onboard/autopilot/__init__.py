"""The autopilot link: MAVLink to a PX4 or ArduPilot flight controller (see :mod:`.base`)."""

from __future__ import annotations

from onboard.autopilot.base import (
    ActionResult,
    AutopilotLink,
    Flavour,
    LinkConfig,
    LinkCounters,
    LinkError,
    LinkEvent,
    StreamState,
    Telemetry,
)

__all__ = [
    "ActionResult",
    "AutopilotLink",
    "Flavour",
    "LinkConfig",
    "LinkCounters",
    "LinkError",
    "LinkEvent",
    "StreamState",
    "Telemetry",
    "open_link",
]


def open_link(backend: str = "pymavlink", config: LinkConfig | None = None) -> AutopilotLink:
    """A not-yet-connected link of the given backend (``pymavlink`` or ``mavsdk``)."""
    if backend == "pymavlink":
        from onboard.autopilot.pymavlink_link import PymavlinkLink

        return PymavlinkLink(config)
    if backend == "mavsdk":
        from messages.optional import require
        from onboard.autopilot.mavsdk_link import MavsdkLink

        require("mavsdk")  # the extra bearingflock[mavsdk]: a one-line error before connecting

        return MavsdkLink(config)
    raise ValueError(f"unknown autopilot backend {backend!r} (pymavlink or mavsdk)")
