"""Numerical rank and rigidity eigenvalues: the one tolerance every rigidity test shares.

Singular values are counted as non-zero when larger than ``RANK_RTOL * s_max`` with
``RANK_RTOL = 1e-9``. The entries are exact formulas evaluated in double precision, so the
singular values of a truly trivial (null) direction come out at the round-off level
``~ sqrt(rows) * eps * s_max``, below ``1e-13 s_max`` for any fleet this toolkit handles; a
relative threshold of ``1e-9`` sits four orders of magnitude above that, so round-off is never
counted as rank. On the other side, a framework whose smallest non-trivial singular value is
below ``1e-9 s_max`` amplifies bearing noise by more than ``1e9`` in some direction, which is
flexible for every practical purpose, so calling it non-rigid is the right answer. Being
relative, the test does not depend on the units or the size of the formation. Near-degenerate
frameworks (e.g. nearly collinear agents) are better judged by the rigidity eigenvalue,
which every result also carries.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

RANK_RTOL = 1e-9
"""Relative singular-value threshold of every rank test in :mod:`onboard.rigidity`."""


def numerical_rank(matrix: ArrayLike, rtol: float = RANK_RTOL) -> int:
    """Number of singular values above ``rtol * s_max`` (see the module doc for ``rtol``)."""
    s = np.linalg.svd(np.asarray(matrix, dtype=float), compute_uv=False)
    if s.size == 0 or s[0] == 0.0:
        return 0
    return int(np.count_nonzero(s > rtol * s[0]))


def rigidity_eigenvalue(matrix: ArrayLike, n_trivial: int) -> float:
    """Smallest non-trivial eigenvalue of ``B^T B``: the ``(n_trivial + 1)``-th smallest."""
    b = np.asarray(matrix, dtype=float)
    if not 0 <= n_trivial < b.shape[1]:
        raise ValueError(f"n_trivial must lie in 0..{b.shape[1] - 1}, got {n_trivial}")
    eig = np.linalg.eigvalsh(b.T @ b)
    return float(max(eig[n_trivial], 0.0))
