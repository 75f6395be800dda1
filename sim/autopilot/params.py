"""A small parameter table and its wire encoding (MAVLink parameter protocol).

MAVLink carries every parameter value in a float32 field. PX4 copies integer values into it
bytewise (``MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE``); ArduPilot casts them
(``PARAM_ENCODE_C_CAST``). :class:`ParamTable` stores typed values and converts at the edge.

Every parameter has a documented range (``lo``..``hi``, the min/max of PX4's parameter reference
and ArduCopter's ``@Range`` where they give one, docs/sim.md): a PARAM_SET outside it, of the
wrong type or non-finite leaves the table unchanged, and the vehicle answers as the parameter
protocol says, with PARAM_VALUE carrying the current value (plus a STATUSTEXT naming the
range, :meth:`sim.autopilot.common.Autopilot._on_param_set`). A value such as ``COM_OF_LOSS_T =
176`` (an offboard failsafe that never fires) or ``GUID_TIMEOUT = -3989`` is refused.

This is stricter than the firmware: ArduPilot checks only a few safety-critical parameters
onboard and leaves the ``@Range`` metadata to ground stations (ArduPilot issues 2986, 20711), and
PX4's ranges are metadata too. A client that handles the protocol's answer to a failed set (the
unchanged PARAM_VALUE) works with both; one that sets absurd values learns it here, not in flight.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

PARAM_TYPE_INT32 = 6
PARAM_TYPE_REAL32 = 9
_INT_TYPES = frozenset({1, 2, 3, 4, 5, 6})
_INT_RANGE = {1: (0, 255), 2: (-128, 127), 3: (0, 65535), 4: (-32768, 32767)}
_INT_RANGE.update({5: (0, 2**32 - 1), 6: (-(2**31), 2**31 - 1)})


@dataclass
class Param:
    name: str
    value: float | int
    param_type: int = PARAM_TYPE_REAL32
    lo: float = -math.inf
    """Smallest accepted value (inclusive)."""
    hi: float = math.inf
    """Largest accepted value (inclusive)."""
    strict_lo: bool = False
    """``lo`` itself (and ``-0.0``) is refused: only values above it are accepted."""

    def __post_init__(self) -> None:
        if not self.accepts(self.value):
            raise ValueError(f"parameter {self.name}: default {self.value} outside its range")

    def accepts(self, value: float) -> bool:
        """Whether ``value`` lies in the documented range (finite, and ``-0.0`` is not 0)."""
        if not math.isfinite(value):
            return False
        if self.strict_lo and (value <= self.lo or math.copysign(1.0, value) < 0 <= self.lo):
            return False
        return self.lo <= value <= self.hi

    def range_text(self) -> str:
        """The range as a STATUSTEXT fragment (``[0.1, 5]``, ``(0, 80]``)."""
        return f"{'(' if self.strict_lo else '['}{self.lo:g}, {self.hi:g}]"


class ParamTable:
    """Ordered, typed parameters; ``bytewise`` selects the PX4 encoding of integers."""

    def __init__(self, params: list[Param], bytewise: bool) -> None:
        for p in params:
            if len(p.name) > 16:
                raise ValueError(f"parameter name {p.name!r} is longer than 16 characters")
        self._params = list(params)
        self._index = {p.name: k for k, p in enumerate(self._params)}
        self.bytewise = bytewise

    def __len__(self) -> int:
        return len(self._params)

    def __contains__(self, name: object) -> bool:
        return name in self._index

    def get(self, name: str) -> float | int:
        return self._params[self._index[name]].value

    def by_index(self, index: int) -> Param | None:
        return self._params[index] if 0 <= index < len(self._params) else None

    def by_name(self, name: str) -> tuple[int, Param] | None:
        k = self._index.get(name)
        return None if k is None else (k, self._params[k])

    def items(self) -> list[tuple[int, Param]]:
        return list(enumerate(self._params))

    def wire_value(self, p: Param) -> float:
        """The float32 that carries ``p`` on the wire."""
        if p.param_type in _INT_TYPES and self.bytewise:
            return struct.unpack("<f", struct.pack("<I", int(p.value) & 0xFFFFFFFF))[0]
        return float(p.value)

    def set_from_wire(self, name: str, wire_value: float, wire_type: int) -> Param | None:
        """Apply a PARAM_SET; returns the updated parameter, or ``None`` if unknown or invalid
        (wrong type, non-finite, outside the wire type's or the parameter's documented range):
        the table is then unchanged."""
        found = self.by_name(name)
        if found is None:
            return None
        _, p = found
        if p.param_type in _INT_TYPES:
            if wire_type not in _INT_TYPES:
                return None
            if self.bytewise:
                bits = struct.unpack("<I", struct.pack("<f", wire_value))[0]
                signed = p.param_type in (2, 4, 6) and bits >= 2**31
                raw = bits - 2**32 if signed else bits
            else:
                if not math.isfinite(wire_value) or wire_value != int(wire_value):
                    return None
                raw = int(wire_value)
            lo, hi = _INT_RANGE[p.param_type]
            if not lo <= raw <= hi or not p.accepts(raw):
                return None
            p.value = raw
        else:
            if wire_type != PARAM_TYPE_REAL32 or not p.accepts(wire_value):
                return None
            p.value = float(wire_value)
        return p


def px4_params(sys_id: int) -> ParamTable:
    """The PX4 flavour's parameters (names and defaults as in PX4)."""
    return ParamTable(
        [
            Param("MAV_SYS_ID", sys_id, PARAM_TYPE_INT32, 1, 250),
            Param("MAV_TYPE", 2, PARAM_TYPE_INT32, 0, 22),
            Param("SYS_AUTOSTART", 4001, PARAM_TYPE_INT32, 0, 9999999),
            Param("MIS_TAKEOFF_ALT", 2.5, lo=0.0, hi=80.0, strict_lo=True),
            Param("MPC_XY_CRUISE", 5.0, lo=3.0, hi=20.0),
            Param("MPC_TKO_SPEED", 1.5, lo=1.0, hi=5.0),
            Param("MPC_LAND_SPEED", 0.7, lo=0.6, hi=4.0),
            Param("RTL_RETURN_ALT", 30.0, lo=0.0, hi=150.0),
            Param("COM_OF_LOSS_T", 1.0, lo=0.0, hi=60.0),
            Param("COM_OBL_RC_ACT", 0, PARAM_TYPE_INT32, 0, 7),
            Param("COM_DISARM_LAND", 2.0, lo=0.0, hi=20.0),
            Param("COM_DISARM_PRFLT", 10.0, lo=0.0, hi=20.0),
        ],
        bytewise=True,
    )


