"""Paper 003's whole team in one compiled loop: the kernel of :mod:`sim.compiled_rigidity`.

:func:`simulate` steps the world of :mod:`sim.runner` and, for every vehicle, what
:class:`onboard.core.agent.AgentCore` with its :class:`onboard.core.rigidity.RigidityLayer` does in
mode ``rigidity-tracking`` (with or without maintenance): angle localization (paper 003 eq.
10-11, :mod:`onboard.estimation.angle_localization`), one round of the distributed subspace
iteration per step (:mod:`onboard.estimation.distributed_eigen`, with the PI and max consensus
of :mod:`onboard.estimation.round_consensus`), the rigidity, collision and tracking actions
(eq. 19-23, 30-33, :mod:`onboard.control.rigidity`), the saturation and the kinematic world.

Each function below is the loop form of the onboard function it names (same equations, same
order of operations where it matters). The two engines agree to round-off, not bit for bit:
matrix products are summed by loops here and by BLAS there, and the Ritz problem's 7x7 solve
and 3x3 symmetric eigenproblems are an LU and Jacobi rotations here, LAPACK there (a LAPACK
call costs ten times the arithmetic of these sizes; the Ritz pairs do not depend on the basis
the eigensolver returns, and the eigenvectors enter only through sign-free quadratic forms).

**Messages**: the payloads a vehicle publishes at step ``k`` go into a ring of ``delay`` slots
(``o_*[slot, sender]``) and reach every other vehicle at step ``k + delay`` (``delay = 1 +
round(latency / dt)``, as :func:`sim.runner.run` delivers), each copy lost when
:func:`sim.draws.lost` says so for ``(k, sender, receiver, kind)`` (the runner's draw, so both
engines lose the same copies). Each receiver keeps the newest of each kind per sender, with its
stamp, as the layer does (``loc_*[receiver, sender]`` with only the receiver's own block of the
per-target parts; ``eig_*[receiver, sender]`` with the slot of the version of the share it
holds, whose content is ``sh_*[sender, slot]``, ``slot = version % n_ver``). While it waits for a round, a vehicle sends its
last eigen share again (``ls_*``), as ``RigidityLayer.advance`` does.

Layouts: ``V`` blocks ``(3, k)``; the consensus vector ``x`` ``(n_c,)`` of
:func:`onboard.estimation.distributed_eigen.n_consensus`; an eigen share's ``per_target`` block
``[M_w V block (3 k) | weighted-degree part | form-gradient block (3)]`` indexed by target id.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from onboard.control.rigidity import BARRIER_FLOOR
from onboard.core.rigidity import BLEND_FLOOR, EIGEN_AGREEMENT, FRAME_MAX_AGE_S, ROUND_TIMEOUT_S
from onboard.estimation.distributed_eigen import MAX_BLOCK_NORM2, N_TRIVIAL, RITZ_RCOND, TT_RCOND
from sim import draws
from sim.jit import compiled

lost = compiled(draws).lost
K_LOC = draws.KIND_ANGLE_LOCALIZATION
K_EIG = draws.KIND_RIGIDITY_EIGEN

# indices of the float parameters (:func:`sim.compiled_rigidity.parameters`)
(
    P_DT,
    P_K_ANGLE,
    P_K_VERTICAL,
    P_K_DISTANCE,
    P_LAMBDA_MIN,
    P_LAMBDA_SAFE,
    P_K_RIGIDITY,
    P_R_COLL,
    P_R_SAFE,
    P_K_COLL,
    P_R_TRACK,
    P_K_TRACK_RANGE,
    P_K_TRACK_CAMERA,
    P_SOFTMIN_TAU,
    P_EIG_STEP,
    P_EIG_KT,
    P_EIG_KN,
    P_EIG_FORGET,
    P_E_G,
    P_E_P,
    P_E_I,
    P_V_MAX,
    P_W_MAX,
    P_PEER_TIMEOUT,
    P_WARMUP,
    P_RANGE_ONE,
    P_RANGE_WIDTH,
    P_FOV_ONE,
    P_FOV_WIDTH,
    P_CAM_COS_HALF,
    P_CAM_RANGE,
    P_YAW_GAIN,
    P_MAINTENANCE,
    N_PARAMS,
) = range(34)


@njit(cache=True)
def wrap(a):
    """``math.remainder(a, tau)``: exact for the angles of a run (Sterbenz)."""
    return a - math.tau * round(a / math.tau)


@njit(cache=True)
def cubic_step(x, x_one, width):
    """:func:`onboard.rigidity.weights._cubic_step` of one value: ``(value, slope)``."""
    t = (x - x_one) / width
    t = min(max(t, 0.0), 1.0)
    return 1.0 - t * t * (3.0 - 2.0 * t), -6.0 * t * (1.0 - t) / width


@njit(cache=True)
def star(p_i, yaw, p_nbr, prm):
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
        w_r, dw_r = cubic_step(d[j], prm[P_RANGE_ONE], prm[P_RANGE_WIDTH])
        w_f, dw_f = cubic_step(cos_axis, prm[P_FOV_ONE], prm[P_FOV_WIDTH])
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


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
def angle_gradient(b, d, cosm, beta, k_angle):
    """:func:`onboard.estimation.star_rigidity.angle_gradient`'s gradient ``(M + 1, 3)`` (paper
    003 eq. 10-11)."""
    m = b.shape[0]
    if m < 2:
        return np.zeros((m + 1, 3))
    e = np.zeros((m, m))
    for j in range(m):
        for k in range(m):
            if j != k:
                e[j, k] = cosm[j, k] - (
                    beta[j, 0] * beta[k, 0] + beta[j, 1] * beta[k, 1] + beta[j, 2] * beta[k, 2]
                )
    rows = row_sums(b, d, cosm, e)
    g = 2.0 * k_angle
    for j in range(m):
        for c in range(3):
            rows[j, c] = g * rows[j, c]
    return with_own(rows)


@njit(cache=True)
def vertical_gradient(b, d, beta, k_vertical):
    """:func:`onboard.estimation.star_rigidity.vertical_gradient`'s gradient ``(M + 1, 3)``."""
    m = b.shape[0]
    rows = np.empty((m, 3))
    for j in range(m):
        e = b[j, 2] - beta[j, 2]
        g = 2.0 * k_vertical * e
        for c in range(3):
            rows[j, c] = g * (((1.0 if c == 2 else 0.0) - b[j, 2] * b[j, c]) / d[j])
    return with_own(rows)


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True, error_model="numpy")
def lu_solve(a, b):
    """``(pivots |diag U| (n,), x (n, k))`` of ``a x = b`` by LU with partial pivoting (LAPACK's
    ``dgesv`` algorithm, for a 7x7 system, without its call overhead). A zero pivot gives a
    non-finite ``x``."""
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


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
def barrier_slope(x, x_min, x_safe, gain):
    """:func:`onboard.control.rigidity.rational_barrier`'s slope ``B'(x)``."""
    c = x_safe - x_min
    xc = min(max(x, x_min + BARRIER_FLOOR * c), x_safe)
    a = x_safe - xc
    b = xc - x_min
    return -gain * a * (a + 2.0 * b) / (c * b * b)


