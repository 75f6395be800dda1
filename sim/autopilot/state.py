"""Plain state shared by the autopilot modules: the global home, options, flight phases."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

from messages import mavlink as mv

EARTH_RADIUS_M = 6378137.0


@dataclass(frozen=True)
class Home:
    """Global position of the world's NED origin (PX4 SITL's default home)."""

    lat_deg: float = 47.397742
    lon_deg: float = 8.545594
    alt_amsl_m: float = 488.0

    def to_global(self, p_ned: np.ndarray) -> tuple[float, float, float]:
        """Flat-earth conversion of a world NED position to (lat deg, lon deg, alt AMSL m)."""
        lat = self.lat_deg + math.degrees(p_ned[0] / EARTH_RADIUS_M)
        lon = self.lon_deg + math.degrees(
            p_ned[1] / (EARTH_RADIUS_M * math.cos(math.radians(self.lat_deg)))
        )
        return lat, lon, self.alt_amsl_m - float(p_ned[2])


@dataclass(frozen=True)
class AutopilotOptions:
    """Behaviour switches shared by all vehicles of a server."""

    strict: bool = False
    """Behave like an autopilot fresh from boot (module docstring of sim.server)."""
    warmup_s: float = 5.0
    """Strict mode: simulated estimator warm-up after boot."""
    home: Home = Home()


class Phase(enum.Enum):
    GROUND = "ground"
    TAKEOFF = "takeoff"
    AIR = "air"
    LANDING = "landing"
    RETURN = "return"


LANDED_STATE = {
    Phase.GROUND: mv.LANDED_ON_GROUND,
    Phase.TAKEOFF: mv.LANDED_TAKEOFF,
    Phase.AIR: mv.LANDED_IN_AIR,
    Phase.LANDING: mv.LANDED_LANDING,
    Phase.RETURN: mv.LANDED_IN_AIR,
}
