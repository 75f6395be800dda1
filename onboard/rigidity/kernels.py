"""Paper 003's star formulas, eigen-estimate and actions as pure loops over small arrays.

One implementation of each formula (the project guide): the rigidity layer of the agent core
(:mod:`onboard.estimation.star_rigidity`, :mod:`onboard.estimation.distributed_eigen`,
:mod:`onboard.core.rigidity`, :mod:`onboard.control.rigidity`) calls these functions as plain
Python, and the compiled team engine (:mod:`sim.rigidity_kernel`) calls the same functions
compiled by :func:`sim.jit.compiled`. They are written in the subset of Python numba compiles
(loops, ``math``, ``numpy`` allocation; no numba import here: the daemons run without numba):
arrays in, arrays out, no state. Loops, not numpy expressions: at these sizes (``M <= 5``
neighbours, ``k = 3`` columns, 7x7 and 3x3 Ritz problems) a compiled loop is ten times faster
than a BLAS or LAPACK call, and the engines then agree to the last bit.

Notation (docs/equations.md, "Angle rigidity"; paper 003 of docs/papers.md): agent ``i`` and its
``M`` neighbours; ``b`` ``(M, 3)`` unit bearings, ``d`` ``(M,)`` distances, ``cosm`` ``(M, M)``
their cosines ``C_jk``, ``h`` ``(M,)`` and ``w`` ``(M, M)`` the sensing weights ``W_jk = h_j h_k``
(0 on the diagonal), ``V`` blocks ``(3, k)``. Row 0 of every ``(M + 1, ...)`` result is agent
``i``'s own block. The derivations are in :mod:`onboard.estimation.star_rigidity`'s docstring.
"""

from __future__ import annotations

import math

import numpy as np

N_TRIVIAL = 7
"""Columns of the trivial-motion basis ``T_i`` (3 translations, 3 rotations, scaling; eq. 4)."""
TT_RCOND = 1e-9
"""``T^T T / N`` whose LU pivots span more than this ratio is singular: fewer than three agents
are in the average yet (an agent's first round averages its own ``T_i^T T_i``, of rank 3), and
the trivial coefficients are not defined. Solved anyway, its round-off-sized pivots gave
coefficients of any size, which kicked ``V`` by ``k_t T_i coef`` (and made the first rounds
depend on the last bit of ``T_i``)."""
RITZ_RCOND = 1e-6
"""Directions of ``G'`` below this fraction of its largest eigenvalue are left out of the Ritz
problem (the columns of ``V`` have (nearly) collapsed onto each other or onto trivial motions)."""
BLEND_FLOOR = 1e-3
"""Modes whose smooth-minimum weight is below this are left out of the blended gradient (the
others' weights renormalized): a mode 0.07 above the smallest, at the default temperature."""
BARRIER_FLOOR = 1e-3
"""Fraction of ``x_safe - x_min`` above ``x_min`` where the barrier's slope saturates."""


def cubic_step(x, x_one, width):
    """The C^1 smooth step of :func:`onboard.rigidity.weights.smooth_step` at one value ``x``:
    ``(value, slope)``, 1 below ``x_one``, 0 beyond ``x_one + width`` (paper 003 eq. 17-18).
    ``width == 0`` means no roll-off (an unlimited range, an all-round camera): ``(1, 0)``."""
    if width == 0.0:
        return 1.0, 0.0
    t = (x - x_one) / width
    t = min(max(t, 0.0), 1.0)
    return 1.0 - t * t * (3.0 - 2.0 * t), -6.0 * t * (1.0 - t) / width


