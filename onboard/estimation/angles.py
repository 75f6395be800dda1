"""Scalar angle arithmetic shared by the per-vehicle estimators and the compiled team engine.

Written in the subset of Python that numba compiles (``sim.jit``): numba has neither
``math.remainder`` nor ``math.fmod``, but its ``%`` on two positive floats is the exact
``fmod`` that CPython's is, so :func:`wrap_rad` is ``math.remainder(a, tau)`` bit for bit in
both (docs/equations.md, "Conventions": angles are wrapped to ``[-pi, pi]``).
"""

from __future__ import annotations

import math

TAU = math.tau
PI = math.pi
THREE_PI = 3.0 * math.pi


def wrap_rad(a: float) -> float:
    """``math.remainder(a, tau)``: ``a`` minus the nearest multiple of ``2 pi``, in ``[-pi, pi]``.

    ``|a| % tau`` is exact (an ``fmod`` of positive operands) and subtracting ``tau`` from a
    remainder in ``(pi, tau)`` is exact too (Sterbenz), so the result is the exact IEEE
    remainder. A non-finite ``a`` gives NaN (``math.remainder`` raises on infinity). Angles
    within a turn of the range skip the ``fmod`` (15 ns in numba, most of the calls)."""
    if -PI <= a <= PI:  # the usual case: already wrapped
        return a
    if PI < a < THREE_PI:  # one turn off: n = 1, and a - tau is exact (Sterbenz)
        return a - TAU
    if -THREE_PI < a < -PI:
        return -(-a - TAU)  # (the sign of a zero as math.remainder)
    r = abs(a) % TAU
    if r > PI:
        r -= TAU
    elif r == PI and abs(a) % (2.0 * TAU) != PI:  # a tie: the even multiple, as IEEE
        r = -PI
    return r if a >= 0.0 else -r
