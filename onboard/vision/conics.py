"""Conics and circular targets: fitting, robust fitting (RANSAC) and the disc pose (paper 002).

A conic is a symmetric 3x3 matrix ``Q`` with ``p^T Q p = 0`` for the homogeneous image points
``p = (u, v, 1)`` on it (paper 002 eq. 32). A disc of radius ``r0`` seen by a camera images to
an ellipse; in *normalized* coordinates (``K = I``) the eigen-decomposition of that ellipse's
conic gives the disc's normal (eq. 33) and centre (eq. 34), hence a bearing and a range.

Equations 33-34 as printed index the eigenvectors inconsistently. With the eigenvalues sorted
``lambda_2 < 0 < lambda_0 <= lambda_1`` (after fixing the sign of ``Q`` so two are positive),
the formulas that hold (checked against an independent forward model in the tests) use the
eigenvector ``q_1`` of the *largest* eigenvalue where the paper writes ``q_0``::

    n = sqrt((l1 - l0)/(l1 - l2)) q1 +- sqrt((l0 - l2)/(l1 - l2)) q2                (33)
    t = r0 / sqrt(-l1 l2) (l2 sqrt((l1 - l0)/(l1 - l2)) q1 +- l1 sqrt((l0 - l2)/(l1 - l2)) q2) (34)

with ``t`` flipped to ``t_z > 0`` (in front of the camera) and ``n`` to face the camera. The
``+-`` is the classic two-fold ambiguity of a circle seen in one view: both candidates are
returned. Their centres differ by a small fraction of the range for a small disc.

RANSAC (paper 002 side panel, eq. 35): hypotheses are exact conics through 5 random contour
points; the iteration count is ``N = log(1-p) / log(1-(1-eps)^n)``, recomputed whenever a larger
consensus set is found (``eps`` = current outlier ratio, ``n = 5``). The final model is the direct
least-squares ellipse fit of Fitzgibbon et al. (paper 002 ref. [24]) on the inliers, in the
numerically stable form of Halir and Flusser. :func:`robust_ellipse` tries that direct fit on all
points first and runs RANSAC only when it leaves too many outliers (the common, unoccluded case
then costs one fit instead of hundreds of hypotheses).

Pure numpy, vectorized over hypotheses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import FloatArray

CONIC_SAMPLE_SIZE = 5
# Q = [[a, b/2, d/2], [b/2, c, e/2], [d/2, e/2, f]] from (a, b, c, d, e, f), row by row.
_CONIC_INDEX = np.array([0, 1, 3, 1, 2, 4, 3, 4, 5])
_CONIC_SCALE = np.array([1.0, 0.5, 0.5, 0.5, 1.0, 0.5, 0.5, 0.5, 1.0])


def ransac_iterations(p_success: float, outlier_ratio: float, n_sample: int) -> float:
    """Number of RANSAC draws for success probability ``p`` (paper 002 eq. 35).

    ``N = log(1 - p) / log(1 - (1 - eps)^n)``; 0 when there are no outliers, ``inf`` when every
    point is an outlier.
    """
    if not 0.0 < p_success < 1.0:
        raise ValueError(f"p_success must be in (0, 1), got {p_success}")
    good = (1.0 - outlier_ratio) ** n_sample
    if good >= 1.0:
        return 0.0
    if good <= 0.0:
        return math.inf
    return math.log(1.0 - p_success) / math.log(1.0 - good)


def conic_matrix(coeffs: ArrayLike) -> FloatArray:
    """``(a, b, c, d, e, f)`` of ``a u^2 + b uv + c v^2 + d u + e v + f = 0`` -> symmetric ``Q``."""
    c = np.asarray(coeffs, dtype=float)
    return (c[..., _CONIC_INDEX] * _CONIC_SCALE).reshape(*c.shape[:-1], 3, 3)


def conic_from_ellipse(
    center: ArrayLike, major_angle_rad: float, semi_major: float, semi_minor: float
) -> FloatArray:
    """Conic of an ellipse from centre, major-axis direction and semi-axes (paper 002 eq. 32).

    ``alpha_1 = cos^2/A^2 + sin^2/B^2``, ``alpha_2 = sin^2/A^2 + cos^2/B^2``,
    ``alpha_3 = cos sin (1/A^2 - 1/B^2)``, ``alpha_4 = -c_u alpha_1 - c_v alpha_3``,
    ``alpha_5 = -c_u alpha_3 - c_v alpha_2``,
    ``alpha_6 = alpha_1 c_u^2 + alpha_2 c_v^2 + 2 alpha_3 c_u c_v - 1`` (the paper's text lost the
    squares), where ``(cos, sin)`` is the unit major axis.
    """
    cu, cv = np.asarray(center, dtype=float)
    co, si = math.cos(major_angle_rad), math.sin(major_angle_rad)
    ia, ib = 1.0 / semi_major**2, 1.0 / semi_minor**2
    a1 = co * co * ia + si * si * ib
    a2 = si * si * ia + co * co * ib
    a3 = co * si * (ia - ib)
    a4 = -cu * a1 - cv * a3
    a5 = -cu * a3 - cv * a2
    a6 = a1 * cu * cu + a2 * cv * cv + 2.0 * a3 * cu * cv - 1.0
    return np.array([[a1, a3, a4], [a3, a2, a5], [a4, a5, a6]])


@dataclass(frozen=True)
class EllipseGeometry:
    """Centre, semi-axes and major-axis angle of an ellipse conic (in the conic's units)."""

    center: FloatArray
    semi_major: float
    semi_minor: float
    major_angle_rad: float

    @property
    def area(self) -> float:
        return math.pi * self.semi_major * self.semi_minor


def ellipse_geometry(q: ArrayLike) -> EllipseGeometry:
    """Inverse of :func:`conic_from_ellipse`; raises ``ValueError`` if ``q`` is not a real ellipse.

    Closed form for the 2x2 block ``A = [[a, b], [b, c]]``: centre ``-A^-1 (d, e)``; with
    ``k = -(f + (d, e) . centre)``, the eigenvalues of ``A / k`` are ``1 / semi-axis^2``.
    """
    q = np.asarray(q, dtype=float)
    a, b, c = float(q[0, 0]), float(q[0, 1]), float(q[1, 1])
    d, e, f = float(q[0, 2]), float(q[1, 2]), float(q[2, 2])
    det = a * c - b * b
    if det <= 0.0:
        raise ValueError("conic is not an ellipse")
    cu, cv = (b * e - c * d) / det, (b * d - a * e) / det
    k = -(f + d * cu + e * cv)  # value so that (x-c)^T A (x-c) = k
    mean, half_gap = 0.5 * (a + c), math.hypot(0.5 * (a - c), b)
    w_small, w_large = (mean - half_gap) / k, (mean + half_gap) / k
    if k == 0.0 or min(w_small, w_large) <= 0.0:
        raise ValueError("conic is an imaginary ellipse")
    # smallest eigenvalue <-> major axis; eigenvector of A for it: (b, l - a) or (l - c, b)
    lam = mean - half_gap if k > 0.0 else mean + half_gap
    vx, vy = (b, lam - a) if abs(a - lam) > abs(c - lam) else (lam - c, b)
    if vx == 0.0 and vy == 0.0:  # a circle: any direction
        vx = 1.0
    return EllipseGeometry(
        center=np.array([cu, cv]),
        semi_major=float(1.0 / math.sqrt(min(w_small, w_large))),
        semi_minor=float(1.0 / math.sqrt(max(w_small, w_large))),
        major_angle_rad=float(math.atan2(vy, vx)),
    )


def is_ellipse(q: ArrayLike) -> FloatArray:
    """Mask of conics ``(..., 3, 3)`` that are real ellipses (definite 2x2 block, real points)."""
    q = np.asarray(q, dtype=float)
    det2 = q[..., 0, 0] * q[..., 1, 1] - q[..., 0, 1] ** 2
    det3 = np.linalg.det(q)
    # Real ellipse: det2 > 0 and det3 has the opposite sign to the trace of the 2x2 block.
    return (det2 > 0.0) & (det3 * (q[..., 0, 0] + q[..., 1, 1]) < 0.0)


def _design(points: FloatArray) -> FloatArray:
    x, y = points[..., 0], points[..., 1]
    return np.stack([x * x, x * y, y * y, x, y, np.ones_like(x)], axis=-1)


def fit_conic_exact(points: ArrayLike) -> FloatArray:
    """Conics through 5 points each: ``(..., 5, 2)`` -> ``(..., 3, 3)`` (null space of the design)."""
    d = _design(np.asarray(points, dtype=float))
    _, _, vt = np.linalg.svd(d, full_matrices=True)
    return conic_matrix(vt[..., -1, :])


def _normalizer(points: FloatArray) -> FloatArray:
    """Similarity ``T`` moving the points' centroid to 0 and their RMS radius to sqrt(2)."""
    mean = points.mean(axis=0)
    rms = math.sqrt(float(np.mean(np.sum((points - mean) ** 2, axis=1)))) or 1.0
    s = math.sqrt(2.0) / rms
    return np.array([[s, 0.0, -s * mean[0]], [0.0, s, -s * mean[1]], [0.0, 0.0, 1.0]])


def _apply(t: FloatArray, points: FloatArray) -> FloatArray:
    return points @ t[:2, :2].T + t[:2, 2]


def fit_ellipse_direct(points: ArrayLike) -> FloatArray:
    """Direct least-squares ellipse fit (Fitzgibbon, paper 002 ref. [24]; Halir-Flusser form).

    Minimizes the algebraic residual subject to ``4ac - b^2 = 1``, so the result is always an
    ellipse. Needs at least 5 points; raises ``ValueError`` when the points are degenerate.
    """
    pts = np.asarray(points, dtype=float)
    if pts.shape[0] < CONIC_SAMPLE_SIZE:
        raise ValueError("need at least 5 points for an ellipse")
    t = _normalizer(pts)
    q = t.T @ _fit_direct_conditioned(_apply(t, pts)) @ t
    return q / np.linalg.norm(q)


def _fit_direct_conditioned(p: FloatArray) -> FloatArray:
    """:func:`fit_ellipse_direct` of points already centred and scaled to about unit size."""
    d = _design(p)
    s = d.T @ d
    s1, s2, s3 = s[:3, :3], s[:3, 3:], s[3:, 3:]
    try:
        tm = -np.linalg.solve(s3, s2.T)
    except np.linalg.LinAlgError:
        raise ValueError("degenerate points for an ellipse fit") from None
    m = s1 + s2 @ tm
    m = np.stack([m[2] / 2.0, -m[1], m[0] / 2.0])
    w, v = np.linalg.eig(m)
    v = np.real(v)
    cond = 4.0 * v[0] * v[2] - v[1] ** 2
    ok = np.flatnonzero(cond > 0.0)
    if ok.size == 0:
        raise ValueError("no ellipse fits these points")
    a1 = v[:, ok[np.argmin(np.abs(np.real(w[ok])))]]
    q = conic_matrix(np.concatenate([a1, tm @ a1]))
    return q / np.linalg.norm(q)


def sampson_distance(q: ArrayLike, points: ArrayLike) -> FloatArray:
    """First-order geometric distance of points ``(N, 2)`` to conics ``(..., 3, 3)`` -> ``(..., N)``.

    ``|p^T Q p| / (2 |(Q p)_{1:2}|)``: the algebraic residual over the gradient's norm.
    """
    q = np.asarray(q, dtype=float)
    pts = np.asarray(points, dtype=float)
    ph = np.concatenate([pts, np.ones((pts.shape[0], 1))], axis=1)
    qp = np.einsum("...ij,nj->...ni", q, ph)
    alg = np.einsum("...ni,ni->...n", qp, ph)
    grad = 2.0 * np.sqrt(qp[..., 0] ** 2 + qp[..., 1] ** 2)
    return np.abs(alg) / np.maximum(grad, 1e-300)


@dataclass(frozen=True)
class RansacEllipse:
    """Result of :func:`ransac_ellipse`: the conic, the inlier mask and the draws used."""

    conic: FloatArray
    inliers: FloatArray
    iterations: int

    @property
    def inlier_ratio(self) -> float:
        return float(np.mean(self.inliers))


def ransac_ellipse(
    points: ArrayLike,
    threshold: float,
    rng: np.random.Generator,
    *,
    p_success: float = 0.99,
    min_iterations: int = 8,
    max_iterations: int = 256,
    batch: int = 16,
) -> RansacEllipse:
    """Robust ellipse through ``points`` (paper 002: adaptive 5-point RANSAC, eq. 35).

    ``threshold`` is the largest Sampson distance of an inlier, in the points' units. Draws come
    in vectorized batches; after each batch the required count ``N`` of eq. 35 is recomputed from
    the best consensus set so far. The winner is refitted by :func:`fit_ellipse_direct` on its
    inliers, and once more if the refitted conic changes the inlier set. Raises ``ValueError`` when
    no ellipse with at least 5 inliers exists.
    """
    pts = np.asarray(points, dtype=float)
    n = pts.shape[0]
    if n < CONIC_SAMPLE_SIZE:
        raise ValueError(f"need at least 5 points, got {n}")
    t = _normalizer(pts)
    p = _apply(t, pts)
    thr = threshold * t[0, 0]
    best_count, best_q = 0, None
    needed, done = float(min_iterations), 0
    while done < min(max(needed, min_iterations), max_iterations):
        idx = np.argpartition(rng.random((batch, n)), CONIC_SAMPLE_SIZE - 1, axis=1)
        q = fit_conic_exact(p[idx[:, :CONIC_SAMPLE_SIZE]])
        counts = np.sum(sampson_distance(q, p) < thr, axis=1)
        counts = np.where(is_ellipse(q), counts, 0)
        k = int(np.argmax(counts))
        done += batch
        if counts[k] > best_count:
            best_count, best_q = int(counts[k]), q[k]
            needed = ransac_iterations(p_success, 1.0 - best_count / n, CONIC_SAMPLE_SIZE)
    if best_q is None or best_count < CONIC_SAMPLE_SIZE:
        raise ValueError("no ellipse found")
    return _refit_on_inliers(p, t, sampson_distance(best_q, p) < thr, thr, done)


def _refit_on_inliers(
    p: FloatArray, t: FloatArray, inliers: FloatArray, thr: float, iterations: int
) -> RansacEllipse:
    """Direct fit on the inliers of normalized points ``p`` (``t`` undoes the normalization),
    once more if the refitted conic changes the inlier set."""
    q_fit = _fit_direct_conditioned(p[inliers])
    new_inliers = sampson_distance(q_fit, p) < thr
    if new_inliers.sum() >= CONIC_SAMPLE_SIZE and not np.array_equal(new_inliers, inliers):
        inliers = new_inliers
        q_fit = _fit_direct_conditioned(p[inliers])
    q_out = t.T @ q_fit @ t
    return RansacEllipse(
        conic=q_out / np.linalg.norm(q_out), inliers=inliers, iterations=iterations
    )


def robust_ellipse(
    points: ArrayLike,
    threshold: float,
    rng: np.random.Generator,
    *,
    direct_inlier_ratio: float = 0.95,
    p_success: float = 0.99,
    max_iterations: int = 256,
) -> RansacEllipse:
    """Ellipse through ``points``: the direct fit when it is already clean, else RANSAC.

    A clean contour (a disc seen whole) needs no random search: the direct least-squares fit
    of all points (Fitzgibbon) leaves at least ``direct_inlier_ratio`` of them within
    ``threshold`` (Sampson distance), and is then refitted on its inliers exactly as the last
    step of :func:`ransac_ellipse` (``iterations = 0``). Otherwise (occlusion, a blob merged
    with something of the same colour) the adaptive 5-point RANSAC of paper 002 (eq. 35) runs.
    Same result as :func:`ransac_ellipse` up to the random draws when there are no outliers;
    raises ``ValueError`` as it does.
    """
    pts = np.asarray(points, dtype=float)
    if pts.shape[0] < CONIC_SAMPLE_SIZE:
        raise ValueError(f"need at least 5 points, got {pts.shape[0]}")
    t = _normalizer(pts)
    p = _apply(t, pts)
    thr = threshold * t[0, 0]
    try:
        q = _fit_direct_conditioned(p)
    except ValueError:
        q = None
    if q is not None:
        inliers = sampson_distance(q, p) < thr
        if inliers.all():  # the refit on the inliers would be this very fit
            q_out = t.T @ q @ t
            return RansacEllipse(conic=q_out / np.linalg.norm(q_out), inliers=inliers, iterations=0)
        if float(np.mean(inliers)) >= direct_inlier_ratio:
            return _refit_on_inliers(p, t, inliers, thr, 0)
    return ransac_ellipse(pts, threshold, rng, p_success=p_success, max_iterations=max_iterations)


def circle_conic(center_cam: ArrayLike, normal_cam: ArrayLike, radius: float) -> FloatArray:
    """Forward model: normalized-image conic of a circle (centre, unit normal, radius) in the
    camera frame. The circle's plane maps to the image by ``H = [u v c]`` (``u, v`` an orthonormal
    basis of the plane), so ``Q = H^-T diag(1, 1, -r^2) H^-1``. Used by tests and for checks."""
    c = np.asarray(center_cam, dtype=float)
    nrm = np.asarray(normal_cam, dtype=float)
    nrm = nrm / np.linalg.norm(nrm)
    helper = np.eye(3)[int(np.argmin(np.abs(nrm)))]
    u = np.cross(nrm, helper)
    u /= np.linalg.norm(u)
    v = np.cross(nrm, u)
    h_inv = np.linalg.inv(np.stack([u, v, c], axis=1))
    q = h_inv.T @ np.diag([1.0, 1.0, -radius * radius]) @ h_inv
    return q / np.linalg.norm(q)


def disc_poses_from_conic(q: ArrayLike, radius: float) -> tuple[FloatArray, FloatArray]:
    """Both candidate (centre, normal) pairs of a disc of ``radius`` imaged as the normalized conic
    ``q`` (paper 002 eq. 33-34, with the eigenvector indexing fixed as in the module docstring).

    Returns ``centers (2, 3)`` (camera frame, ``z > 0``) and unit ``normals (2, 3)`` pointing
    toward the camera (``n . c < 0``). Raises ``ValueError`` if ``q`` is not the conic of an ellipse.
    """
    q = np.asarray(q, dtype=float)
    q = 0.5 * (q + q.T)
    w, v = np.linalg.eigh(q)
    if np.sum(w > 0.0) == 1:
        w, v = -w[::-1], v[:, ::-1]
    if not (w[0] < 0.0 < w[1] <= w[2]):
        raise ValueError("conic does not have the signature of an imaged circle")
    l2, l0, l1 = w
    q2, q1 = v[:, 0], v[:, 2]
    a = math.sqrt((l1 - l0) / (l1 - l2))
    b = math.sqrt((l0 - l2) / (l1 - l2))
    signs = np.array([1.0, -1.0])[:, None]
    normals = a * q1[None, :] + signs * b * q2[None, :]
    centers = radius / math.sqrt(-l1 * l2) * (l2 * a * q1[None, :] + signs * l1 * b * q2[None, :])
    centers *= np.where(centers[:, 2:3] < 0.0, -1.0, 1.0)
    normals *= np.where(np.sum(normals * centers, axis=1, keepdims=True) > 0.0, -1.0, 1.0)
    return centers, normals / np.linalg.norm(normals, axis=1, keepdims=True)