def star(p_i, yaw, p_nbr, range_one, range_width, fov_one, fov_width):
    """:func:`onboard.estimation.star_rigidity.star`: ``(r, d, b, cos, h, w, dh_dr, dh_dyaw)``
    for ``M`` neighbours ``p_nbr`` ``(M, 3)``."""
    m = p_nbr.shape[0]
    r = np.empty((m, 3))
    d = np.empty(m)
    b = np.empty((m, 3))
    ca, sa = math.cos(yaw), math.sin(yaw)
    h = np.empty(m)
    dh_dr = np.empty((m, 3))
    dh_dyaw = np.empty(m)
    for j in range(m):
        for c in range(3):
            r[j, c] = p_nbr[j, c] - p_i[c]
        d[j] = math.sqrt(r[j, 0] * r[j, 0] + r[j, 1] * r[j, 1] + r[j, 2] * r[j, 2])
        if not (d[j] > 0.0 and d[j] < np.inf):
            raise ValueError("a neighbour estimate coincides with the agent's (or is not finite)")
        for c in range(3):
            b[j, c] = r[j, c] / d[j]
        cos_axis = b[j, 0] * ca + b[j, 1] * sa + b[j, 2] * 0.0
        w_r, dw_r = cubic_step(d[j], range_one, range_width)
        w_f, dw_f = cubic_step(cos_axis, fov_one, fov_width)
        k1 = (dw_r * d[j] + w_r) * w_f
        k2 = w_r * dw_f
        dh_dr[j, 0] = k1 * b[j, 0] + k2 * (ca - cos_axis * b[j, 0])
        dh_dr[j, 1] = k1 * b[j, 1] + k2 * (sa - cos_axis * b[j, 1])
        dh_dr[j, 2] = k1 * b[j, 2] + k2 * (0.0 - cos_axis * b[j, 2])
        h[j] = w_r * w_f * d[j]
        dh_dyaw[j] = w_r * dw_f * d[j] * (b[j, 0] * -sa + b[j, 1] * ca + b[j, 2] * 0.0)
    cosm = np.empty((m, m))
    w = np.zeros((m, m))
    for j in range(m):
        for k in range(m):
            cosm[j, k] = b[j, 0] * b[k, 0] + b[j, 1] * b[k, 1] + b[j, 2] * b[k, 2]
            if j != k:
                w[j, k] = h[j] * h[k]
    return r, d, b, cosm, h, w, dh_dr, dh_dyaw


def with_own(rows):
    """:func:`onboard.estimation.star_rigidity._with_own`: ``-sum rows`` on top ``(M + 1, 3)``."""
    m = rows.shape[0]
    out = np.zeros((m + 1, 3))
    for j in range(m):
        for c in range(3):
            out[0, c] += rows[j, c]
            out[j + 1, c] = rows[j, c]
    for c in range(3):
        out[0, c] = -out[0, c]
    return out


def row_sums(b, d, cosm, coef):
    """:func:`onboard.estimation.star_rigidity._row_sums`: ``sum_k coef_jk R_jk`` ``(M, 3)``."""
    m = b.shape[0]
    out = np.empty((m, 3))
    for j in range(m):
        s = 0.0
        for k in range(m):
            s += coef[j, k] * cosm[j, k]
        for c in range(3):
            acc = 0.0
            for k in range(m):
                acc += coef[j, k] * b[k, c]
            out[j, c] = (acc - s * b[j, c]) / d[j]
    return out


def angle_gradient(b, d, cosm, beta, k_angle):
    """Angle-localization terms ``k_A sum_a (f_a(phat) - f_a)^2`` of the star and their gradient
    ``(value, grad (M + 1, 3))`` (paper 003 eq. 10-11); ``beta`` ``(M, 3)`` are the measured
    unit bearings (body frame: angles are frame-free)."""
    m = b.shape[0]
    if m < 2:
        return 0.0, np.zeros((m + 1, 3))
    e = np.zeros((m, m))
    sq = 0.0
    for j in range(m):
        for k in range(m):
            if j != k:
                e[j, k] = cosm[j, k] - (
                    beta[j, 0] * beta[k, 0] + beta[j, 1] * beta[k, 1] + beta[j, 2] * beta[k, 2]
                )
                sq += e[j, k] * e[j, k]
    rows = row_sums(b, d, cosm, e)
    g = 2.0 * k_angle
    for j in range(m):
        for c in range(3):
            rows[j, c] = g * rows[j, c]
    return 0.5 * k_angle * sq, with_own(rows)


def vertical_gradient(b, d, beta, k_vertical):
    """Gravity term ``k_z sum_j (b_j . e3 - beta_j . e3)^2`` and its gradient ``(value, grad
    (M + 1, 3))`` (as :func:`onboard.estimation.angle_localization.local_vertical_gradient`)."""
    m = b.shape[0]
    rows = np.empty((m, 3))
    sq = 0.0
    for j in range(m):
        e = b[j, 2] - beta[j, 2]
        sq += e * e
        g = 2.0 * k_vertical * e
        for c in range(3):
            rows[j, c] = g * (((1.0 if c == 2 else 0.0) - b[j, 2] * b[j, c]) / d[j])
    return k_vertical * sq, with_own(rows)


