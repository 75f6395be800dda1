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
then costs one fit instead of hundreds of hypotheses); :func:`robust_ellipses` does it for several
point sets with shared numpy calls.

Numpy, vectorized over hypotheses; the 3x3 solves go through OpenCV (``cv2.solve``, ``cv2.eigen``,
``cv2.eigenNonSymmetric``), whose call overhead is a fraction of ``numpy.linalg``'s.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import FloatArray

CONIC_SAMPLE_SIZE = 5
# Q = [[a, b/2, d/2], [b/2, c, e/2], [d/2, e/2, f]] from (a, b, c, d, e, f), row by row.
_CONIC_INDEX = np.array([0, 1, 3, 1, 2, 4, 3, 4, 5])
_CONIC_SCALE = np.array([1.0, 0.5, 0.5, 0.5, 1.0, 0.5, 0.5, 0.5, 1.0])
_QUAD_I, _QUAD_J = [0, 0, 1], [0, 1, 1]  # x^2, xy, y^2
# Rows of C1^-1 M for the constraint 4ac - b^2 (Halir-Flusser), applied to M's reversed rows.
_INV_C1_DIAG = np.array([[0.5], [-1.0], [0.5]])


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
    return _normalized(points)[0]


def _normalized(points: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``(T, T applied to points)`` for :func:`_normalizer`'s ``T`` (the points ``(N, 2)``)."""
    mean = np.add.reduce(points, axis=0) / points.shape[0]
    dev = points - mean
    rms = math.sqrt(float(np.vdot(dev, dev)) / points.shape[0]) or 1.0
    s = math.sqrt(2.0) / rms
    mu, mv = float(mean[0]), float(mean[1])
    t = np.array([[s, 0.0, -s * mu], [0.0, s, -s * mv], [0.0, 0.0, 1.0]])
    return t, dev * s


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
    return _fit_direct_design(_design_2d(p))


def _design_2d(p: FloatArray) -> FloatArray:
    """:func:`_design` of points ``(N, 2)`` (rows ``x^2, xy, y^2, x, y, 1``), in fewer calls."""
    d = np.ones((p.shape[0], 6))
    d[:, :3] = p[:, _QUAD_I] * p[:, _QUAD_J]
    d[:, 3:5] = p
    return d


def _fit_direct_design(d: FloatArray) -> FloatArray:
    """Halir-Flusser direct ellipse fit from the design matrix ``d`` (rows of :func:`_design`)
    of conditioned points; the unit-norm conic."""
    return _fit_direct_scatter(d.T @ d)


def _fit_direct_scatter(s: FloatArray) -> FloatArray:
    """Halir-Flusser direct ellipse fit (Fitzgibbon, paper 002 ref. [24]) from the scatter
    matrix ``s = d^T d`` (6 x 6) of conditioned points; the unit-norm conic with a positive
    2x2 block."""
    ok, sol = cv2.solve(s[3:, 3:], s[3:, :3], flags=cv2.DECOMP_LU)
    if not ok:
        raise ValueError("degenerate points for an ellipse fit")
    tm = -sol
    m = (s[:3, :3] + s[:3, 3:] @ tm)[::-1] * _INV_C1_DIAG
    # M = C1^-1 R with R (reduced scatter) positive semi-definite: its eigenvalues are real
    # (those of R^-1 C1 inverted), so the real-only solver suffices; vectors come as rows.
    w, v = cv2.eigenNonSymmetric(m)
    vr = v.tolist()
    wr = np.abs(w).ravel().tolist()
    # the ellipse is the eigenvector with 4ac - b^2 > 0 (of smallest |eigenvalue| if several)
    cands = [k for k in range(3) if 4.0 * vr[k][0] * vr[k][2] - vr[k][1] ** 2 > 0.0]
    if not cands:
        raise ValueError("no ellipse fits these points")
    a1 = vr[min(cands, key=lambda k: wr[k])]
    a, b, c = a1
    dd, e, f = (tm @ np.array(a1)).tolist()
    norm = math.sqrt(a * a + c * c + f * f + 0.5 * (b * b + dd * dd + e * e))
    norm = norm if a + c > 0.0 else -norm  # sign: positive 2x2 block (the solver's is arbitrary)
    return np.array([[a, 0.5 * b, 0.5 * dd], [0.5 * b, c, 0.5 * e], [0.5 * dd, 0.5 * e, f]]) / norm


def _sampson_design(q: FloatArray, p: FloatArray, d: FloatArray) -> FloatArray:
    """:func:`sampson_distance` of one conic ``q`` to points ``p (N, 2)`` whose design matrix
    ``d`` is known (the algebraic residual is then one product)."""
    coef = np.array([q[0, 0], 2.0 * q[0, 1], q[1, 1], 2.0 * q[0, 2], 2.0 * q[1, 2], q[2, 2]])
    g = p @ q[:2, :2] + q[2, :2]  # half the gradient
    return np.abs(d @ coef) / np.maximum(2.0 * np.hypot(g[:, 0], g[:, 1]), 1e-300)


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
        return np.count_nonzero(self.inliers) / max(self.inliers.size, 1)


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
    t, p = _normalized(pts)
    thr = threshold * t[0, 0]
    d = _design_2d(p)
    try:
        q = _fit_direct_design(d)
    except ValueError:
        q = None
    if q is not None:
        inliers = _sampson_design(q, p, d) < thr
        if inliers.all():  # the refit on the inliers would be this very fit
            q_out = t.T @ q @ t
            return RansacEllipse(conic=q_out / np.linalg.norm(q_out), inliers=inliers, iterations=0)
        if float(np.mean(inliers)) >= direct_inlier_ratio:
            return _refit_on_inliers(p, t, inliers, thr, 0)
    return ransac_ellipse(pts, threshold, rng, p_success=p_success, max_iterations=max_iterations)


def robust_ellipses(
    point_sets: Sequence[FloatArray],
    threshold: float,
    rng: np.random.Generator,
    *,
    direct_inlier_ratio: float = 0.95,
    p_success: float = 0.99,
    max_iterations: int = 256,
) -> list[RansacEllipse | None]:
    """:func:`robust_ellipse` of each point set ``(N_k, 2)``, ``None`` where it raises (paper
    002: the direct fit of ref. [24], adaptive RANSAC of eq. 35 where it leaves outliers).

    The conditioning, design matrices, scatter matrices and Sampson distances of all the sets
    are computed together (a few numpy calls for all instead of for each: the per-call cost
    dominates at a few hundred points); each set's direct fit is then solved from its scatter
    matrix, and a set left with too many outliers goes on alone (refit or RANSAC, in order,
    drawing from ``rng``). Same results as :func:`robust_ellipse` up to rounding.
    """
    out: list[RansacEllipse | None] = [None] * len(point_sets)
    todo = [k for k, pts in enumerate(point_sets) if len(pts) >= CONIC_SAMPLE_SIZE]
    if not todo:
        return out
    sizes = np.array([len(point_sets[k]) for k in todo])
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    seg = np.repeat(np.arange(len(todo)), sizes)
    pts = np.concatenate([np.asarray(point_sets[k], dtype=float) for k in todo])
    # conditioning of each set (as _normalized): centroid to 0, RMS radius to sqrt(2)
    mean = np.add.reduceat(pts, starts, axis=0) / sizes[:, None]
    dev = pts - mean[seg]
    rms = np.sqrt(np.add.reduceat(np.einsum("ij,ij->i", dev, dev), starts) / sizes)
    scale = math.sqrt(2.0) / np.where(rms > 0.0, rms, 1.0)
    p = dev * scale[seg][:, None]
    d = _design_2d(p)
    scatter = np.add.reduceat(d[:, :, None] * d[:, None, :], starts, axis=0)
    conics = np.zeros((len(todo), 3, 3))
    fitted = np.zeros(len(todo), dtype=bool)
    for j, s_j in enumerate(scatter):
        try:
            conics[j] = _fit_direct_scatter(s_j)
            fitted[j] = True
        except ValueError:
            pass
    # Sampson distance of every point to its own set's conic (as _sampson_design)
    q = conics[seg]
    coef = np.stack(
        [q[:, 0, 0], 2.0 * q[:, 0, 1], q[:, 1, 1], 2.0 * q[:, 0, 2], 2.0 * q[:, 1, 2], q[:, 2, 2]],
        axis=1,
    )
    g = np.einsum("ni,nij->nj", p, q[:, :2, :2]) + q[:, 2, :2]
    dist = np.abs(np.einsum("ij,ij->i", d, coef)) / np.maximum(
        2.0 * np.hypot(g[:, 0], g[:, 1]), 1e-300
    )
    thr = threshold * scale
    inliers = dist < thr[seg]
    counts = np.add.reduceat(inliers, starts)
    for j, k in enumerate(todo):
        s = float(scale[j])
        mu, mv = float(mean[j, 0]), float(mean[j, 1])
        t = np.array([[s, 0.0, -s * mu], [0.0, s, -s * mv], [0.0, 0.0, 1.0]])
        lo, hi = int(starts[j]), int(starts[j] + sizes[j])
        try:
            if fitted[j] and counts[j] == sizes[j]:
                q_out = t.T @ conics[j] @ t
                out[k] = RansacEllipse(
                    conic=q_out / np.linalg.norm(q_out), inliers=inliers[lo:hi], iterations=0
                )
            elif fitted[j] and counts[j] / sizes[j] >= direct_inlier_ratio:
                out[k] = _refit_on_inliers(p[lo:hi], t, inliers[lo:hi], float(thr[j]), 0)
            else:
                out[k] = ransac_ellipse(
                    point_sets[k],
                    threshold,
                    rng,
                    p_success=p_success,
                    max_iterations=max_iterations,
                )
        except ValueError:
            out[k] = None
    return out


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
    ok, w_desc, v_rows = cv2.eigen(0.5 * (q + q.T))  # eigenvalues descending, vectors as rows
    if not ok:
        raise ValueError("eigen-decomposition failed")
    w = w_desc.ravel()[::-1].tolist()  # ascending, as numpy's eigh
    vecs = v_rows[::-1].tolist()
    if sum(x > 0.0 for x in w) == 1:
        w, vecs = [-x for x in w[::-1]], vecs[::-1]
    if not (w[0] < 0.0 < w[1] <= w[2]):
        raise ValueError("conic does not have the signature of an imaged circle")
    l2, l0, l1 = w
    q2, q1 = vecs[0], vecs[2]
    a = math.sqrt((l1 - l0) / (l1 - l2))
    b = math.sqrt((l0 - l2) / (l1 - l2))
    k = radius / math.sqrt(-l1 * l2)
    centers, normals = [], []
    for sign in (1.0, -1.0):
        c = [k * (l2 * a * u + sign * l1 * b * v) for u, v in zip(q1, q2, strict=True)]
        n = [a * u + sign * b * v for u, v in zip(q1, q2, strict=True)]
        if c[2] < 0.0:
            c = [-x for x in c]
        n_len = math.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
        if n[0] * c[0] + n[1] * c[1] + n[2] * c[2] > 0.0:
            n_len = -n_len
        centers.append(c)
        normals.append([x / n_len for x in n])
    return np.array(centers), np.array(normals)
