"""Altitude envelope: keep a vehicle's height between a floor and a ceiling.

Bearing formations carry no scale (paper 002; :mod:`onboard.control.formation`), and paper
000's active motion moves the team along that free direction: a formation can grow while it
flies, and its vertical offsets grow with it. Started 2.5 m up, a three-vehicle team in the
simulator settled at 1.0, 2.5 and 4.0 m, its spacing grown from 4 to 14 m. Nothing in the papers keeps
a vehicle off the ground, and an autopilot in offboard velocity control does not either.

The envelope bounds the commanded *down* velocity by the height margin (a first-order barrier,
the same shape as a geofence's soft boundary): with height ``h`` (m above the autopilot's
local origin), floor ``h_min``, ceiling ``h_max`` and gain ``k`` (1/s),

    -k (h_max - h)  <=  v_down  <=  k (h - h_min).

Inside the band the bounds only slow a descent near the floor (or a climb near the ceiling),
reaching zero there; below the floor the upper bound is negative and the vehicle climbs at
``k (h_min - h)``, above the ceiling it descends likewise. The horizontal command is untouched,
and ``v_down`` is the third component of the heading-frame velocity (a rotation about the down
axis leaves it unchanged).
"""

from __future__ import annotations

ALTITUDE_GAIN_1_S = 1.0
"""``k``: 1 m/s of allowed descent per metre above the floor."""


def bound_down_velocity(
    v_down_m_s: float,
    altitude_m: float,
    min_alt_m: float,
    max_alt_m: float,
    gain_1_s: float = ALTITUDE_GAIN_1_S,
) -> float:
    """``v_down`` clipped to ``[-k (h_max - h), k (h - h_min)]`` (module docstring).

    Raises ``ValueError`` unless ``min_alt_m < max_alt_m`` and ``gain_1_s > 0``.
    """
    if not min_alt_m < max_alt_m or not gain_1_s > 0.0:
        raise ValueError("need min_alt_m < max_alt_m and gain_1_s > 0")
    lowest = -gain_1_s * (max_alt_m - altitude_m)
    highest = gain_1_s * (altitude_m - min_alt_m)
    return min(max(v_down_m_s, lowest), highest)
