"""Sub-pixel edge points: where an image profile across an edge crosses its mid level.

A marker's outline is a step between two levels (the marker's colour or black, and the
background) blurred by the optics and sampled by pixels. For a step blurred by any symmetric
kernel, the edge is where the profile crosses the mean of the two levels. Given rough edge
points and outward normals, :func:`sample_profiles` samples the ``score`` image along each
normal (bilinear) and :func:`profile_crossings` returns the linearly interpolated mid-level
crossing nearest the rough point, for the profiles of several contours at once. ``score``
must be high inside the marker (chroma for a coloured disc, darkness for a tag's black
border).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import FloatArray

_RIGHT = np.array([1.0, -1.0])
_LEFT = -_RIGHT


def profile_offsets(reach_in_px: float, reach_out_px: float, step_px: float) -> np.ndarray:
    """Sample positions (float32, px) along a normal: ``-reach_in_px`` to ``reach_out_px``."""
    return np.arange(-reach_in_px, reach_out_px + 1e-6, step_px, dtype=np.float32)


def sample_profiles(
    score: np.ndarray, points_px: np.ndarray, normals: np.ndarray, offsets: np.ndarray
) -> np.ndarray:
    """Bilinear samples ``(N, S)`` (float32) of ``score`` at ``points + offsets x normals``
    (points and normals ``(N, 2)`` float32); the image edge is replicated."""
    return sample_profiles_xy(
        score, points_px[:, 0], points_px[:, 1], normals[:, 0], normals[:, 1], offsets
    )


def sample_profiles_xy(
    score: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    nx: np.ndarray,
    ny: np.ndarray,
    offsets: np.ndarray,
) -> np.ndarray:
    """:func:`sample_profiles` with the points and normals as coordinate vectors ``(N,)``."""
    sx = x[:, None] + offsets[None, :] * nx[:, None]
    sy = y[:, None] + offsets[None, :] * ny[:, None]
    return cv2.remap(
        np.asarray(score, dtype=np.float32),
        sx,
        sy,
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )


def profile_crossings(
    prof: np.ndarray, offsets: np.ndarray, min_contrast: float
) -> tuple[FloatArray, FloatArray]:
    """Shift along the normal (px, 0 where none) and found-mask of each profile's high-to-low
    mid-level crossing nearest the rough point (offset 0), linearly interpolated between
    samples (``offsets`` evenly spaced); a profile spanning less than ``min_contrast`` has none.
    Profiles of several contours can be stacked and done in one call."""
    hi = cv2.reduce(prof, 1, cv2.REDUCE_MAX)  # (N, 1)
    lo = cv2.reduce(prof, 1, cv2.REDUCE_MIN)
    mid = 0.5 * (hi + lo)
    above = prof >= mid
    falls = above[:, :-1] > above[:, 1:]  # above, then not above: a high-to-low crossing
    s0 = prof[:, :-1]
    # linear interpolation of the crossing inside its step; no crossing -> inf
    cross = np.divide(
        s0 - mid, s0 - prof[:, 1:], out=np.full(falls.shape, np.inf, np.float32), where=falls
    )
    cross *= offsets[1] - offsets[0]
    cross += offsets[:-1]
    k = np.argmin(np.abs(cross), axis=1)
    best = cross[np.arange(cross.shape[0]), k]
    ok = np.isfinite(best) & ((hi - lo)[:, 0] >= min_contrast)
    return np.where(ok, best, 0.0), ok


def contour_normals(contour_px: ArrayLike) -> FloatArray:
    """Unit outward normals of a closed, ordered contour ``(N, 2)`` (orientation from the sign of
    its shoelace area; tangent from a 5-point central difference)."""
    p = np.asarray(contour_px, dtype=float).reshape(-1, 2)
    if p.shape[0] == 0:
        return p.copy()
    wrapped = p[np.arange(-2, p.shape[0] + 2) % p.shape[0]]
    # wrapped[k + 2] = p[k]: central differences over k -+ 1 and k -+ 2 (cyclic)
    nxt = wrapped[3:-1]
    tangent = nxt - wrapped[1:-3] + 0.5 * (wrapped[4:] - wrapped[:-4])
    norm = np.hypot(tangent[:, 0], tangent[:, 1])[:, None]
    tangent /= np.where(norm > 0.0, norm, 1.0)
    signed_area = 0.5 * float(p[:, 0] @ nxt[:, 1] - nxt[:, 0] @ p[:, 1])
    return tangent[:, ::-1] * (_RIGHT if signed_area >= 0.0 else _LEFT)