@njit(cache=True)
def collision_gradient(p_i, others, prm):
    """:func:`onboard.control.rigidity.collision_potential`'s gradient ``(3,)`` (eq. 30-31)."""
    g = np.zeros(3)
    for j in range(others.shape[0]):
        r0 = others[j, 0] - p_i[0]
        r1 = others[j, 1] - p_i[1]
        r2 = others[j, 2] - p_i[2]
        d = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
        if d == 0.0:
            raise ValueError("coincident positions: collision potential undefined")
        if d < prm[P_R_SAFE]:
            s = barrier_slope(d, prm[P_R_COLL], prm[P_R_SAFE], prm[P_K_COLL])
            g[0] += s * r0 / d
            g[1] += s * r1 / d
            g[2] += s * r2 / d
    return -g


@njit(cache=True)
def simulate(
    p0,
    yaw0,
    offsets,
    p_hat0,
    v0,
    restart_v,
    targets,
    track,
    range_pairs,
    bearing_noise,
    prm,
    n_steps,
    frame_every,
    record_every,
    delay,
    loss,
    loss_seed,
):
    """Run the team for ``n_steps`` steps (module docstring). Arrays: ``p0`` ``(N, 3)``, ``yaw0``
    and ``offsets`` ``(N,)``, ``p_hat0`` the localization priors ``(N, 3)``, ``v0`` the eigen
    starts ``(N, 3, k)``, ``restart_v`` ``(N, R, 3, k)`` the restart draws, ``targets`` ``(F, T,
    3)`` at every frame, ``track`` ``(N,)`` (-1: none), ``range_pairs`` ``(P, 2)``,
    ``bearing_noise`` ``(F or 1, N (N - 1), 3)`` (sigma included, or zeros).

    Returns the records ``(p, yaw, v_body, lambda_hat, p_hat, yaw_hat)`` and counters
    ``(nonfinite actions, restarts)``."""
    n = p0.shape[0]
    kk = v0.shape[2]
    n_c = N_TRIVIAL * kk + 28 + kk * (kk + 1)
    st_len = 2 * n_c + 3 * kk + 2
    per_len = 3 * kk + 4
    n_t = targets.shape[1]
    dt = prm[P_DT]
    timeout = prm[P_PEER_TIMEOUT]
    noisy = bearing_noise.shape[0] > 1
    maintenance = prm[P_MAINTENANCE] > 0.5

    # world
    p = p0.copy()
    yaw = yaw0.copy()
    v_body = np.zeros((n, 3))
    # camera frame (truth), ranges and target measurements of the last frame
    fr_beta = np.zeros((n, n, 3))
    fr_seen = np.zeros((n, n), np.bool_)
    fr_t = 0.0
    rng_d = np.full((n, n), np.nan)
    tg_beta = np.zeros((n, n_t, 3))
    tg_d = np.zeros((n, n_t))
    # localization
    p_hat = p_hat0.copy()
    yaw_off = np.zeros(n)
    yaw_known = np.zeros(n, np.bool_)
    yaw_hat = np.zeros(n)
    # eigen-estimate
    vmat = v0.copy()
    xs = np.zeros((n, n_c))
    zs = np.zeros((n, n_c))
    x_none = np.ones(n, np.bool_)
    s_bar = np.zeros(n)
    eig_lam = np.zeros(n)
    theta = np.zeros((n, kk))
    n_theta = np.zeros(n, np.int64)
    c_ritz = np.zeros((n, kk, kk))
    coef = np.zeros((n, N_TRIVIAL, kk))
    has_ritz = np.zeros(n, np.bool_)
    degree = np.zeros(n, np.int64)
    restarts = np.zeros(n, np.int64)
    rounds = np.zeros(n, np.int64)
    round_t = np.full(n, -np.inf)
    # layer outputs
    lam = np.zeros(n)
    gp = np.zeros((n, 3))
    gy = np.zeros(n)
    agreed = np.zeros(n, np.bool_)
    nonfinite = 0
    # inbox [receiver, sender]: the newest payload of each kind, with the receiver's own
    # block of its per-target parts (module docstring)
    loc_has = np.zeros((n, n), np.bool_)
    loc_t = np.zeros((n, n))
    loc_p = np.zeros((n, n, 3))
    loc_tgt = np.zeros((n, n), np.bool_)
    loc_grad = np.zeros((n, n, 3))
    eig_has = np.zeros((n, n), np.bool_)
    eig_t = np.zeros((n, n))
    eig_l = np.zeros((n, n))
    eig_round = np.zeros((n, n), np.int64)
    eig_ver = np.zeros((n, n), np.int64)
    # each agent's last eigen share (re-sent while it waits for a round)
    ls_has = np.zeros(n, np.bool_)
    ls_t = np.zeros(n)
    ls_l = np.zeros(n)
    ls_round = np.zeros(n, np.int64)
    ls_ver = np.zeros(n, np.int64)
    # every agent's shares by version (a receiver holds a version, not a copy): a version
    # is overwritten ``n_ver`` versions later, when it is stale (one version per step at most);
    # without loss a receiver holds one at most ``delay + 1`` versions old (fewer, hotter slots)
    n_ver = int(min(timeout / dt, n_steps + 1.0)) + delay + 4 if loss > 0.0 else delay + 3
    n_made = np.zeros(n, np.int64)
    sh_state = np.zeros((n, n_ver, st_len))
    sh_tgt = np.zeros((n, n_ver, n), np.bool_)
    sh_per = np.zeros((n, n_ver, n, per_len))
    # what is published [slot, sender]: a ring of the last ``delay`` steps' payloads
    ring = delay
    o_loc_p = np.zeros((ring, n, 3))
    o_loc_tgt = np.zeros((ring, n, n), np.bool_)
    o_loc_grad = np.zeros((ring, n, n, 3))
    o_eig_has = np.zeros((ring, n), np.bool_)
    o_eig_t = np.zeros((ring, n))
    o_eig_l = np.zeros((ring, n))
    o_eig_round = np.zeros((ring, n), np.int64)
    o_eig_ver = np.zeros((ring, n), np.int64)

    ax = np.zeros(n_c)
    live_buf = np.empty(n, np.int64)
    is_live_buf = np.zeros(n, np.bool_)
    seen_buf = np.empty(n, np.int64)
    fresh_buf = np.zeros(n, np.bool_)
    cand_buf = np.empty(n, np.int64)
    pos_buf = np.full(n, -1, np.int64)
    az = np.zeros(n_c)
    u_cmd = np.zeros((n, 3))
    w_cmd = np.zeros(n)
    n_rec = n_steps // record_every + 1
    rec_p = np.zeros((n_rec, n, 3))
    rec_yaw = np.zeros((n_rec, n))
    rec_vb = np.zeros((n_rec, n, 3))
    rec_lam = np.zeros((n_rec, n))
    rec_ph = np.zeros((n_rec, n, 3))
    rec_yh = np.zeros((n_rec, n))
    r_idx = 0
    cos_half = prm[P_CAM_COS_HALF]
    cam_range = prm[P_CAM_RANGE]

    for k in range(n_steps + 1):
        t = k * dt
        slot = k % ring
        if k % frame_every == 0:
            fi = k // frame_every
            e = 0
            for i in range(n):
                ci, si = math.cos(yaw[i]), math.sin(yaw[i])
                for j in range(n):
                    if j == i:
                        continue
                    r0 = p[j, 0] - p[i, 0]
                    r1 = p[j, 1] - p[i, 1]
                    r2 = p[j, 2] - p[i, 2]
                    dd = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
                    b0, b1, b2 = r0 / dd, r1 / dd, r2 / dd
                    be0 = ci * b0 + si * b1
                    be1 = -si * b0 + ci * b1
                    be2 = b2
                    if noisy:
                        q0 = bearing_noise[fi, e, 0]
                        q1 = bearing_noise[fi, e, 1]
                        q2 = bearing_noise[fi, e, 2]
                        dot = q0 * be0 + q1 * be1 + q2 * be2
                        q0 -= dot * be0
                        q1 -= dot * be1
                        q2 -= dot * be2
                        o0, o1, o2 = be0 + q0, be1 + q1, be2 + q2
                        nn = math.sqrt(o0 * o0 + o1 * o1 + o2 * o2)
                        be0, be1, be2 = o0 / nn, o1 / nn, o2 / nn
                    fr_beta[i, j, 0] = be0
                    fr_beta[i, j, 1] = be1
                    fr_beta[i, j, 2] = be2
                    fr_seen[i, j] = (ci * b0 + si * b1 + 0.0 * b2) >= cos_half and dd <= cam_range
                    e += 1
            fr_t = t
            for q in range(range_pairs.shape[0]):
                a_, b_ = range_pairs[q, 0], range_pairs[q, 1]
                r0 = p[b_, 0] - p[a_, 0]
                r1 = p[b_, 1] - p[a_, 1]
                r2 = p[b_, 2] - p[a_, 2]
                dd = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
                rng_d[a_, b_] = dd
                rng_d[b_, a_] = dd
            for i in range(n):
                ci, si = math.cos(yaw[i]), math.sin(yaw[i])
                for m in range(n_t):
                    r0 = targets[fi, m, 0] - p[i, 0]
                    r1 = targets[fi, m, 1] - p[i, 1]
                    r2 = targets[fi, m, 2] - p[i, 2]
                    dd = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
                    b0, b1, b2 = r0 / dd, r1 / dd, r2 / dd
                    tg_beta[i, m, 0] = ci * b0 + si * b1
                    tg_beta[i, m, 1] = -si * b0 + ci * b1
                    tg_beta[i, m, 2] = b2
                    tg_d[i, m] = dd
        frame_fresh = t - fr_t <= FRAME_MAX_AGE_S

        for i in range(n):
            yaw_odo = yaw[i] + offsets[i]
            # fresh neighbour estimates, ascending (the layer's ``live``)
            live = live_buf
            n_live = 0
            for j in range(n):
                if j != i and loc_has[i, j] and t - loc_t[i, j] <= timeout:
                    live[n_live] = j
                    n_live += 1
            live = live[:n_live]
            is_live = is_live_buf
            is_live.fill(False)
            for j in live:
                is_live[j] = True
            # the current frame's bearings to live targets, ascending
            seen = seen_buf
            n_seen = 0
            for j in live:
                if fr_seen[i, j] and frame_fresh:
                    bb = fr_beta[i, j]
                    nrm2 = bb[0] * bb[0] + bb[1] * bb[1] + bb[2] * bb[2]
                    if abs(nrm2 - 1.0) <= 1e-3:
                        seen[n_seen] = j
                        n_seen += 1
            seen = seen[:n_seen]
            beta = np.empty((n_seen, 3))
            for q in range(n_seen):
                beta[q] = fr_beta[i, seen[q]]
            fresh = fresh_buf
            fresh.fill(False)
            for j in range(n):
                if j != i and eig_has[i, j] and t - eig_t[i, j] <= timeout:
                    fresh[j] = True
            cand = cand_buf
            n_cand = 0
            for j in live:
                if fresh[j]:
                    cand[n_cand] = j
                    n_cand += 1
            cand = cand[:n_cand]

            # 1. yaw in the estimated frame (AngleLocalizer.update_yaw)
            if n_seen > 0:
                ok = True
                s_ = 0.0
                c_ = 0.0
                for q in range(n_seen):
                    j = seen[q]
                    r0 = loc_p[i, j, 0] - p_hat[i, 0]
                    r1 = loc_p[i, j, 1] - p_hat[i, 1]
                    r2 = loc_p[i, j, 2] - p_hat[i, 2]
                    nn = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
                    if nn == 0.0:
                        ok = False
                        break
                    bx, by = r0 / nn, r1 / nn
                    s_ += beta[q, 0] * by - beta[q, 1] * bx
                    c_ += beta[q, 0] * bx + beta[q, 1] * by
                if ok and math.hypot(s_, c_) >= 1e-3:
                    psi = math.atan2(s_, c_)
                    err = wrap(psi - yaw_odo - yaw_off[i])
                    gain = prm[P_YAW_GAIN] if yaw_known[i] else 1.0
                    yaw_off[i] = wrap(yaw_off[i] + gain * err)
                    yaw_known[i] = True
            yaw_hat[i] = wrap(yaw_odo + yaw_off[i])
            p_own = p_hat[i].copy()

            # 2. angle localization (eq. 10-11)
            # one star over the candidates (elementwise: a sub-star is a restriction)
            p_cand = np.empty((n_cand, 3))
            for q in range(n_cand):
                p_cand[q] = loc_p[i, cand[q]]
            _, d_c, b_c, cos_c, h_c, w_c, dhr_c, dhy_c = star(p_own, yaw_hat[i], p_cand, prm)
            pos = pos_buf
            pos.fill(-1)
            for q in range(n_cand):
                pos[cand[q]] = q
            inside = True
            for q in range(n_seen):
                inside = inside and pos[seen[q]] >= 0
            if inside:
                d_s = np.empty(n_seen)
                b_s = np.empty((n_seen, 3))
                cos_s = np.empty((n_seen, n_seen))
                for q in range(n_seen):
                    a_q = pos[seen[q]]
                    d_s[q] = d_c[a_q]
                    b_s[q] = b_c[a_q]
                    for q2 in range(n_seen):
                        cos_s[q, q2] = cos_c[a_q, pos[seen[q2]]]
            else:
                p_seen = np.empty((n_seen, 3))
                for q in range(n_seen):
                    p_seen[q] = loc_p[i, seen[q]]
                _, d_s, b_s, cos_s, _, _, _, _ = star(p_own, yaw_hat[i], p_seen, prm)
            g_loc = angle_gradient(b_s, d_s, cos_s, beta, prm[P_K_ANGLE])
            g_loc += vertical_gradient(b_s, d_s, beta, prm[P_K_VERTICAL])
            grad = g_loc[0].copy()
            for j in live:
                if loc_tgt[i, j]:
                    grad += loc_grad[i, j]
            for j in range(n):
                if is_live[j] and frame_fresh and rng_d[i, j] > 0.0:
                    r0 = p_own[0] - loc_p[i, j, 0]
                    r1 = p_own[1] - loc_p[i, j, 1]
                    r2 = p_own[2] - loc_p[i, j, 2]
                    nn = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
                    if nn != 0.0:
                        ge = 2.0 * prm[P_K_DISTANCE] * (nn - rng_d[i, j])
                        grad[0] += ge * r0 / nn
                        grad[1] += ge * r1 / nn
                        grad[2] += ge * r2 / nn
            o_loc_p[slot, i] = p_own
            o_loc_tgt[slot, i] = False
            for q in range(n_seen):
                o_loc_tgt[slot, i, seen[q]] = True
                o_loc_grad[slot, i, seen[q]] = g_loc[q + 1]
            # AgentCore's dt: 0 at the first step, then t - t_previous (not exactly dt)
            dt_i = 0.0 if k == 0 else t - (k - 1) * dt
            vn0, vn1, vn2 = 0.0, 0.0, 0.0
            if yaw_known[i]:
                cp, sp = math.cos(yaw_hat[i]), math.sin(yaw_hat[i])
                ux, uy, uz = v_body[i, 0], v_body[i, 1], v_body[i, 2]
                vn0, vn1, vn2 = cp * ux - sp * uy, sp * ux + cp * uy, uz
            np0 = p_hat[i, 0] + dt_i * (vn0 - grad[0])
            np1 = p_hat[i, 1] + dt_i * (vn1 - grad[1])
            np2 = p_hat[i, 2] + dt_i * (vn2 - grad[2])
            if math.isfinite(np0) and math.isfinite(np1) and math.isfinite(np2):
                p_hat[i, 0], p_hat[i, 1], p_hat[i, 2] = np0, np1, np2

            # 3. eigenvalue and its gradient (RigidityLayer._new_round, _eigen_step)
            take = True
            low = -1
            for j in cand:
                if eig_round[i, j] < rounds[i]:
                    take = t - round_t[i] >= ROUND_TIMEOUT_S
                if low < 0 or eig_round[i, j] < low:
                    low = eig_round[i, j]
            if take:
                rounds[i] = max(rounds[i], max(low, 0)) + 1
                round_t[i] = t
                v_cand = np.empty((n_cand, 3, kk))
                for q in range(n_cand):
                    j = cand[q]
                    for c in range(3):
                        for col in range(kk):
                            v_cand[q, c, col] = sh_state[j, eig_ver[i, j], 2 * n_c + c * kk + col]
                v_i = vmat[i]
                mv = weighted_matvec(b_c, d_c, cos_c, w_c, v_i, v_cand)
                s_parts = weighted_degree(d_c, cos_c, w_c)
                total = np.zeros(per_len)
                got = False
                for j in range(n):
                    if fresh[j] and sh_tgt[j, eig_ver[i, j], i]:
                        if got:
                            total += sh_per[j, eig_ver[i, j], i]
                        else:
                            total[:] = sh_per[j, eig_ver[i, j], i]
                            got = True
                mv_i = mv[0].copy()
                for c in range(3):
                    for col in range(kk):
                        mv_i[c, col] += total[c * kk + col]
                s_i = s_parts[0] + total[3 * kk]
                t_i = trivial_block(p_own)
                g_form = np.zeros((n_cand + 1, 3))
                g_form_yaw = 0.0
                if has_ritz[i]:
                    nt = n_theta[i]
                    wts = blend(theta[i, :nt], prm[P_SOFTMIN_TAU])
                    y = ritz_blocks(p_own, v_i, p_cand, v_cand, coef[i], c_ritz[i], nt)
                    for m in range(nt):
                        if wts[m] == 0.0:
                            continue
                        g_m, g_m_yaw = form_gradient_only(
                            b_c, d_c, cos_c, h_c, w_c, dhr_c, dhy_c, y[0, :, m], y[1:, :, m]
                        )
                        for q in range(n_cand + 1):
                            for c in range(3):
                                g_form[q, c] = g_form[q, c] + wts[m] * g_m[q, c]
                        g_form_yaw += wts[m] * g_m_yaw
                # DistributedEigenEstimator.step
                phi = consensus_input(t_i, v_i, mv_i)
                k_nb = 0
                for j in range(n):
                    if fresh[j]:
                        k_nb += 1
                degree[i] = k_nb
                if x_none[i] or not np.all(np.isfinite(xs[i])):
                    xs[i] = phi
                    zs[i] = 0.0
                    x_none[i] = False
                # round_consensus.pi_round with Metropolis weights, and max_round
                a_sum = 0.0
                ax.fill(0.0)
                az.fill(0.0)
                top = -np.inf
                for j in range(n):
                    if fresh[j]:
                        a_j = 1.0 / (1.0 + max(float(k_nb), sh_state[j, eig_ver[i, j], st_len - 2]))
                        a_sum += a_j
                        for q in range(n_c):
                            ax[q] += a_j * sh_state[j, eig_ver[i, j], q]
                            az[q] += a_j * sh_state[j, eig_ver[i, j], n_c + q]
                        top = max(top, sh_state[j, eig_ver[i, j], st_len - 1])
                e_g, e_p, e_i = prm[P_E_G], prm[P_E_P], prm[P_E_I]
                for q in range(n_c):
                    dxq = a_sum * xs[i, q] - ax[q]
                    dzq = a_sum * zs[i, q] - az[q]
                    xq = xs[i, q]
                    xs[i, q] = xq + e_g * (phi[q] - xq) - e_p * dxq + e_i * dzq
                    zs[i, q] = zs[i, q] - e_i * dxq
                top = max(s_bar[i], top)
                s_bar[i] = max(s_i, prm[P_EIG_FORGET] * top)
                th, cr_new, cf_new = ritz(xs[i], kk)
                coef[i] = cf_new
                if len(th) > 0:
                    n_theta[i] = len(th)
                    theta[i, : len(th)] = th
                    eig_lam[i] = max(th[0], 0.0)
                    c_ritz[i] = 0.0
                    c_ritz[i, :, : len(th)] = cr_new
                    has_ritz[i] = True
                trivial = mm(t_i, cf_new)
                alpha = prm[P_EIG_STEP] / s_bar[i] if s_bar[i] > 0.0 else 0.0
                vv = unpack_sym(xs[i], N_TRIVIAL * kk + 28, kk)
                for c in range(kk):
                    vv[c, c] -= 1.0
                vvv = mm(v_i, vv)
                v_new = np.empty((3, kk))
                k_t, k_n2 = prm[P_EIG_KT], 0.5 * prm[P_EIG_KN]
                norm2 = 0.0
                for c in range(3):
                    for col in range(kk):
                        x_ = (
                            v_i[c, col]
                            - alpha * mv_i[c, col]
                            - k_t * trivial[c, col]
                            - k_n2 * vvv[c, col]
                        )
                        v_new[c, col] = x_
                        norm2 += x_ * x_
                if not norm2 <= MAX_BLOCK_NORM2:
                    restarts[i] += 1
                    if restarts[i] > restart_v.shape[1]:
                        raise ValueError("more restarts of the eigen-estimate than drawn")
                    v_new = restart_v[i, restarts[i] - 1].copy()
                    x_none[i] = True
                vmat[i] = v_new
                ls_has[i] = False  # after a restart the layer has no share to send
                if not x_none[i]:
                    ls_has[i] = True
                    vs = n_made[i] % n_ver
                    ls_ver[i] = vs
                    n_made[i] += 1
                    ls_t[i] = t
                    ls_l[i] = eig_lam[i]
                    ls_round[i] = rounds[i]
                    sh_state[i, vs, :n_c] = xs[i]
                    sh_state[i, vs, n_c : 2 * n_c] = zs[i]
                    for c in range(3):
                        for col in range(kk):
                            sh_state[i, vs, 2 * n_c + c * kk + col] = v_new[c, col]
                    sh_state[i, vs, st_len - 2] = float(degree[i])
                    sh_state[i, vs, st_len - 1] = s_bar[i]
                    sh_tgt[i, vs] = False
                    for q in range(n_cand):
                        j = cand[q]
                        sh_tgt[i, vs, j] = True
                        for c in range(3):
                            for col in range(kk):
                                sh_per[i, vs, j, c * kk + col] = mv[q + 1, c, col]
                        sh_per[i, vs, j, 3 * kk] = s_parts[q + 1]
                        for c in range(3):
                            sh_per[i, vs, j, 3 * kk + 1 + c] = g_form[q + 1, c]
                lam[i] = eig_lam[i]
                for c in range(3):
                    gp[i, c] = (g_form[0, c] + total[3 * kk + 1 + c]) / n
                gy[i] = g_form_yaw / n
            tol = EIGEN_AGREEMENT * prm[P_LAMBDA_SAFE]
            agreed[i] = n_cand > 0
            for j in cand:
                if not abs(eig_l[i, j] - lam[i]) <= tol:
                    agreed[i] = False

            # publish: a new round's share, else the last one again (RigidityLayer.advance)
            o_eig_has[slot, i] = ls_has[i]
            if ls_has[i]:
                o_eig_t[slot, i] = ls_t[i]
                o_eig_l[slot, i] = ls_l[i]
                o_eig_round[slot, i] = ls_round[i]
                o_eig_ver[slot, i] = ls_ver[i]

            # 4. actions (RigidityLayer._actions)
            u = np.zeros(3)
            w = 0.0
            if t >= prm[P_WARMUP]:
                if yaw_known[i]:
                    if maintenance and agreed[i] and lam[i] < prm[P_LAMBDA_SAFE]:
                        slope = barrier_slope(
                            lam[i], prm[P_LAMBDA_MIN], prm[P_LAMBDA_SAFE], prm[P_K_RIGIDITY]
                        )
                        g0, g1, g2 = slope * gp[i, 0], slope * gp[i, 1], slope * gp[i, 2]
                        cy, sy = math.cos(yaw_hat[i]), math.sin(yaw_hat[i])
                        u[0] += -(cy * g0 + sy * g1 + 0.0 * g2)
                        u[1] += -(-sy * g0 + cy * g1 + 0.0 * g2)
                        u[2] += -(0.0 * g0 + 0.0 * g1 + 1.0 * g2)
                        w += -(slope * gy[i])
                    if n_live > 0:
                        others = np.empty((n_live, 3))
                        for q in range(n_live):
                            others[q] = loc_p[i, live[q]]
                        gc = collision_gradient(p_own, others, prm)
                        if gc[0] != 0.0 or gc[1] != 0.0 or gc[2] != 0.0:
                            cy, sy = math.cos(yaw_hat[i]), math.sin(yaw_hat[i])
                            u[0] += -(cy * gc[0] + sy * gc[1] + 0.0 * gc[2])
                            u[1] += -(-sy * gc[0] + cy * gc[1] + 0.0 * gc[2])
                            u[2] += -(0.0 * gc[0] + 0.0 * gc[1] + 1.0 * gc[2])
                if frame_fresh:
                    for m in range(n_t):
                        bt = tg_beta[i, m]
                        dm = tg_d[i, m]
                        if not (np.all(np.isfinite(bt)) and math.isfinite(dm) and dm > 0.0):
                            continue
                        gc = collision_gradient(np.zeros(3), (dm * bt).reshape(1, 3), prm)
                        u -= gc
                        if m == track[i]:
                            kr = prm[P_K_TRACK_RANGE] * (dm - prm[P_R_TRACK])
                            kc = prm[P_K_TRACK_CAMERA]
                            u[0] += kr * bt[0] - kc * (1.0 - bt[0] * bt[0]) / dm
                            u[1] += kr * bt[1] - kc * (0.0 - bt[0] * bt[1]) / dm
                            u[2] += kr * bt[2] - kc * (0.0 - bt[0] * bt[2]) / dm
                            w += kc * bt[1]
            if not (np.all(np.isfinite(u)) and math.isfinite(w)):
                nonfinite += 1
                u[:] = 0.0
                w = 0.0
            # AgentCore: saturation
            nv = math.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
            if nv > prm[P_V_MAX]:
                sc = prm[P_V_MAX] / nv
                u[0], u[1], u[2] = sc * u[0], sc * u[1], sc * u[2]
            u_cmd[i] = u
            w_cmd[i] = max(-prm[P_W_MAX], min(prm[P_W_MAX], w))

        # delivery: the payloads of step k + 1 - delay are next step's inbox, each copy lost
        # as sim.draws.lost says for (step sent, sender, receiver, kind), as the runner drops it
        k_sent = k + 1 - delay
        if k_sent >= 0:
            src = k_sent % ring
            t_sent = k_sent * dt
            for j in range(n):
                for i in range(n):
                    if i == j:
                        continue
                    if not (loss > 0.0 and lost(loss_seed, k_sent, j, i, n, K_LOC, loss)):
                        loc_has[i, j] = True
                        loc_t[i, j] = t_sent
                        loc_tgt[i, j] = o_loc_tgt[src, j, i]
                        for c in range(3):  # scalar copies: slices cost more at this size
                            loc_p[i, j, c] = o_loc_p[src, j, c]
                            loc_grad[i, j, c] = o_loc_grad[src, j, i, c]
                    if o_eig_has[src, j] and not (
                        loss > 0.0 and lost(loss_seed, k_sent, j, i, n, K_EIG, loss)
                    ):
                        eig_has[i, j] = True
                        eig_t[i, j] = o_eig_t[src, j]
                        eig_l[i, j] = o_eig_l[src, j]
                        eig_round[i, j] = o_eig_round[src, j]
                        eig_ver[i, j] = o_eig_ver[src, j]
        if k % record_every == 0:
            rec_p[r_idx] = p
            rec_yaw[r_idx] = yaw
            rec_vb[r_idx] = v_body
            rec_lam[r_idx] = lam
            rec_ph[r_idx] = p_hat
            rec_yh[r_idx] = yaw_hat
            r_idx += 1
        # the world (sim.runner.run): explicit Euler on the commanded body velocity
        for i in range(n):
            u0, u1, u2 = u_cmd[i, 0], u_cmd[i, 1], u_cmd[i, 2]
            c, s = math.cos(yaw[i]), math.sin(yaw[i])
            v0_, v1_, v2_ = c * u0 - s * u1, s * u0 + c * u1, u2
            p[i, 0] = p[i, 0] + dt * v0_
            p[i, 1] = p[i, 1] + dt * v1_
            p[i, 2] = p[i, 2] + dt * v2_
            yaw[i] = yaw[i] + dt * w_cmd[i]
            c, s = math.cos(yaw[i]), math.sin(yaw[i])
            v_body[i, 0] = c * v0_ + s * v1_
            v_body[i, 1] = -s * v0_ + c * v1_
            v_body[i, 2] = v2_
    return (rec_p, rec_yaw, rec_vb, rec_lam, rec_ph, rec_yh), (nonfinite, restarts.sum())