def ardupilot_params(sys_id: int) -> ParamTable:
    """The ArduCopter flavour's parameters (names, units and defaults as in ArduCopter)."""
    return ParamTable(
        [
            Param("SYSID_THISMAV", sys_id, PARAM_TYPE_INT32, 1, 255),
            Param("FRAME_CLASS", 1, PARAM_TYPE_INT32, 0, 17),
            Param("GUID_TIMEOUT", 3.0, lo=0.1, hi=5.0),
            Param("WPNAV_SPEED", 500.0, lo=20.0, hi=2000.0),
            Param("WPNAV_SPEED_UP", 250.0, lo=10.0, hi=1000.0),
            Param("WPNAV_SPEED_DN", 150.0, lo=10.0, hi=500.0),
            Param("PILOT_SPEED_UP", 250.0, lo=50.0, hi=500.0),
            Param("LAND_SPEED", 50.0, lo=30.0, hi=200.0),
            Param("LAND_SPEED_HIGH", 0.0, lo=0.0, hi=2500.0),
            Param("LAND_ALT_LOW", 1000.0, lo=100.0, hi=10000.0),
            Param("RTL_ALT", 1500.0, lo=200.0, hi=300000.0),
            Param("PILOT_TKOFF_ALT", 0.0, lo=0.0, hi=1000.0),
            Param("DISARM_DELAY", 10, PARAM_TYPE_INT32, 0, 127),
            Param("ARMING_CHECK", 1, PARAM_TYPE_INT32),
        ],
        bytewise=False,
    )
