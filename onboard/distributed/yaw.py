"""The yaw-only case of paper 002's rotation estimation: relative yaws from reciprocal levelled
bearings (paper 002 fig. 6, "Rotation (Yaw) Localization") and eq. 13-15 restricted to rotations
about the vertical (docs/papers.md, Paper 002; docs/equations.md, "Distributed gradient
framework", yaw-only rotations).

**Levelled frames.** Roll and pitch are observed through gravity, so every camera bearing is
rotated into the agent's heading frame (roll and pitch removed, :mod:`onboard.vision.levelling`;
paper 002, "IMU attitude compensation"). The rotation between two heading frames is a yaw:
``iR_j = R_z(psi_ij)``, ``psi_ij = psi_j - psi_i`` (docs/equations.md, "Conventions").

**Relative yaw from a reciprocal pair** (:func:`relative_yaw_from_reciprocal`). ``i`` sees ``j``
along ``beta_ij`` and ``j`` sees ``i`` along ``beta_ji`` (both levelled). The world bearings are
opposite, ``R_i beta_ij = -R_j beta_ji``, hence ``beta_ij = -R_z(psi_ij) beta_ji``: ``psi_ij`` is
the angle from the horizontal projection of ``-beta_ji`` to that of ``beta_ij`` (paper 002 fig. 6,
``psi_21 = theta_12 + pi - theta_21``), the formula of :func:`onboard.geometry.relative_yaw`.
Undefined when a bearing is (nearly) vertical: pairs whose horizontal norm ``h`` is below
``min_horizontal`` are flagged unusable and get ``nan``.

*Noise.* A tangent perturbation ``db`` of a bearing turns its azimuth by ``(e_az . db) / h``
(``e_az`` the horizontal unit vector normal to the bearing's vertical plane, itself tangent to the
sphere). With isotropic bearing noise of RMS angle ``sigma`` (``sigma / sqrt 2`` per tangent
axis), to first order

    std(psi_ij) = (sigma / sqrt 2) sqrt(1 / h_ij^2 + 1 / h_ji^2)   (:func:`relative_yaw_std_rad`)

and for a reciprocal pair ``h_ij = h_ji = cos(elevation)``: ``sigma / cos(elevation)``. Level
vehicles at one altitude get the bearing noise itself (1 deg RMS -> 1 deg); at 60 degrees of
elevation twice it, at ``h = min_horizontal = 0.1`` ten times. A roll/pitch error ``epsilon`` of
the levelling adds about ``epsilon tan(elevation)`` (it tilts the bearing out of its vertical
plane).

**Yaw-only rotation estimation** (paper 002 eq. 13-15 on SO(2)). Pairwise cost
``phi_ij = f_R(|wrap(psi_j - psi_i - psit_ij)|)`` with eq. 15's ``f_R`` (``b = 2``). It *is* eq. 13
for ``R_i = R_z(psi_i)``, ``Rt_ij = R_z(psit_ij)``: then ``w_ij = log(Rt^T R_i^T R_j) = e_ij e3``,
``e_ij = wrap(psi_j - psi_i - psit_ij)``, and the body coordinate ``delta`` of
``R_z(psi) exp(hat(delta e3)) = R_z(psi + delta)`` is an increment of the yaw. So the costs and
gradients here build the ``R_z`` matrices and call :mod:`.rotation` (one implementation of the
formula), keeping the ``e3`` component of its body gradients::

    grad_{psi_j} phi_ij = (f_R'(|e|) / |e|) e_ij = -grad_{psi_i} phi_ij.

The exponential map on SO(2) is angle addition: the step is ``psi <- wrap(psi - h k g)``
(:func:`onboard.distributed.flow.so2_step`) with the SO(3) step rule ``h k = 1 / L``,
``L = 2 b^2 deg_max`` (:func:`onboard.distributed.rotation.rotation_lipschitz`: the yaw Hessian is
a principal block of the SO(3) one, so the bound holds). The global yaw is a gauge: the flow keeps
``sum_i psi_i`` (mod ``2 pi``), since each edge's two gradients cancel; hold one agent as an
anchor or compare modulo a global yaw (:func:`yaw_error_deg`).

Shapes: ``psi`` ``(N,)``, ``edges`` ``(E, 2)``, ``psi_meas`` ``(E,)`` (rad); bearings ``(..., 3)``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from onboard.distributed.flow import EdgeGradients, check_edges
from onboard.distributed.reshaping import F_R, ReshapeR
from onboard.distributed.rotation import rotation_costs, rotation_gradients
from onboard.estimation.relative_yaw import MIN_HORIZONTAL
from onboard.geometry import FloatArray, relative_yaw, rot_z, wrap_angle


class RelativeYaw(NamedTuple):
    """Relative yaws of reciprocal pairs and whether each pair could give one."""

    psi_rad: FloatArray
    """``(...,)`` ``psi_ij = psi_j - psi_i`` in ``[-pi, pi)``; ``nan`` where not ``usable``."""
    usable: np.ndarray
    """``(...,)`` bool: both bearings finite with a horizontal norm ``>= min_horizontal``."""


def _horizontal(b: FloatArray) -> FloatArray:
    return np.hypot(b[..., 0], b[..., 1])


def relative_yaw_from_reciprocal(
    beta_ij_level: ArrayLike, beta_ji_level: ArrayLike, min_horizontal: float = MIN_HORIZONTAL
) -> RelativeYaw:
    """``psi_ij`` from a reciprocal pair of levelled unit bearings ``(..., 3)`` (module docstring;
    paper 002 fig. 6): ``beta_ij = -R_z(psi_ij) beta_ji``.

    A pair with a bearing closer to the vertical than ``min_horizontal`` (horizontal norm of the
    unit vector; the default is the camera layer's :data:`MIN_HORIZONTAL` = 0.1, about 84 degrees
    of elevation) or a non-finite entry is flagged ``usable = False`` and gets ``nan``: its
    horizontal angle is noise (``std(psi) ~ sigma / h``, :func:`relative_yaw_std_rad`).
    ``ValueError`` when the shapes differ or the last axis is not 3."""
    bij = np.asarray(beta_ij_level, dtype=float)
    bji = np.asarray(beta_ji_level, dtype=float)
    if bij.shape != bji.shape or bij.shape[-1:] != (3,):
        raise ValueError(
            f"bearings must be two (..., 3) arrays of one shape: {bij.shape}, {bji.shape}"
        )
    if not min_horizontal > 0:
        raise ValueError("min_horizontal must be positive")
    ok = np.all(np.isfinite(bij), axis=-1) & np.all(np.isfinite(bji), axis=-1)
    with np.errstate(invalid="ignore"):
        ok &= (_horizontal(bij) >= min_horizontal) & (_horizontal(bji) >= min_horizontal)
        psi = relative_yaw(bij, bji)
    return RelativeYaw(psi_rad=np.where(ok, psi, np.nan), usable=ok)


def relative_yaw_std_rad(
    beta_ij_level: ArrayLike, beta_ji_level: ArrayLike, sigma_bearing_rad: float
) -> FloatArray:
    """First-order std of :func:`relative_yaw_from_reciprocal` for isotropic bearing noise of RMS
    angle ``sigma_bearing_rad``: ``(sigma / sqrt 2) sqrt(1 / h_ij^2 + 1 / h_ji^2)``, ``(...,)``
    (``inf`` for a vertical bearing)."""
    bij = np.asarray(beta_ij_level, dtype=float)
    bji = np.asarray(beta_ji_level, dtype=float)
    with np.errstate(divide="ignore"):
        s = 1.0 / _horizontal(bij) ** 2 + 1.0 / _horizontal(bji) ** 2
    return sigma_bearing_rad / np.sqrt(2.0) * np.sqrt(s)


def yaw_errors(psi_rad: ArrayLike, edges: ArrayLike, psi_meas_rad: ArrayLike) -> FloatArray:
    """``e_ij = wrap(psi_j - psi_i - psit_ij)`` per edge, ``(E,)`` in ``[-pi, pi)``."""
    psi = np.asarray(psi_rad, dtype=float).reshape(-1)
    e = check_edges(edges, len(psi))
    return wrap_angle(psi[e[:, 1]] - psi[e[:, 0]] - np.asarray(psi_meas_rad, dtype=float))


def yaw_costs(
    psi_rad: ArrayLike, edges: ArrayLike, psi_meas_rad: ArrayLike, f: ReshapeR = F_R
) -> FloatArray:
    """``phi_ij = f_R(d(R_z(psi_i)^T R_z(psi_j), R_z(psit_ij)))`` (paper 002 eq. 13, 15) per edge:
    ``(E,)``, through :func:`onboard.distributed.rotation.rotation_costs`."""
    psi = np.asarray(psi_rad, dtype=float).reshape(-1)
    return rotation_costs(rot_z(psi), edges, rot_z(np.asarray(psi_meas_rad, dtype=float)), f)


def yaw_gradients(
    psi_rad: ArrayLike, edges: ArrayLike, psi_meas_rad: ArrayLike, f: ReshapeR = F_R
) -> EdgeGradients:
    """Yaw gradients of eq. 13 per edge: ``g_src, g_dst`` ``(E,)`` (rad^-1), the ``e3`` component of
    :func:`onboard.distributed.rotation.rotation_gradients` at ``R_z`` rotations (module docstring).
    Assemble per agent with :func:`onboard.distributed.flow.node_gradient` (``(N,)``)."""
    psi = np.asarray(psi_rad, dtype=float).reshape(-1)
    g = rotation_gradients(rot_z(psi), edges, rot_z(np.asarray(psi_meas_rad, dtype=float)), f)
    return EdgeGradients(g_src=g.g_src[:, 2].copy(), g_dst=g.g_dst[:, 2].copy())


def relative_yaws(psi_rad: ArrayLike, edges: ArrayLike) -> FloatArray:
    """Ideal measurements ``psi_ij = wrap(psi_j - psi_i)`` per edge: ``(E,)``."""
    psi = np.asarray(psi_rad, dtype=float).reshape(-1)
    e = check_edges(edges, len(psi))
    return wrap_angle(psi[e[:, 1]] - psi[e[:, 0]])


def yaw_error_deg(est_rad: ArrayLike, true_rad: ArrayLike) -> float:
    """Largest ``|wrap(est_i + g - true_i)|`` in degrees after the best global yaw ``g`` (the
    circular mean of ``true - est``: :func:`onboard.distributed.metrics.align_rotations`
    restricted to yaws)."""
    est = np.asarray(est_rad, dtype=float).reshape(-1)
    true = np.asarray(true_rad, dtype=float).reshape(-1)
    d = true - est
    g = np.arctan2(np.sin(d).sum(), np.cos(d).sum())
    return float(np.degrees(np.max(np.abs(wrap_angle(est + g - true)))))
