"""Counter-based random draws: the same number for the same ``(seed, stream, a, b, c)``, in any
order, in Python and in numba-compiled code alike.

The headless runner's two engines (one Python agent core per vehicle, or the compiled team
engine) must lose the same messages and add the same noise to a run with the same seed, although
they visit messages and bearings in different orders. A sequential generator ties each draw to
the order of the calls before it; a counter-based one (Salmon et al., "Parallel random numbers:
as easy as 1, 2, 3", SC 2011) makes each draw a hash of *what* it is for: the copy of message
kind ``c`` sent by ``a`` to ``b`` at step ``k`` is lost when ``uniform(seed, LOSS, k, a * n + b,
c) < loss``, whichever engine asks.

The hash is MurmurHash3's 32-bit finalizer chained over the five words. Every operation keeps
its operands below ``2**32`` and masks its result to 32 bits, so Python's unbounded integers and
numba's wrapping ``int64`` give the same bits (a product of two 32-bit words overflows ``int64``,
but its low 32 bits, all that is kept, are right in two's complement). Not for cryptography.
"""

from __future__ import annotations

import math

MASK32 = 0xFFFFFFFF
LOSS = 1
"""Stream of message-loss draws: ``(step, sender * n + receiver, kind)``."""
BEARING_NOISE = 2
"""Stream of bearing noise: ``(frame, edge, axis)``."""
ODOMETRY_NOISE = 3
"""Stream of odometry noise: ``(step, agent, component)`` (``v_body`` x, y, z, yaw rate)."""

# the payload kinds of the loss stream (one word per peer payload type, messages.peer and
# messages.rigidity; sim.runner.PAYLOAD_KINDS maps the types, the compiled engines use these)
KIND_MOTION = 0
KIND_LOCALIZATION = 1
KIND_CONSENSUS = 2
KIND_EXCITATION = 3
KIND_SFM = 4
KIND_BEARING = 5
KIND_ANGLE_LOCALIZATION = 6
KIND_RIGIDITY_EIGEN = 7
KIND_GRADIENT_LOCALIZATION = 8


def fmix32(h: int) -> int:
    """MurmurHash3's finalizer: a bijection of 32-bit words with full avalanche."""
    h &= MASK32
    h ^= h >> 16
    h = (h * 0x85EBCA6B) & MASK32
    h ^= h >> 13
    h = (h * 0xC2B2AE35) & MASK32
    h ^= h >> 16
    return h


def hash32(seed: int, stream: int, a: int, b: int, c: int) -> int:
    """A 32-bit hash of five integers (each taken modulo ``2**32``)."""
    h = fmix32(seed & MASK32)
    h = fmix32(h ^ (stream & MASK32))
    h = fmix32(h ^ (a & MASK32))
    h = fmix32(h ^ (b & MASK32))
    h = fmix32(h ^ (c & MASK32))
    return h


def uniform(seed: int, stream: int, a: int, b: int, c: int) -> float:
    """A uniform draw in ``[0, 1)`` (32-bit resolution)."""
    return hash32(seed, stream, a, b, c) * (1.0 / 4294967296.0)


def normal(seed: int, stream: int, a: int, b: int, c: int) -> float:
    """A standard normal draw (Box-Muller on two uniforms derived from the same counter)."""
    h = hash32(seed, stream, a, b, c)
    u1 = (fmix32(h ^ 0x68E31DA4) + 1.0) * (1.0 / 4294967297.0)  # in (0, 1): log is finite
    u2 = fmix32(h ^ 0xB5297A4D) * (1.0 / 4294967296.0)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


def lost(
    seed: int, step: int, sender: int, receiver: int, n_agents: int, kind: int, p: float
) -> bool:
    """Whether the copy of payload kind ``kind`` that ``sender`` publishes at ``step`` is lost on
    its way to ``receiver`` (probability ``p``, independent per copy)."""
    if p <= 0.0:
        return False
    return uniform(seed, LOSS, step, sender * n_agents + receiver, kind) < p
