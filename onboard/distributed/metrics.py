"""Errors modulo the unobservable gauge of paper 002 (the ``g`` and scale ``alpha`` of its
state decomposition, fig. 1): positions after the best similarity (or scale + translation)
alignment, rotations after the best global rotation."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import FloatArray, so3_distance


def _proj_so(m: FloatArray) -> FloatArray:
    u, _, vt = np.linalg.svd(m)
    s = np.eye(m.shape[0])
    s[-1, -1] = np.sign(np.linalg.det(u @ vt)) or 1.0
    return u @ s @ vt


def align_similarity(est: ArrayLike, true: ArrayLike, rotate: bool = True) -> FloatArray:
    """``s Q est_i + c`` closest to ``true_i`` in least squares (Umeyama; ``rotate=False``: scale
    and translation only, for known rotations). ``(N, d) -> (N, d)``."""
    x = np.asarray(est, dtype=float)
    y = np.asarray(true, dtype=float)
    xc, yc = x - x.mean(axis=0), y - y.mean(axis=0)
    q = _proj_so(yc.T @ xc) if rotate else np.eye(x.shape[1])
    xr = xc @ q.T
    den = float(np.sum(xr * xr))
    s = float(np.sum(xr * yc)) / den if den > 0 else 0.0
    return s * xr + y.mean(axis=0)


def position_error_m(est: ArrayLike, true: ArrayLike, rotate: bool = True) -> float:
    """Largest ``|aligned est_i - true_i|`` after :func:`align_similarity`."""
    a = align_similarity(est, true, rotate)
    return float(np.max(np.linalg.norm(a - np.asarray(true, dtype=float), axis=1)))


def align_rotations(est: ArrayLike, true: ArrayLike) -> FloatArray:
    """``G R_est_i`` with the global ``G`` closest to ``true`` (``G = proj sum R_true R_est^T``).
    ``(N, 3, 3) -> (N, 3, 3)``."""
    e = np.asarray(est, dtype=float)
    t = np.asarray(true, dtype=float)
    g = _proj_so(np.sum(t @ np.swapaxes(e, -1, -2), axis=0))
    return g @ e


def rotation_error_deg(est: ArrayLike, true: ArrayLike) -> float:
    """Largest geodesic error (degrees) after :func:`align_rotations`."""
    a = align_rotations(est, true)
    return float(np.degrees(np.max(so3_distance(a, np.asarray(true, dtype=float)))))


def distance_errors_m(p: ArrayLike, edges: ArrayLike, d_des_m: ArrayLike) -> FloatArray:
    """``| |p_j - p_i| - d*_ij |`` per edge: ``(E,)``."""
    pp = np.asarray(p, dtype=float)
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    d = np.linalg.norm(pp[e[:, 1]] - pp[e[:, 0]], axis=1)
    return np.abs(d - np.asarray(d_des_m, dtype=float))