def weighted_matvec(b, d, cosm, w, v_own, v_nbr):
    """:func:`onboard.estimation.star_rigidity.weighted_matvec`: the star's part of ``M_w V``
    (paper 003 eq. 16), ``v_own`` ``(3, k)``, ``v_nbr`` ``(M, 3, k)`` -> ``(M + 1, 3, k)``."""
    m = b.shape[0]
    kk = v_own.shape[1]
    out = np.zeros((m + 1, 3, kk))
    if m < 2:
        return out
    delta = np.empty((m, 3))
    a = np.empty(m)
    g1 = np.empty((m, m))
    rows = np.empty((m, 3))
    for col in range(kk):
        for j in range(m):
            for c in range(3):
                delta[j, c] = v_nbr[j, c, col] - v_own[c, col]
            a[j] = delta[j, 0] * b[j, 0] + delta[j, 1] * b[j, 1] + delta[j, 2] * b[j, 2]
        for j in range(m):
            for k in range(m):
                dk = delta[j, 0] * b[k, 0] + delta[j, 1] * b[k, 1] + delta[j, 2] * b[k, 2]
                g1[j, k] = (dk - cosm[j, k] * a[j]) / d[j]
        for j in range(m):
            s = 0.0
            acc0 = 0.0
            acc1 = 0.0
            acc2 = 0.0
            for k in range(m):
                q = w[j, k] * (g1[j, k] + g1[k, j])
                acc0 += q * b[k, 0]
                acc1 += q * b[k, 1]
                acc2 += q * b[k, 2]
                s += q * cosm[j, k]
            rows[j, 0] = (acc0 - s * b[j, 0]) / d[j]
            rows[j, 1] = (acc1 - s * b[j, 1]) / d[j]
            rows[j, 2] = (acc2 - s * b[j, 2]) / d[j]
        for j in range(m):
            for c in range(3):
                out[0, c, col] += rows[j, c]
                out[j + 1, c, col] = rows[j, c]
        for c in range(3):
            out[0, c, col] = -out[0, c, col]
    return out


def weighted_degree(d, cosm, w):
    """:func:`onboard.estimation.star_rigidity.weighted_degree` ``(M + 1,)``, own first."""
    m = d.shape[0]
    out = np.zeros(m + 1)
    total = 0.0
    for j in range(m):
        s = 0.0
        for k in range(m):
            c = cosm[j, k]
            ij = 1.0 / d[j]
            ik = 1.0 / d[k]
            r2 = 2.0 * (1.0 - c * c) * (ij * ij + ik * ik - c * (ij * ik))
            s += w[j, k] * r2
        out[j + 1] = s
        total += s
    out[0] = 0.5 * total
    return out


def form_gradient_only(b, d, cosm, h, w, dh_dr, dh_dyaw, v_own, v_nbr):
    """:func:`onboard.estimation.star_rigidity.form_gradient_only`: ``(grad_p (M + 1, 3),
    d/dpsi_i)`` of the star's ``v^T M_w v`` at fixed ``v`` (paper 003 eq. 21)."""
    m = b.shape[0]
    if m < 2:
        return np.zeros((m + 1, 3)), 0.0
    delta = np.empty((m, 3))
    a = np.empty(m)
    for j in range(m):
        for c in range(3):
            delta[j, c] = v_nbr[j, c] - v_own[c]
        a[j] = delta[j, 0] * b[j, 0] + delta[j, 1] * b[j, 1] + delta[j, 2] * b[j, 2]
    g1 = np.empty((m, m))
    for j in range(m):
        for k in range(m):
            dk = delta[j, 0] * b[k, 0] + delta[j, 1] * b[k, 1] + delta[j, 2] * b[k, 2]
            g1[j, k] = (dk - cosm[j, k] * a[j]) / d[j]
    g = np.empty((m, m))
    bq = np.empty((m, m))
    for j in range(m):
        for k in range(m):
            g[j, k] = g1[j, k] + g1[k, j]
            bq[j, k] = 2.0 * (w[j, k] * g[j, k])
    pd = np.empty((m, 3))
    for j in range(m):
        for c in range(3):
            pd[j, c] = delta[j, c] - a[j] * b[j, c]
    e = np.empty((m, m))
    for j in range(m):
        for k in range(m):
            e[j, k] = pd[j, 0] * b[k, 0] + pd[j, 1] * b[k, 1] + pd[j, 2] * b[k, 2]
    grad_r = np.empty((m, 3))
    grad_yaw = 0.0
    for j in range(m):
        coef = 0.0
        qc = 0.0
        qe = 0.0
        qet = 0.0
        for k in range(m):
            if k != j:
                coef += g[j, k] * g[j, k] * h[k]
            qc += bq[j, k] * cosm[j, k]
            qe += bq[j, k] * e[j, k]
            qet += bq[j, k] * e[k, j] * (1.0 / d[k])
        inv_d = 1.0 / d[j]
        inv_d2 = inv_d * inv_d
        for c in range(3):
            qb = 0.0
            qpd = 0.0
            for k in range(m):
                qb += bq[j, k] * b[k, c]
                qpd += bq[j, k] * (pd[k, c] * (1.0 / d[k]))
            grad_r[j, c] = (
                -(a[j] * inv_d) * ((qb - qc * b[j, c]) / d[j])
                - (qe * inv_d2) * b[j, c]
                - (qc * inv_d2) * pd[j, c]
                + inv_d * (qpd - qet * b[j, c])
                + coef * dh_dr[j, c]
            )
        grad_yaw += coef * dh_dyaw[j]
    return with_own(grad_r), grad_yaw


