"""The exact Hessian of the Lagrangian of Problem 3 by the chain rule through 3x3 matrices.

IPOPT needs, at every iteration, the Hessian of the Lagrangian

    L(t, z, psi) = lam_f t + sum_i lam_i (tr(J_i^-1) / s - t) + sum_k mu_k c_k(z, psi),

where ``J_i = Sigmabar^-1 + sigma_m^-2 sum_j A(z_j - x_i)`` is the information of setpoint
``i`` (paper 004 eq. 7, ``A`` the closed form of eq. 34) and ``c_k`` the distance and
field-of-view constraints. Generic automatic differentiation of ``tr(J_i^-1)`` costs about
``3M`` times the size of the trace expressions (one direction per variable), which makes the
Hessian the largest single cost of an IPOPT iteration at M = 10. Paper 004 eq. 11 gives the
same second derivative in terms of ``dJ`` and ``d^2 J``:

    d^2 tr(J^-1) / (d theta_a d theta_b)
        = -tr(J^-2 d^2J/(d theta_a d theta_b)) + 2 tr(J^-2 dJ/d theta_a J^-1 dJ/d theta_b).

Writing ``J`` by its six distinct entries ``j`` and ``phi(j) = tr(J^-1)``, this is

    H_i = D_i^T (d^2 phi / dj^2) D_i + blockdiag_j( sum_k dphi/dj_k d^2 A_k(r_ij) / dr^2 ),

with ``D_i = dj_i / dz`` (6 x 3M, one 6 x 3 block per landmark, since each landmark moves only
its own term). The first part is one small dense product per setpoint and the second is block
diagonal: 125 000 operations at N = M = 10 instead of 180 000 (the dense products
``D_i^T W D_i`` are most of it), and a faster build. The constraints are
separable (each involves one landmark and at most one heading), so their part is left to
casadi's automatic differentiation, which is cheap for them. Both parts are exact: tests
compare the result with casadi's Hessian of the whole Lagrangian and with finite differences.

casadi is imported inside the functions so that importing this module stays cheap.
"""

from __future__ import annotations

from typing import Any

from groundstation.planner.problem import PlacementProblem
from groundstation.planner.symbolic import Params, landmark_dims

UPPER = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
"""Order of the six distinct entries of a symmetric 3x3 matrix: diagonal, then (01, 02, 12)."""


def _term_functions() -> tuple[Any, Any]:
    """casadi Functions for one bearing term and for ``tr(J^-1)`` of a symmetric 3x3 ``J``.

    ``term(r, delta^2, c) -> (a, da/dr, d^2(c . a)/dr^2)`` where ``a`` are the six entries of
    ``A(r) = I/s2 - (s2 + delta^2)/s2^3 r r^T``, ``s2 = |r|^2 + delta^2`` (eq. 34);
    ``phi(j) -> (tr(J^-1), gradient, Hessian)`` in the entries ``j`` (sum of the principal
    2x2 minors over the determinant).
    """
    import casadi as ca

    r = ca.SX.sym("r", 3)
    delta2 = ca.SX.sym("delta2")
    c = ca.SX.sym("c", 6)
    s2 = ca.dot(r, r) + delta2
    a_mat = ca.SX.eye(3) / s2 - (s2 + delta2) / s2**3 * (r @ r.T)
    a = ca.vertcat(*[a_mat[p, q] for p, q in UPPER])
    curvature = ca.hessian(ca.dot(c, a), r)[0]
    term = ca.Function("bearing_term", [r, delta2, c], [a, ca.jacobian(a, r), curvature])

    j = ca.SX.sym("j", 6)
    d00, d11, d22, e01, e02, e12 = (j[k] for k in range(6))
    minors = (d11 * d22 - e12 * e12) + (d00 * d22 - e02 * e02) + (d00 * d11 - e01 * e01)
    det = (
        d00 * (d11 * d22 - e12 * e12)
        - e01 * (e01 * d22 - e12 * e02)
        + e02 * (e01 * e12 - d11 * e02)
    )
    phi = minors / det
    hess, grad = ca.hessian(phi, j)
    return term, ca.Function("trace_of_inverse", [j], [phi, grad, hess])


def trace_hessian(
    problem: PlacementProblem, z_vars: Any, par: Params, weights: Any
) -> tuple[Any, Any]:
    """``sum_i weights_i tr(J_i^-1)``: its Hessian in ``z_vars`` and the traces themselves.

    Returns ``(H, traces)``: ``H`` is the dense ``(dims M, dims M)`` casadi SX matrix of the
    weighted sum (eq. 11 in chain-rule form, see the module docstring) and ``traces`` the
    ``N`` trace expressions (eq. 7 with eq. 34), equal to ``symbolic_traces``.
    """
    import casadi as ca

    term, phi = _term_functions()
    dims = landmark_dims(problem)
    m = problem.n_landmarks
    info0 = ca.vertcat(*[par.info0[p, q] for p, q in UPPER])
    h_total = ca.SX.zeros(dims * m, dims * m)
    traces = []
    for i in range(problem.n_setpoints):
        offsets = []
        for j in range(m):
            zj = z_vars[dims * j : dims * (j + 1)]
            z3 = ca.vertcat(zj, par.ground) if problem.planar else zj
            offsets.append(z3 - par.x[:, i])
        zero6 = ca.SX.zeros(6)
        terms = [term(r, par.delta2, zero6) for r in offsets]
        info = info0 + par.inv_sigma2 * sum((t[0] for t in terms), ca.SX.zeros(6))
        value, grad, hess = phi(info)
        traces.append(value)
        jac = ca.horzcat(*[t[1][:, :dims] for t in terms]) * par.inv_sigma2  # (6, dims M)
        h_total += jac.T @ ((weights[i] * hess) @ jac)
        c = weights[i] * par.inv_sigma2 * grad
        blocks = [term(r, par.delta2, c)[2][:dims, :dims] for r in offsets]
        h_total += ca.diagcat(*blocks)
    return h_total, traces


def lagrangian_hessian(
    problem: PlacementProblem, w: Any, z_vars: Any, par: Params, v: Any, g: Any
) -> Any:
    """casadi Function ``(x, p, lam_f, lam_g) -> triu(Hessian of the Lagrangian)`` for IPOPT.

    ``w = [t; z; psi]`` are the decision variables, ``v`` the parameter vector and ``g`` the
    constraint vector whose first ``N`` entries are ``tr_i / scale - t`` (the order of
    :func:`groundstation.planner.ipopt`); the signature and output sparsity are those casadi
    expects for the ``hess_lag`` option of ``nlpsol``.
    """
    import casadi as ca

    n = problem.n_setpoints
    lam_f = ca.SX.sym("lam_f")
    lam_g = ca.SX.sym("lam_g", g.numel())
    h_trace, _ = trace_hessian(problem, z_vars, par, lam_g[:n] / par.scale)
    n_z = int(z_vars.numel())
    n_psi = int(w.numel()) - 1 - n_z
    h_trace_w = ca.diagcat(ca.SX(1, 1), h_trace, ca.SX(n_psi, n_psi))
    rest = ca.dot(lam_g[n:], g[n:])
    h_rest = ca.hessian(rest, w)[0]
    hess = ca.triu(h_trace_w + h_rest)
    return ca.Function(
        "nlp_hess_l",
        [w, v, lam_f, lam_g],
        [hess],
        ["x", "p", "lam_f", "lam_g"],
        ["triu_hess_gamma_x_x"],
    )
