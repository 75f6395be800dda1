"""Seeded standard-normal draws without ``numpy.random`` (issue 27: onboard footprint).

A daemon draws random numbers twice, once each at start: the active controller's first
direction (paper 000 eq. 12, ``onboard/core/motion.py``) and the distributed eigenvector
estimator's start block (``onboard/estimation/distributed_eigen.py``). ``numpy.random`` is a
lazily loaded subpackage of numpy, and the first ``np.random`` touch loaded it: 6.8 MB
resident (measured in a fresh interpreter after numpy, this machine) for a handful of numbers.
Python's :class:`random.Random` is loaded anyway; seeded with a string it is reproducible
across runs and platforms (seed version 2: the string's bytes, not its salted hash; Python
docs, ``random.seed``). The draws differ from the earlier ``numpy.random`` ones: each is still
a fixed function of its seed.
"""

from __future__ import annotations

import math
import random
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray


def standard_normal(seed: Sequence[int], shape: int | tuple[int, ...]) -> NDArray[np.float64]:
    """An array of ``shape`` independent standard-normal draws, a fixed function of ``seed``
    (a sequence of integers, e.g. ``(fleet seed, agent id, purpose)``)."""
    rng = random.Random("bearingflock:" + ",".join(str(int(s)) for s in seed))
    dims = (shape,) if isinstance(shape, int) else tuple(shape)
    draws = [rng.gauss(0.0, 1.0) for _ in range(math.prod(dims))]
    return np.array(draws, dtype=np.float64).reshape(dims)