def mm(a, b):
    """``a @ b`` for small matrices, summed by a loop (BLAS's call costs more than the work)."""
    n, m = a.shape
    p = b.shape[1]
    out = np.zeros((n, p))
    for i in range(n):
        for q in range(m):
            x = a[i, q]
            for j in range(p):
                out[i, j] += x * b[q, j]
    return out


def mm_tn(a, b):
    """``a.T @ b`` for small matrices, summed by a loop."""
    m, n = a.shape
    p = b.shape[1]
    out = np.zeros((n, p))
    for q in range(m):
        for i in range(n):
            x = a[q, i]
            for j in range(p):
                out[i, j] += x * b[q, j]
    return out


def lu_solve(a, b):
    """``(pivots |diag U| (n,), x (n, k))`` of ``a x = b`` by LU with partial pivoting (LAPACK's
    ``dgesv`` algorithm, for a 7x7 system, without its call overhead). A zero pivot gives a
    zero in ``pivots`` and a ``nan`` ``x``."""
    n = a.shape[0]
    kk = b.shape[1]
    lu = a.copy()
    x = b.copy()
    piv = np.empty(n)
    for c in range(n):
        best = c
        for r in range(c + 1, n):
            if abs(lu[r, c]) > abs(lu[best, c]):
                best = r
        if best != c:
            for q in range(n):
                lu[c, q], lu[best, q] = lu[best, q], lu[c, q]
            for q in range(kk):
                x[c, q], x[best, q] = x[best, q], x[c, q]
        pivot = lu[c, c]
        piv[c] = abs(pivot)
        if pivot == 0.0:  # singular: no solution (and no division by zero in either engine)
            x[:, :] = np.nan
            piv[c + 1 :] = 0.0
            return piv, x
        for r in range(c + 1, n):
            f = lu[r, c] / pivot
            lu[r, c] = f
            for q in range(c + 1, n):
                lu[r, q] -= f * lu[c, q]
            for q in range(kk):
                x[r, q] -= f * x[c, q]
    for c in range(n - 1, -1, -1):
        for q in range(kk):
            acc = x[c, q]
            for r in range(c + 1, n):
                acc -= lu[c, r] * x[r, q]
            x[c, q] = acc / lu[c, c]
    return piv, x


def sym_eig(a):
    """Eigenvalues ascending ``(n,)`` and eigenvectors (columns) of the symmetric matrix whose
    upper triangle is ``a``'s (LAPACK's ``dsyevd`` convention), by cyclic Jacobi rotations: for
    the 3x3 Ritz problems of the eigen-estimate, a tenth of a LAPACK call. Eigenvectors are
    defined up to sign (every use of them here is sign-free)."""
    n = a.shape[0]
    m = np.empty((n, n))
    for i in range(n):
        for j in range(i, n):
            m[i, j] = a[i, j]
            m[j, i] = a[i, j]
    v = np.eye(n)
    for _ in range(60):
        off = 0.0
        scale = 0.0
        for i in range(n):
            scale += m[i, i] * m[i, i]
            for j in range(i + 1, n):
                off += m[i, j] * m[i, j]
        if not off > 1e-30 * scale:  # converged (or not finite)
            break
        for p in range(n - 1):
            for q in range(p + 1, n):
                if m[p, q] == 0.0:
                    continue
                theta = (m[q, q] - m[p, p]) / (2.0 * m[p, q])
                t = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                for r in range(n):
                    mrp, mrq = m[r, p], m[r, q]
                    m[r, p] = c * mrp - s * mrq
                    m[r, q] = s * mrp + c * mrq
                for r in range(n):
                    mpr, mqr = m[p, r], m[q, r]
                    m[p, r] = c * mpr - s * mqr
                    m[q, r] = s * mpr + c * mqr
                m[p, q] = 0.0  # what the rotation is for (it leaves round-off there)
                m[q, p] = 0.0
                for r in range(n):
                    vrp, vrq = v[r, p], v[r, q]
                    v[r, p] = c * vrp - s * vrq
                    v[r, q] = s * vrp + c * vrq
    w = np.empty(n)
    for i in range(n):
        w[i] = m[i, i]
    order = np.argsort(w)
    return w[order], v[:, order].copy()


