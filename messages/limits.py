"""Physical ranges of every quantity that crosses a process boundary, in one table.

The codec (:mod:`messages.codec`) rejects NaN and infinity; these bounds also reject the huge
*finite* numbers that a faulty or compromised sender can put in a well-formed payload (one
``MotionShare`` with ``v_body = 1e300`` made every estimate of its receiver NaN, issue 23).
They are deliberately generous: ten to a thousand times what a multicopter team reaches, so
no legitimate sample comes near them, while anything beyond is physically impossible and would
overflow the estimators' products (``|v|^2``, ``|p|^2``, ``chi |u|``).

The payload structs of :mod:`messages.peer`, :mod:`messages.sim`, :mod:`messages.rigidity` and
:mod:`messages.codec` use the ``Annotated`` types below, so msgspec enforces the bounds while
decoding; :data:`ARRAY_ABS_MAX` bounds the :data:`messages.codec.F64Array` fields in
:func:`messages.codec.decode`. A violation is a :class:`messages.codec.MessageError` with reason
``out_of_range``, counted and dropped like any other bad sample. The table is documented in
docs/flying.md ("Input limits").

Stamps are bounded twice: here by magnitude, and by each receiver against its own clock
(:data:`STAMP_FUTURE_MAX_S`): a stamp further ahead than that is dropped (``future_stamp``).
"""

from __future__ import annotations

from typing import Annotated

import msgspec

SPEED_MAX_M_S = 100.0
"""Any velocity component (body or NED), m/s. Multicopters fly below 30 m/s."""
POSITION_MAX_M = 1.0e5
"""Any position component (NED or the team's estimated frame), m: 100 km from the origin."""
ANGLE_MAX_RAD = 1.0e6
"""Any angle, rad. Odometry yaws are wrapped, but a sender's own reference may be unwrapped;
at 1e6 rad a double still resolves 1e-10 rad."""
RATE_MAX_RAD_S = 20.0
"""Any angular rate, rad/s (multicopters turn below 5 rad/s)."""
BEARING_COMPONENT_MAX = 1.01
"""A component of a unit bearing (receivers check the norm to 1e-3 themselves)."""
INV_DISTANCE_MAX_INV_M = 100.0
"""Inverse distance ``chihat`` of an SfM observer, 1/m (1 cm); also bounded below by its minus."""
DIMENSIONLESS_MAX = 1.0e9
"""Excitation ``lambda``, convergence index ``E``, e-foldings, consensus states, eigenvalues."""
STAMP_ABS_MAX_S = 1.0e10
"""Any stamp or clock reading, s (Unix time until the year 2286; simulation time from 0)."""
SPEEDUP_MAX = 1000.0
"""Simulation seconds per wall second a simulator may announce."""
AGENT_ID_MAX = 65_535
"""Largest agent id (sender, target, edge end); the fleet file bounds the ids further."""
SEQ_MAX = (1 << 63) - 1
"""Sequence numbers are non-negative int64."""
LIST_MAX = 4096
"""Longest per-payload list (targets, edges, consensus names): far above any fleet's size."""
NAME_MAX = 64
"""Longest consensus quantity name."""
ARRAY_ABS_MAX = DIMENSIONLESS_MAX
"""Bound of every entry of a float64 array field (rigidity shares: positions, eigenvectors)."""
RANGE_MIN_M = 1.0 / INV_DISTANCE_MAX_INV_M
"""Shortest measured distance to another vehicle, m (1 cm: the SfM observers' bound, above)."""
RANGE_MAX_M = POSITION_MAX_M
"""Longest measured distance to another vehicle, m (100 km: a camera sees a vehicle's marker
within tens of metres)."""
STAMP_FUTURE_MAX_S = 1.0
"""A receiver drops a sample stamped more than this ahead of its own clock (``future_stamp``):
the team's clocks agree to milliseconds (docs/flying.md), and a peer whose clock runs ahead by
more than 0.2 s is already flagged by :mod:`onboard.daemon.peer_clock`."""


def _sym(limit: float) -> msgspec.Meta:
    return msgspec.Meta(ge=-limit, le=limit)


Speed = Annotated[float, _sym(SPEED_MAX_M_S)]
Position = Annotated[float, _sym(POSITION_MAX_M)]
Angle = Annotated[float, _sym(ANGLE_MAX_RAD)]
Rate = Annotated[float, _sym(RATE_MAX_RAD_S)]
BearingComponent = Annotated[float, _sym(BEARING_COMPONENT_MAX)]
InvDistance = Annotated[float, _sym(INV_DISTANCE_MAX_INV_M)]
Dimensionless = Annotated[float, _sym(DIMENSIONLESS_MAX)]
Stamp = Annotated[float, _sym(STAMP_ABS_MAX_S)]
Speedup = Annotated[float, msgspec.Meta(ge=0.0, le=SPEEDUP_MAX)]
AgentId = Annotated[int, msgspec.Meta(ge=0, le=AGENT_ID_MAX)]
Seq = Annotated[int, msgspec.Meta(ge=0, le=SEQ_MAX)]
Name = Annotated[str, msgspec.Meta(max_length=NAME_MAX)]

SpeedVec3 = tuple[Speed, Speed, Speed]
PositionVec3 = tuple[Position, Position, Position]
Bearing3 = tuple[BearingComponent, BearingComponent, BearingComponent]
IdList = Annotated[list[AgentId], msgspec.Meta(max_length=LIST_MAX)]


def stamp_ahead(stamp_s: float, now_s: float | None) -> bool:
    """Whether a sender's ``stamp_s`` is further ahead of the receiver's clock ``now_s`` than
    :data:`STAMP_FUTURE_MAX_S` (``False`` while the receiver's clock is unknown)."""
    return now_s is not None and stamp_s > now_s + STAMP_FUTURE_MAX_S


def plausible_range(range_m: float) -> bool:
    """Whether a measured distance to another vehicle is finite and within
    [:data:`RANGE_MIN_M`, :data:`RANGE_MAX_M`] (``False`` for NaN and infinity)."""
    return RANGE_MIN_M <= range_m <= RANGE_MAX_M
