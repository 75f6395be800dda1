"""Sub-pixel edge points: where an image profile across an edge crosses its mid level.

A marker's outline is a step between two levels (the marker's colour or black, and the
background) blurred by the optics and sampled by pixels. For a step blurred by any symmetric
kernel, the edge is where the profile crosses the mean of the two levels. Given rough edge
points and outward normals, :func:`refine_edge_points` samples the ``score`` image along each
normal (bilinear), and returns the linearly interpolated mid-level crossing nearest the rough
point. ``score`` must be high inside the marker (chroma for a coloured disc, darkness for a
tag's black border).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import FloatArray


def refine_edge_points(
    score: np.ndarray,
    points_px: ArrayLike,
    normals: ArrayLike,
    reach_in_px: float,
    reach_out_px: float,
    step_px: float = 0.25,
    min_contrast: float = 10.0,
) -> tuple[FloatArray, FloatArray]:
    """Refined points ``(N, 2)`` and a mask of points whose profile had a usable crossing.

    The profile of point ``k`` runs from ``-reach_in_px`` (inside) to ``+reach_out_px``
    (outside) along its unit outward normal. Points without a high-to-low crossing, or whose
    profile spans less than ``min_contrast``, keep their input position and are flagged False.
    """
    p = np.asarray(points_px, dtype=np.float32).reshape(-1, 2)
    n = np.asarray(normals, dtype=np.float32).reshape(-1, 2)
    offsets = np.arange(-reach_in_px, reach_out_px + 1e-6, step_px, dtype=np.float32)
    if p.shape[0] == 0 or offsets.size < 2:
        return p.astype(float), np.zeros(p.shape[0], dtype=bool)
    sx = p[:, None, 0] + offsets[None, :] * n[:, None, 0]
    sy = p[:, None, 1] + offsets[None, :] * n[:, None, 1]
    prof = cv2.remap(
        np.asarray(score, dtype=np.float32),
        sx,
        sy,
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    ).astype(float)
    hi, lo = prof.max(axis=1), prof.min(axis=1)
    mid = 0.5 * (hi + lo)[:, None]
    above = prof >= mid
    falls = above[:, :-1] & ~above[:, 1:]
    s0, s1 = prof[:, :-1], prof[:, 1:]
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.clip((s0 - mid) / (s0 - s1), 0.0, 1.0)
    cross = offsets[None, :-1] + frac * step_px
    cross = np.where(falls, cross, np.inf)
    k = np.argmin(np.abs(cross), axis=1)
    best = cross[np.arange(cross.shape[0]), k]
    ok = np.isfinite(best) & ((hi - lo) >= min_contrast)
    shift = np.where(ok, best, 0.0)
    return p.astype(float) + shift[:, None] * n.astype(float), ok


def contour_normals(contour_px: ArrayLike) -> FloatArray:
    """Unit outward normals of a closed, ordered contour ``(N, 2)`` (orientation from the sign of
    its shoelace area; tangent from a 5-point central difference)."""
    p = np.asarray(contour_px, dtype=float)
    k = np.arange(p.shape[0])
    nxt, nxt2 = (k + 1) % p.shape[0], (k + 2) % p.shape[0]
    tangent = p[nxt] - p[k - 1] + 0.5 * (p[nxt2] - p[k - 2])  # negative indices wrap
    norm = np.sqrt(np.sum(tangent * tangent, axis=1, keepdims=True))
    tangent /= np.where(norm > 0.0, norm, 1.0)
    signed_area = 0.5 * float(np.sum(p[:, 0] * p[nxt, 1] - p[nxt, 0] * p[:, 1]))
    orient = 1.0 if signed_area >= 0.0 else -1.0
    return orient * tangent[:, ::-1] * np.array([1.0, -1.0])
