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
    ekf_warmup_s: float = 4.0
    """ArduPilot: simulation seconds after boot until the EKF has a position: before it,
    LOCAL_POSITION_NED and HOME_POSITION do not stream (their requests are accepted) and arming
    is refused. ArduCopter 4.7 SITL takes about 40 s with GPS and 4.5 s with optical flow; the
    default is the optical-flow figure, which keeps tests fast."""
    boot_streams: bool = False
    """ArduPilot: stream the default set from boot, as this flavour once did, for clients that
    never ask. A real ArduCopter streams nothing but HEARTBEAT until asked."""
    home: Home = Home()

    def __post_init__(self) -> None:
        for name in ("warmup_s", "ekf_warmup_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0, got {value}")


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