def ritz_blocks(p_own, v_own, p_nbr, v_nbr, coef, c_ritz, r):
    """:meth:`onboard.estimation.distributed_eigen.DistributedEigenEstimator.ritz_blocks`:
    ``y_jm = (V_j - T_j coef) c_m`` ``(M + 1, 3, r)`` for the agent (row 0) and its ``M``
    neighbours, ``T_j`` from the positions."""
    m_n = p_nbr.shape[0]
    kk = v_own.shape[1]
    out = np.zeros((m_n + 1, 3, r))
    res = np.empty((3, kk))
    for q in range(m_n + 1):
        t = trivial_block(p_own if q == 0 else p_nbr[q - 1])
        for c in range(3):
            for col in range(kk):
                acc = 0.0
                for a in range(N_TRIVIAL):
                    acc += t[c, a] * coef[a, col]
                res[c, col] = (v_own[c, col] if q == 0 else v_nbr[q - 1, c, col]) - acc
        for c in range(3):
            for m in range(r):
                acc = 0.0
                for col in range(kk):
                    acc += res[c, col] * c_ritz[col, m]
                out[q, c, m] = acc
    return out


def trivial_block(p):
    """:func:`onboard.estimation.distributed_eigen.trivial_motion_block`: ``T_i`` ``(3, 7)``."""
    x, y, z = p[0], p[1], p[2]
    t = np.zeros((3, 7))
    t[0, 0] = 1.0
    t[1, 1] = 1.0
    t[2, 2] = 1.0
    t[0, 4] = z
    t[0, 5] = -y
    t[0, 6] = x
    t[1, 3] = -z
    t[1, 5] = x
    t[1, 6] = y
    t[2, 3] = y
    t[2, 4] = -x
    t[2, 6] = z
    return t


def consensus_input(t_i, v, mv):
    """:func:`onboard.estimation.distributed_eigen.consensus_input` ``(n_c,)``."""
    kk = v.shape[1]
    out = np.empty(N_TRIVIAL * kk + 28 + kk * (kk + 1))
    n = 0
    tv = mm_tn(t_i, v)
    for a in range(N_TRIVIAL):
        for c in range(kk):
            out[n] = tv[a, c]
            n += 1
    tt = mm_tn(t_i, t_i)
    for a in range(N_TRIVIAL):
        for c in range(a, N_TRIVIAL):
            out[n] = tt[a, c]
            n += 1
    vv = mm_tn(v, v)
    for a in range(kk):
        for c in range(a, kk):
            out[n] = vv[a, c]
            n += 1
    vmv = mm_tn(v, mv)
    for a in range(kk):
        for c in range(a, kk):
            out[n] = 0.5 * (vmv[a, c] + vmv[c, a])
            n += 1
    return out


def unpack_sym(x, start, k):
    """The symmetric ``(k, k)`` matrix packed (upper triangle, row-major) at ``x[start:]``."""
    out = np.empty((k, k))
    n = start
    for a in range(k):
        for c in range(a, k):
            out[a, c] = x[n]
            out[c, a] = x[n]
            n += 1
    return out


