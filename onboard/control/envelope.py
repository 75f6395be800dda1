"""Flight envelope: keep a vehicle's height between a floor and a ceiling, and inside a fence.

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

The formation grows horizontally too, and indoor labs fly in nets of a few metres; without GPS
an autopilot has no geofence either. The horizontal fence is a circle of radius ``R`` about the
autopilot's local origin (where its estimator started, the take-off spot): with ``r`` the
horizontal distance from it and ``e_r`` the outward unit vector, the outward velocity is bounded
the same way,

    v . e_r  <=  k (R - r),

and only that component is changed: inside, motion along the fence and inwards is untouched;
outside, the vehicle is pulled back in at ``k (r - R)``.
"""

from __future__ import annotations

import math

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


FENCE_GAIN_1_S = 1.0
"""``k`` of the fence: 1 m/s of allowed outward speed per metre from the fence."""


def bound_horizontal_velocity(
    v_north_m_s: float,
    v_east_m_s: float,
    north_m: float,
    east_m: float,
    radius_m: float,
    gain_1_s: float = FENCE_GAIN_1_S,
) -> tuple[float, float]:
    """``(v_north, v_east)`` with its outward component bounded by ``k (R - r)`` (module
    docstring); unchanged at the origin or when already within the bound.

    Raises ``ValueError`` unless ``radius_m > 0`` and ``gain_1_s > 0``.
    """
    if not radius_m > 0.0 or not gain_1_s > 0.0:
        raise ValueError("need radius_m > 0 and gain_1_s > 0")
    r = math.hypot(north_m, east_m)
    if r == 0.0:
        return v_north_m_s, v_east_m_s
    e_n, e_e = north_m / r, east_m / r
    outward = v_north_m_s * e_n + v_east_m_s * e_e
    excess = outward - gain_1_s * (radius_m - r)
    if excess <= 0.0:
        return v_north_m_s, v_east_m_s
    return v_north_m_s - excess * e_n, v_east_m_s - excess * e_e
