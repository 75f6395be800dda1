"""Centralized extended Kalman filter on ``SE(3)^(N-1)`` from body-frame bearings and velocities.

Paper 001 sec. IV (eq. 34-43). The state is the pose of agents ``2..N`` in agent 1's body
frame (agent 1 is the reference: its pose is ``(0, I)`` by construction, which removes the
gauge of global translations and rotations). In code agents are numbered from 0, so "agent 1"
is index 0 and the state holds indices ``1..N-1``.

Shapes, with ``M = N - 1`` estimated agents:

* ``p_ref``: ``(M, 3)`` positions of agents ``1..N-1`` in the reference frame (m);
* ``rot_ref_body``: ``(M, 3, 3)`` rotations mapping agent ``i``'s body vectors to the
  reference frame;
* error state ``dx``: ``(6M,)`` laid out ``(dp_1..dp_M, dtheta_1..dtheta_M)``: the same
  column order as :func:`onboard.rigidity.bearing.se3_rigidity_matrix` with agent 1's columns
  removed; the retraction (docs/equations.md, "Centralized EKF on SE(3)^N") is
  ``(p + dp, R exp(hat(dtheta)))``;
* inputs ``v_body_m_s``, ``w_body_rad_s``: ``(N, 3)`` every agent's measured body-frame linear
  and angular velocity, agent 1 (the reference) included;
* ``input_std``: ``(N, 2)`` standard deviations of each agent's ``v`` (m/s) and ``w`` (rad/s)
  noise, isotropic per vector (the process noise of eq. 36: ``f(q, u + n)``);
* bearings: ``edges`` ``(E, 2)`` of agent indices ``0..N-1`` (``(i, j)``: ``i`` measures ``j``),
  ``beta_body`` ``(E, 3)`` unit vectors in ``i``'s body frame (paper 001 eq. 3, 35).

Process model with a moving reference (relative kinematics; paper 001 eq. 34 is the case
``v_1 = w_1 = 0``, with the rotation ``R_i`` the extracted text drops): over ``dt`` with
constant inputs, ``E_i = exp(dt hat(w_i))``::

    p_i+ = E_1^T (p_i + dt R_i v_i - dt v_1),     R_i+ = E_1^T R_i E_i

Error-state Jacobians (paper 001 eq. 37-39, derived for this retraction; checked against
finite differences on the manifold in tests/onboard/test_se3_ekf.py), ``J_r`` the right
Jacobian of ``SO(3)``::

    d dp_i+ / d dp_i = E_1^T          d dp_i+ / d dtheta_i = -dt E_1^T R_i hat(v_i)
    d dtheta_i+ / d dtheta_i = E_i^T
    d dp_i+ / d n_v_i = dt E_1^T R_i  d dtheta_i+ / d n_w_i = dt J_r(dt w_i)
    d dp_i+ / d n_v_1 = -dt E_1^T     d dp_i+ / d n_w_1 = dt hat(p_i+) J_r(dt w_1)
    d dtheta_i+ / d n_w_1 = -dt R_i+^T J_r(dt w_1)

Measurement model (paper 001 eq. 35): ``beta_ij = R_i^T (p_j - p_i)/d_ij``; its Jacobian is the
``SE(3)`` bearing rigidity matrix (paper 001 eq. 22, with the rotation-block sign the
finite-difference tests verify, docs/equations.md "Bearing rigidity" item 3) with agent 1's
columns removed. The 3-vector innovation has a singular covariance along the bearing (the
bearing is a unit vector: only two components are independent, paper 001 remark 1), so each
bearing is updated in the 2-D tangent plane of the predicted bearing ``betahat``: with an
orthonormal basis ``T`` (3 x 2) of that plane, the innovation is the log map of the sphere,
``y = T^T log_betahat(beta)`` (angle times direction), the measurement Jacobian ``T^T H`` and
the noise ``sigma^2 I_2`` (isotropic angular noise in radians). The covariance update is in
Joseph form, ``P+ = (I - K H) P (I - K H)^T + K R K^T``, and the state is updated through the
retraction (eq. 42).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import FloatArray, IntArray, hat, so3_exp, so3_log
from onboard.rigidity.bearing import se3_rigidity_matrix

_SMALL_ANGLE = 1e-4
_MIN_DISTANCE_M = 1e-6


@dataclass(frozen=True)
class Se3EkfState:
    """Estimate and error-state covariance of the centralized ``SE(3)`` EKF.

    ``p_ref`` ``(M, 3)``, ``rot_ref_body`` ``(M, 3, 3)`` (agents ``1..N-1`` in agent 0's frame),
    ``cov`` ``(6M, 6M)`` in the tangent coordinates ``(dp_1..dp_M, dtheta_1..dtheta_M)``.
    """

    p_ref: FloatArray
    rot_ref_body: FloatArray
    cov: FloatArray

    @property
    def n_agents(self) -> int:
        """``N``: the reference agent plus the estimated ones."""
        return len(self.p_ref) + 1


@dataclass(frozen=True)
class UpdateStats:
    """Per-update diagnostics: normalized innovation squared and its degrees of freedom."""

    nis: float
    dof: int


# ---------------------------------------------------------------------------------------------
# SO(3) helpers
# ---------------------------------------------------------------------------------------------


def so3_right_jacobian(phi: ArrayLike) -> FloatArray:
    """Right Jacobian ``J_r(phi)``: ``exp(hat(phi + d)) = exp(hat(phi)) exp(hat(J_r(phi) d))``.

    ``J_r = I - (1 - cos t)/t^2 hat(phi) + (t - sin t)/t^3 hat(phi)^2``, ``t = |phi|``, series
    near 0. Shape ``(..., 3) -> (..., 3, 3)``.
    """
    phi = np.asarray(phi, dtype=float)
    t = np.linalg.norm(phi, axis=-1)
    small = t < _SMALL_ANGLE
    ts = np.where(small, 1.0, t)
    t2 = t * t
    a = np.where(small, 0.5 - t2 / 24.0, (1.0 - np.cos(ts)) / ts**2)
    b = np.where(small, 1.0 / 6.0 - t2 / 120.0, (ts - np.sin(ts)) / ts**3)
    k = hat(phi)
    return np.eye(3) - a[..., None, None] * k + b[..., None, None] * (k @ k)


def sphere_log(base: ArrayLike, x: ArrayLike) -> FloatArray:
    """Log map of the unit sphere: tangent vector at ``base`` pointing to ``x``, length = angle.

    ``(..., 3), (..., 3) -> (..., 3)``; zero when ``x == base``; antipodal points (undefined)
    give a zero vector.
    """
    b = np.asarray(base, dtype=float)
    v = np.asarray(x, dtype=float)
    cos_a = np.clip(np.sum(b * v, axis=-1), -1.0, 1.0)
    perp = v - cos_a[..., None] * b
    sin_a = np.linalg.norm(perp, axis=-1)
    angle = np.arctan2(sin_a, cos_a)
    scale = np.where(sin_a > 1e-12, angle / np.where(sin_a > 1e-12, sin_a, 1.0), 1.0)
    return scale[..., None] * perp


def tangent_basis(beta: ArrayLike) -> FloatArray:
    """Orthonormal basis ``T`` of the plane normal to each unit vector: ``(E, 3) -> (E, 3, 2)``.

    ``T^T beta = 0``, ``T^T T = I_2``; built from the coordinate axis least aligned with
    ``beta`` (continuous almost everywhere; the update does not depend on the choice).
    """
    b = np.asarray(beta, dtype=float)
    axis = np.eye(3)[np.argmin(np.abs(b), axis=-1)]
    t1 = np.cross(b, axis)
    t1 /= np.linalg.norm(t1, axis=-1, keepdims=True)
    t2 = np.cross(b, t1)
    return np.stack([t1, t2], axis=-1)


# ---------------------------------------------------------------------------------------------
# State helpers
# ---------------------------------------------------------------------------------------------


def _check_state_arrays(p_ref: ArrayLike, rot_ref_body: ArrayLike) -> tuple[FloatArray, FloatArray]:
    p = np.asarray(p_ref, dtype=float)
    rot = np.asarray(rot_ref_body, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] < 1:
        raise ValueError(f"p_ref must have shape (M, 3) with M >= 1, got {p.shape}")
    if rot.shape != (len(p), 3, 3):
        raise ValueError(f"rot_ref_body must have shape ({len(p)}, 3, 3), got {rot.shape}")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(rot))):
        raise ValueError("poses contain NaN or inf")
    return p, rot


def _check_inputs(x: ArrayLike, n: int, name: str) -> FloatArray:
    arr = np.asarray(x, dtype=float)
    if arr.shape != (n, 3):
        raise ValueError(f"{name} must have shape ({n}, 3), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or inf")
    return arr


def initial_state(
    p_ref: ArrayLike, rot_ref_body: ArrayLike, sigma_p_m: float, sigma_theta_rad: float
) -> Se3EkfState:
    """Filter state at the prior ``(p_ref, rot_ref_body)`` with a diagonal covariance."""
    p, rot = _check_state_arrays(p_ref, rot_ref_body)
    if not (sigma_p_m > 0.0 and sigma_theta_rad > 0.0):
        raise ValueError("prior standard deviations must be positive")
    m = len(p)
    diag = np.concatenate([np.full(3 * m, sigma_p_m**2), np.full(3 * m, sigma_theta_rad**2)])
    return Se3EkfState(p.copy(), rot.copy(), np.diag(diag))


def full_poses(p_ref: ArrayLike, rot_ref_body: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Poses of all ``N`` agents in the reference frame, the reference ``(0, I)`` first.

    ``(M, 3), (M, 3, 3) -> (N, 3), (N, 3, 3)``.
    """
    p, rot = _check_state_arrays(p_ref, rot_ref_body)
    return np.vstack([np.zeros((1, 3)), p]), np.concatenate([np.eye(3)[None], rot])


def relative_poses(p_world: ArrayLike, rot_world_body: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Poses of agents ``1..N-1`` in agent 0's body frame from world poses (the filter's truth).

    ``p_i^ref = R_0^T (p_i - p_0)``, ``R_i^ref = R_0^T R_i``. ``(N, 3), (N, 3, 3) -> (M, 3), (M, 3, 3)``.
    """
    p = np.asarray(p_world, dtype=float)
    rot = np.asarray(rot_world_body, dtype=float)
    r0t = rot[0].T
    return (p[1:] - p[0]) @ r0t.T, r0t @ rot[1:]


def retract(
    p_ref: ArrayLike, rot_ref_body: ArrayLike, dx: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """Retraction ``(p + dp, R exp(hat(dtheta)))`` of paper 001 eq. 42; ``dx`` is ``(6M,)``."""
    p, rot = _check_state_arrays(p_ref, rot_ref_body)
    m = len(p)
    d = np.asarray(dx, dtype=float)
    if d.shape != (6 * m,):
        raise ValueError(f"dx must have shape ({6 * m},), got {d.shape}")
    return p + d[: 3 * m].reshape(m, 3), rot @ so3_exp(d[3 * m :].reshape(m, 3))


def local_difference(
    p_a: ArrayLike, rot_a: ArrayLike, p_b: ArrayLike, rot_b: ArrayLike
) -> FloatArray:
    """Inverse of :func:`retract`: ``dx`` with ``retract(a, dx) = b``, ``(6M,)``."""
    pa, ra = _check_state_arrays(p_a, rot_a)
    pb, rb = _check_state_arrays(p_b, rot_b)
    dtheta = so3_log(np.swapaxes(ra, -1, -2) @ rb)
    return np.concatenate([(pb - pa).ravel(), dtheta.ravel()])


def scale_direction(p_ref: ArrayLike) -> FloatArray:
    """Unit tangent vector of a scaling of the formation about the reference agent, ``(6M,)``.

    Bearings are invariant along it (it is in the null space of the measurement Jacobian);
    only motion with known velocities makes it observable (paper 001 sec. III).
    """
    p = np.asarray(p_ref, dtype=float)
    s = np.concatenate([p.ravel(), np.zeros(p.size)])
    return s / np.linalg.norm(s)


# ---------------------------------------------------------------------------------------------
# Process model (paper 001 eq. 34, 37-39) and prediction (eq. 40-41)
# ---------------------------------------------------------------------------------------------


def propagate(
    p_ref: ArrayLike,
    rot_ref_body: ArrayLike,
    v_body_m_s: ArrayLike,
    w_body_rad_s: ArrayLike,
    dt_s: float,
) -> tuple[FloatArray, FloatArray]:
    """Discrete process model (module doc): poses after ``dt_s`` with constant inputs.

    ``(M, 3), (M, 3, 3), (N, 3), (N, 3), float -> (M, 3), (M, 3, 3)``.
    """
    p, rot = _check_state_arrays(p_ref, rot_ref_body)
    n = len(p) + 1
    v = _check_inputs(v_body_m_s, n, "v_body_m_s")
    w = _check_inputs(w_body_rad_s, n, "w_body_rad_s")
    e = so3_exp(dt_s * w)
    e1t = e[0].T
    p_new = (p + dt_s * np.einsum("mkl,ml->mk", rot, v[1:]) - dt_s * v[0]) @ e1t.T
    rot_new = e1t @ rot @ e[1:]
    return p_new, rot_new


def process_jacobians(
    p_ref: ArrayLike,
    rot_ref_body: ArrayLike,
    v_body_m_s: ArrayLike,
    w_body_rad_s: ArrayLike,
    dt_s: float,
) -> tuple[FloatArray, FloatArray]:
    """``F = d dx+ / d dx`` ``(6M, 6M)`` and ``L = d dx+ / d n`` ``(6M, 6N)`` (eq. 37-39).

    Noise columns ``(n_v_0..n_v_{N-1}, n_w_0..n_w_{N-1})`` (input noise, true = measured + n).
    """
    p, rot = _check_state_arrays(p_ref, rot_ref_body)
    m = len(p)
    n = m + 1
    v = _check_inputs(v_body_m_s, n, "v_body_m_s")
    w = _check_inputs(w_body_rad_s, n, "w_body_rad_s")
    e = so3_exp(dt_s * w)
    e1t = e[0].T
    p_new, rot_new = propagate(p, rot, v, w, dt_s)
    jr = so3_right_jacobian(dt_s * w)
    f = np.zeros((6 * m, 6 * m))
    big_l = np.zeros((6 * m, 6 * n))
    for a in range(m):
        ip, it = slice(3 * a, 3 * a + 3), slice(3 * m + 3 * a, 3 * m + 3 * a + 3)
        f[ip, ip] = e1t
        f[ip, it] = -dt_s * e1t @ rot[a] @ hat(v[a + 1])
        f[it, it] = e[a + 1].T
        big_l[ip, 3 * (a + 1) : 3 * (a + 2)] = dt_s * e1t @ rot[a]
        big_l[it, 3 * n + 3 * (a + 1) : 3 * n + 3 * (a + 2)] = dt_s * jr[a + 1]
        big_l[ip, 0:3] = -dt_s * e1t
        big_l[ip, 3 * n : 3 * n + 3] = dt_s * hat(p_new[a]) @ jr[0]
        big_l[it, 3 * n : 3 * n + 3] = -dt_s * rot_new[a].T @ jr[0]
    return f, big_l


def input_covariance(input_std: ArrayLike) -> FloatArray:
    """Diagonal input-noise covariance ``Q`` ``(6N, 6N)`` from ``(N, 2)`` stds (v, w)."""
    s = np.asarray(input_std, dtype=float)
    if s.ndim != 2 or s.shape[1] != 2 or np.any(s < 0.0) or not np.all(np.isfinite(s)):
        raise ValueError(f"input_std must be (N, 2) of non-negative numbers, got {s.shape}")
    return np.diag(np.concatenate([np.repeat(s[:, 0] ** 2, 3), np.repeat(s[:, 1] ** 2, 3)]))


def predict(
    state: Se3EkfState,
    v_body_m_s: ArrayLike,
    w_body_rad_s: ArrayLike,
    dt_s: float,
    input_std: ArrayLike,
) -> Se3EkfState:
    """Prediction step (paper 001 eq. 40-41): ``x+ = f(x, u)``, ``P+ = F P F^T + L Q L^T``."""
    if not (np.isfinite(dt_s) and dt_s > 0.0):
        raise ValueError(f"dt_s must be a positive number, got {dt_s}")
    f, big_l = process_jacobians(state.p_ref, state.rot_ref_body, v_body_m_s, w_body_rad_s, dt_s)
    p_new, rot_new = propagate(state.p_ref, state.rot_ref_body, v_body_m_s, w_body_rad_s, dt_s)
    q = input_covariance(input_std)
    if q.shape[0] != big_l.shape[1]:
        raise ValueError(f"input_std must have {state.n_agents} rows, got {q.shape[0] // 6}")
    cov = f @ state.cov @ f.T + big_l @ q @ big_l.T
    return Se3EkfState(p_new, rot_new, 0.5 * (cov + cov.T))


# ---------------------------------------------------------------------------------------------
# Measurement model (paper 001 eq. 35, 22) and update (eq. 42-43)
# ---------------------------------------------------------------------------------------------


def _check_edges(edges: ArrayLike, n: int) -> IntArray:
    e = np.asarray(edges)
    if e.size == 0 or not np.issubdtype(e.dtype, np.integer):
        raise ValueError("edges must be a non-empty integer array of shape (E, 2)")
    e = e.astype(np.int64).reshape(-1, 2)
    if np.any(e < 0) or np.any(e >= n) or np.any(e[:, 0] == e[:, 1]):
        raise ValueError(f"edge endpoints must be distinct agents in 0..{n - 1}")
    return e


def predicted_bearings(p_ref: ArrayLike, rot_ref_body: ArrayLike, edges: ArrayLike) -> FloatArray:
    """Body-frame bearings the state predicts, ``beta_ij = R_i^T (p_j - p_i)/d_ij`` ``(E, 3)``."""
    p, rot = full_poses(p_ref, rot_ref_body)
    e = _check_edges(edges, len(p))
    r = p[e[:, 1]] - p[e[:, 0]]
    d = np.linalg.norm(r, axis=1)
    if np.any(d < _MIN_DISTANCE_M):
        raise ValueError("two agents coincide in the estimate: bearing undefined")
    return np.einsum("eki,ek->ei", rot[e[:, 0]], r) / d[:, None]


def measurement_jacobian(p_ref: ArrayLike, rot_ref_body: ArrayLike, edges: ArrayLike) -> FloatArray:
    """``H = d beta / d dx`` ``(3E, 6M)``: the SE(3) rigidity matrix without agent 0's columns."""
    p, rot = full_poses(p_ref, rot_ref_body)
    n = len(p)
    e = _check_edges(edges, n)
    full = se3_rigidity_matrix(p, rot, e)
    keep = np.r_[3 : 3 * n, 3 * n + 3 : 6 * n]
    return full[:, keep]


def _linearize(
    p_ref: FloatArray, rot_ref_body: FloatArray, e: IntArray, beta: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Tangent-plane innovation ``y`` ``(2E,)`` and Jacobian ``T^T H`` ``(2E, 6M)`` at a point."""
    beta_hat = predicted_bearings(p_ref, rot_ref_body, e)
    h3 = measurement_jacobian(p_ref, rot_ref_body, e).reshape(len(e), 3, -1)
    basis = tangent_basis(beta_hat)
    y = np.einsum("eka,ek->ea", basis, sphere_log(beta_hat, beta)).ravel()
    return y, np.einsum("eka,ekc->eac", basis, h3).reshape(2 * len(e), -1)


def update(
    state: Se3EkfState,
    edges: ArrayLike,
    beta_body: ArrayLike,
    sigma_rad: float,
    iterations: int = 1,
) -> tuple[Se3EkfState, UpdateStats]:
    """Update with bearings ``beta_body`` ``(E, 3)`` on ``edges`` ``(E, 2)`` (eq. 42-43).

    Tangent-plane innovation per bearing, Joseph-form covariance, retraction (module doc).
    ``iterations = 1`` is the paper's EKF. ``iterations > 1`` is the iterated EKF (Gauss-Newton
    on the manifold): relinearize at the current iterate ``x_i``, with ``D_i`` the tangent
    vector from the prior to ``x_i``, ``x_{i+1} = retract(prior, K_i (y_i + H_i D_i))``; the
    covariance uses the last linearization, so it is consistent with the null space of the
    measurement Jacobian at the estimate (with the plain EKF, a large first correction moves
    the estimate off the linearization point and the covariance loses the scale ambiguity that
    bearings alone leave: tests/onboard/test_se3_ekf.py). Caveat, measured: when the scale is
    unobservable (static agents) the iterated update shrinks the formation step after step
    (the joint MAP prefers small formations, where a bearing correction costs less prior
    displacement): -97% scale after 200 static steps from a 0.5 m prior. Hence the default 1.
    Rows whose measured bearing is not finite or not a unit vector (within 1e-3) are dropped;
    :class:`UpdateStats` reports the innovation's NIS and its degrees of freedom (0 if nothing
    was used).
    """
    if not (np.isfinite(sigma_rad) and sigma_rad > 0.0):
        raise ValueError(f"sigma_rad must be a positive number, got {sigma_rad}")
    if iterations < 1:
        raise ValueError(f"iterations must be >= 1, got {iterations}")
    e = _check_edges(edges, state.n_agents)
    beta = np.asarray(beta_body, dtype=float).reshape(-1, 3)
    if len(beta) != len(e):
        raise ValueError(f"{len(e)} edges but {len(beta)} bearings")
    ok = np.all(np.isfinite(beta), axis=1)
    ok &= np.abs(np.linalg.norm(np.where(ok[:, None], beta, 0.0), axis=1) - 1.0) < 1e-3
    if not np.any(ok):
        return state, UpdateStats(nis=0.0, dof=0)
    e, beta = e[ok], beta[ok]
    p_i, rot_i = state.p_ref, state.rot_ref_body
    r = sigma_rad**2 * np.eye(2 * len(e))
    nis = 0.0
    for it in range(iterations):
        y, h = _linearize(p_i, rot_i, e, beta)
        s = h @ state.cov @ h.T + r
        k = np.linalg.solve(s, h @ state.cov).T
        if it == 0:
            nis = float(y @ np.linalg.solve(s, y))
        offset = local_difference(state.p_ref, state.rot_ref_body, p_i, rot_i)
        p_i, rot_i = retract(state.p_ref, state.rot_ref_body, k @ (y + h @ offset))
    a = np.eye(len(state.cov)) - k @ h
    cov = a @ state.cov @ a.T + k @ r @ k.T
    return Se3EkfState(p_i, rot_i, 0.5 * (cov + cov.T)), UpdateStats(nis=nis, dof=len(e) * 2)


def rotation_error(rot_est: ArrayLike, rot_true: ArrayLike) -> FloatArray:
    """Orientation error of paper 001 eq. 44, ``0.5 tr(I - Rhat^T R)`` per agent, ``(...,)``.

    Zero for a perfect estimate, 2 for an error of ``pi``; equals ``1 - cos(angle)``.
    """
    a = np.asarray(rot_est, dtype=float)
    b = np.asarray(rot_true, dtype=float)
    return 0.5 * (3.0 - np.einsum("...ki,...ki->...", a, b))
