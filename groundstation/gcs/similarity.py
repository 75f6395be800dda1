"""The least-squares similarity between two planar point sets (Umeyama 1991).

Bearings fix a formation only up to translation, scale and heading, so every picture that puts
an estimate or a plan beside the truth first maps it by this similarity. Pure: arrays in,
arrays out; its own module because the recording readers, the plots and the 3D scene all use it.
"""

from __future__ import annotations

import numpy as np

from onboard.geometry import FloatArray


def similarity_2d(src: FloatArray, dst: FloatArray) -> tuple[float, FloatArray, FloatArray]:
    """Scale ``s``, rotation ``R`` (2x2) and translation ``t`` minimizing
    ``sum |dst_k - (s R src_k + t)|^2`` (Umeyama 1991, eq. 40-42); needs >= 2 distinct points."""
    src = np.asarray(src, dtype=float)
    dst = np.asarray(dst, dtype=float)
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    xs, xd = src - mu_s, dst - mu_d
    var_s = np.sum(xs**2) / len(src)
    if var_s <= 0:
        raise ValueError("similarity_2d needs at least two distinct source points")
    cov = xd.T @ xs / len(src)
    u, sig, vt = np.linalg.svd(cov)
    d = np.diag([1.0, np.sign(np.linalg.det(u) * np.linalg.det(vt)) or 1.0])
    r = u @ d @ vt
    s = float(np.trace(np.diag(sig) @ d) / var_s)
    return s, r, mu_d - s * r @ mu_s