def ritz(x, kk):
    """:func:`onboard.estimation.distributed_eigen.ritz` on the packed averages ``x``:
    ``(theta (r,), c (k, r), coef (7, k))``."""
    tv = np.empty((N_TRIVIAL, kk))
    for a in range(N_TRIVIAL):
        for c in range(kk):
            tv[a, c] = x[a * kk + c]
    b0 = N_TRIVIAL * kk
    b1 = b0 + 28
    b2 = b1 + kk * (kk + 1) // 2
    tt = unpack_sym(x, b0, N_TRIVIAL)
    vv = unpack_sym(x, b1, kk)
    vmv = unpack_sym(x, b2, kk)
    piv, coef = lu_solve(tt, tv)
    if not (np.all(np.isfinite(coef)) and piv.min() > TT_RCOND * piv.max()):
        coef = np.zeros((N_TRIVIAL, kk))
    g = vv - mm_tn(tv, coef)
    ev, u = sym_eig(g)
    top = ev[-1]
    if not top > 0.0:
        return np.zeros(0), np.zeros((kk, 0)), coef
    keep = np.flatnonzero(ev > RITZ_RCOND * top)
    w_half = np.empty((kk, len(keep)))
    for c, q in enumerate(keep):
        sq = math.sqrt(ev[q])
        for a in range(kk):
            w_half[a, c] = u[a, q] / sq
    theta, s = sym_eig(mm(mm_tn(w_half, vmv), w_half))
    if not np.all(np.isfinite(theta)):
        return np.zeros(0), np.zeros((kk, 0)), coef
    return theta, mm(w_half, s), coef


def fsum(values):
    """``math.fsum`` (Shewchuk's exact partials) of a few floats."""
    partials = np.zeros(len(values) + 1)
    n_p = 0
    for x0 in values:
        x = x0
        i = 0
        for q in range(n_p):
            y = partials[q]
            if abs(x) < abs(y):
                x, y = y, x
            hi = x + y
            lo = y - (hi - x)
            if lo != 0.0:
                partials[i] = lo
                i += 1
            x = hi
        partials[i] = x
        n_p = i + 1
    # the sum of the partials, rounded once (the partials do not overlap)
    total = 0.0
    if n_p > 0:
        n_p -= 1
        total = partials[n_p]
        while n_p > 0:
            x = total
            n_p -= 1
            y = partials[n_p]
            total = x + y
            yr = total - x
            lo = y - yr
            if lo != 0.0:
                if n_p > 0 and (
                    (lo < 0.0 and partials[n_p - 1] < 0.0) or (lo > 0.0 and partials[n_p - 1] > 0.0)
                ):
                    y = lo * 2.0
                    x = total + y
                    yr = x - total
                    if y == yr:
                        total = x
                break
    return total


def blend(theta, tau):
    """:func:`onboard.core.rigidity._blend`: the modes' weights of the smooth minimum
    (:func:`onboard.control.rigidity.softmin_weights`), floored and renormalized ``(r,)``."""
    r = len(theta)
    pi = np.zeros(r)
    if r == 0:
        return pi
    if tau == 0.0:
        pi[np.argmin(theta)] = 1.0
    else:
        low = theta.min()
        e = np.empty(r)
        for m in range(r):
            e[m] = math.exp((low - theta[m]) / tau)
        total = fsum(e)
        for m in range(r):
            pi[m] = e[m] / total
    kept = 0.0
    for m in range(r):
        if pi[m] >= BLEND_FLOOR:
            kept += pi[m]
    out = np.zeros(r)
    for m in range(r):
        if pi[m] >= BLEND_FLOOR:
            out[m] = pi[m] / kept
    return out


def barrier_slope(x, x_min, x_safe, gain):
    """:func:`onboard.control.rigidity.rational_barrier`'s slope ``B'(x)``."""
    c = x_safe - x_min
    xc = min(max(x, x_min + BARRIER_FLOOR * c), x_safe)
    a = x_safe - xc
    b = xc - x_min
    return -gain * a * (a + 2.0 * b) / (c * b * b)


def collision_gradient(p_i, others, r_coll, r_safe, k_coll):
    """:func:`onboard.control.rigidity.collision_potential`'s gradient ``(3,)`` (eq. 30-31)."""
    g = np.zeros(3)
    for j in range(others.shape[0]):
        r0 = others[j, 0] - p_i[0]
        r1 = others[j, 1] - p_i[1]
        r2 = others[j, 2] - p_i[2]
        d = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
        if d == 0.0:
            raise ValueError("coincident positions: collision potential undefined")
        if d < r_safe:
            s = barrier_slope(d, r_coll, r_safe, k_coll)
            g[0] += s * r0 / d
            g[1] += s * r1 / d
            g[2] += s * r2 / d
    return -g
