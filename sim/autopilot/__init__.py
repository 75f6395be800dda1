"""Simulated autopilots: one MAVLink 2 endpoint per vehicle, in PX4 or ArduPilot flavour.

``common`` holds the shared flight logic and telemetry, ``px4`` and ``ardupilot`` the flavour
rules, ``params`` the parameter tables, ``signing`` MAVLink 2 signing, ``link`` the sockets.
"""

from __future__ import annotations

from sim.autopilot.ardupilot import ArduPilotAutopilot
from sim.autopilot.common import Autopilot, AutopilotOptions, Home, Phase
from sim.autopilot.link import Codec, LinkCounters, TcpLink, UdpLink
from sim.autopilot.params import ardupilot_params, px4_params
from sim.autopilot.px4 import Px4Autopilot
from sim.world import World

FLAVOURS = ("px4", "ardupilot")


def make_autopilot(
    flavour: str, index: int, world: World, options: AutopilotOptions, counters: LinkCounters
) -> Autopilot:
    """Autopilot of vehicle ``index`` (system id ``index + 1``) in the given flavour."""
    if flavour == "px4":
        return Px4Autopilot(index, world, px4_params(index + 1), options, counters)
    if flavour == "ardupilot":
        return ArduPilotAutopilot(index, world, ardupilot_params(index + 1), options, counters)
    raise ValueError(f"unknown flavour {flavour!r}; expected one of {FLAVOURS}")


__all__ = [
    "FLAVOURS",
    "ArduPilotAutopilot",
    "Autopilot",
    "AutopilotOptions",
    "Codec",
    "Home",
    "LinkCounters",
    "Phase",
    "Px4Autopilot",
    "TcpLink",
    "UdpLink",
    "make_autopilot",
]
