"""RANSAC scale consensus from redundant range readings (paper 002, "Scale consensus").

Bearings fix a formation up to scale; ranges from the marker sizes fix the scale but are noisy
and sometimes wrong (a partly hidden disc, a bad ellipse). Every range reading gives one
candidate for the same unknown, and a consensus over the candidates rejects the outliers:

* network form: ranges ``r_ij`` and an up-to-scale formation estimate with distances ``dhat_ij``
  give candidate scales ``s = r_ij / dhat_ij`` (:func:`scale_candidates`);
* the paper's triangle form: the interior angles (from bearings) and any measured side give
  the "base" side by the law of sines, ``base = side_k sin(A_base) / sin(A_k)``
  (:func:`triangle_base_candidates`).

:func:`consensus` is RANSAC with one-point hypotheses. With so few readings (tens) every
candidate is tried as a hypothesis, which is the exhaustive limit of eq. 35 and makes the result
deterministic; the inliers are the candidates within a relative tolerance of the hypothesis, the
largest set wins (ties: the smaller spread), and the estimate is the inliers' median.

Pure numpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import FloatArray


@dataclass(frozen=True)
class Consensus:
    """``value``: the consensus estimate; ``inliers``: mask over the candidates."""

    value: float
    inliers: FloatArray

    @property
    def n_inliers(self) -> int:
        return int(np.sum(self.inliers))


def scale_candidates(d_unscaled: ArrayLike, ranges_m: ArrayLike) -> FloatArray:
    """Candidate scales ``r_ij / dhat_ij`` (metres per unit of the up-to-scale estimate)."""
    d = np.asarray(d_unscaled, dtype=float)
    r = np.asarray(ranges_m, dtype=float)
    if d.shape != r.shape:
        raise ValueError(f"shapes differ: {d.shape} vs {r.shape}")
    if np.any(d <= 0.0):
        raise ValueError("up-to-scale distances must be positive")
    return r / d


def triangle_base_candidates(
    angles_rad: ArrayLike, side_index: ArrayLike, side_m: ArrayLike, base: int = 0
) -> FloatArray:
    """Base-side candidates of a triangle from its interior angles and measured sides.

    ``angles_rad[k]`` is the interior angle *opposite* side ``k`` (so at the vertex that does not
    touch it); ``side_m[m]`` measures side ``side_index[m]``. Law of sines:
    ``base = side_k sin(A_base) / sin(A_k)``.
    """
    a = np.asarray(angles_rad, dtype=float)
    k = np.asarray(side_index, dtype=np.int64)
    s = np.asarray(side_m, dtype=float)
    return s * np.sin(a[base]) / np.sin(a[k])


def consensus(candidates: ArrayLike, rel_tol: float = 0.1, min_inliers: int = 2) -> Consensus:
    """One-point RANSAC over scalar candidates (exhaustive hypotheses, see module docstring).

    Raises ``ValueError`` when no hypothesis gathers ``min_inliers`` finite, positive candidates.
    """
    c = np.asarray(candidates, dtype=float).ravel()
    finite = np.isfinite(c) & (c > 0.0)
    if np.sum(finite) < min_inliers:
        raise ValueError(f"need at least {min_inliers} valid candidates, got {int(np.sum(finite))}")
    h = np.where(finite, c, np.nan)
    with np.errstate(invalid="ignore"):
        member = np.abs(h[None, :] - h[:, None]) <= rel_tol * h[:, None]  # (hyp, cand)
    member &= finite[None, :] & finite[:, None]
    counts = member.sum(axis=1)
    spread = np.where(member, np.abs(h[None, :] - h[:, None]), 0.0).sum(axis=1)
    order = np.lexsort((spread, -counts))
    best = order[0]
    if counts[best] < min_inliers:
        raise ValueError("no consensus: candidates disagree beyond the tolerance")
    inliers = member[best]
    return Consensus(value=float(np.median(c[inliers])), inliers=inliers)
