"""Smooth sensing weights: how much an edge counts when it nears the edge of range or view.

Paper 003, section 4.3.2, eq. (17)-(18): a bearing ``(i, j)`` is measured only while ``j`` is
within ``i``'s sensing range and inside its camera cone (eq. 15). To make the rigidity
eigenvalue a smooth function of the poses, every edge gets a weight

    ``w_ij = w_range(d_ij) * w_fov(c_i . b_ij)``,

with ``c_i = R_z(psi_i) e1`` the camera axis (body x of a level vehicle, NED) and ``b_ij`` the
world-frame unit bearing. Each factor is a C^1 smooth step from 1 (well inside range / view)
to 0 (at the sensing range / at the edge of the field of view). The step of eq. (17) lost its
symbols in extraction; this module uses the cubic "smoothstep", the lowest-degree polynomial
with matching values and zero slopes at both ends, which is exactly C^1 (equations.md,
"Angle rigidity": weights).

Every weight comes with its derivative, so gradients built on it are analytic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache

import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import FloatArray, bearings_world, camera_axis_ned


def smooth_step(x: ArrayLike, x_one: float, x_zero: float) -> tuple[FloatArray, FloatArray]:
    """C^1 step equal to 1 at and beyond ``x_one`` and 0 at and beyond ``x_zero``; its derivative.

    With ``t = clip((x - x_one) / (x_zero - x_one), 0, 1)`` the step is ``1 - 3 t^2 + 2 t^3``
    and its derivative ``-6 t (1 - t) / (x_zero - x_one)``: both ends are flat, so value and
    slope are continuous everywhere (paper 003 eq. 17, cubic form). Works in either direction
    (``x_zero`` above or below ``x_one``); ``x_one == x_zero`` is rejected (a hard step).
    """
    _check_ends(x_one, x_zero)
    return _cubic_step(np.asarray(x, dtype=float), x_one, x_zero - x_one)


def _check_ends(x_one: float, x_zero: float) -> None:
    if not (math.isfinite(x_one) and math.isfinite(x_zero)) or x_one == x_zero:
        raise ValueError(f"smooth_step needs finite, distinct ends, got {x_one!r}, {x_zero!r}")


def _cubic_step(
    x: FloatArray, x_one: float | FloatArray, width: float | FloatArray
) -> tuple[FloatArray, FloatArray]:
    """:func:`smooth_step` with checked ends, ``width = x_zero - x_one`` (ends may be arrays
    that broadcast against ``x``)."""
    t = np.clip((x - x_one) / width, 0.0, 1.0)
    value = 1.0 - t * t * (3.0 - 2.0 * t)
    slope = -6.0 * t * (1.0 - t) / width
    return value, slope


@dataclass(frozen=True)
class SensingModel:
    """A camera with a limited range and field of view, and where its weights roll off.

    ``fov_deg`` is the full cone angle around the optical axis (``j`` is seen when the angle
    between ``c_i`` and ``b_ij`` is below ``fov_deg / 2``, as in ``graph.sensing_graph``);
    ``fov_deg >= 360`` means an all-round sensor (fov weight 1). ``range_m`` may be ``inf``
    (range weight 1).

    The transition zones are the outer fractions of each limit: the range weight falls from 1
    at ``(1 - range_transition) * range_m`` to 0 at ``range_m``; the fov weight falls from 1 at
    the half-angle ``(1 - fov_transition) * fov/2`` to 0 at ``fov/2`` (as a step in the
    cosine). The default 20 % keeps most of the sensed volume at full weight while giving the
    controller a warning zone before a measurement is lost.
    """

    fov_deg: float
    range_m: float
    range_transition: float = 0.2
    fov_transition: float = 0.2

    def __post_init__(self) -> None:
        if not (math.isfinite(self.fov_deg) and self.fov_deg > 0.0):
            raise ValueError(f"fov_deg must be a positive finite angle, got {self.fov_deg!r}")
        if math.isnan(self.range_m) or self.range_m <= 0.0:
            raise ValueError(f"range_m must be positive (inf allowed), got {self.range_m!r}")
        for name in ("range_transition", "fov_transition"):
            frac = getattr(self, name)
            if not (0.0 < frac <= 1.0):
                raise ValueError(f"{name} must be in (0, 1], got {frac!r}")

    @property
    def all_round(self) -> bool:
        """True when the camera sees in every direction (no fov roll-off)."""
        return self.fov_deg >= 360.0

    @property
    def range_full_m(self) -> float:
        """Distance up to which the range weight is exactly 1."""
        return (1.0 - self.range_transition) * self.range_m

    @property
    def cos_fov_full(self) -> float:
        """Cosine of the half-angle up to which the fov weight is exactly 1."""
        return math.cos((1.0 - self.fov_transition) * math.radians(self.fov_deg) / 2.0)

    @property
    def cos_fov_edge(self) -> float:
        """Cosine of the half field of view, where the fov weight reaches 0."""
        return math.cos(math.radians(self.fov_deg) / 2.0)


def range_weight(d_m: ArrayLike, model: SensingModel) -> tuple[FloatArray, FloatArray]:
    """Range weight ``w_range(d)`` and ``d w_range / d d`` (paper 003 eq. 17-18)."""
    d = np.asarray(d_m, dtype=float)
    if math.isinf(model.range_m):
        return np.ones_like(d), np.zeros_like(d)
    return smooth_step(d, model.range_full_m, model.range_m)


def fov_weight(cos_axis: ArrayLike, model: SensingModel) -> tuple[FloatArray, FloatArray]:
    """Field-of-view weight ``w_fov(c)`` of ``c = c_i . b_ij`` and ``d w_fov / d c`` (eq. 17-18)."""
    c = np.asarray(cos_axis, dtype=float)
    if model.all_round:
        return np.ones_like(c), np.zeros_like(c)
    return smooth_step(c, model.cos_fov_full, model.cos_fov_edge)


def sensing_weights(
    d_m: FloatArray, cos_axis: FloatArray, model: SensingModel
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """:func:`range_weight` of ``d_m`` and :func:`fov_weight` of ``cos_axis`` (both ``(M,)``):
    ``(w_range, dw_range/dd, w_fov, dw_fov/dcos)`` (paper 003 eq. 17-18).

    The two smooth steps are evaluated together, as the rows of one ``(2, M)`` array (one
    numpy call per operation instead of two: this runs for every star, every step)."""
    if math.isinf(model.range_m) or model.all_round:
        return (*range_weight(d_m, model), *fov_weight(cos_axis, model))
    value, slope = _cubic_step(np.array((d_m, cos_axis), dtype=float), *_step_rows(model))
    return value[0], slope[0], value[1], slope[1]


@cache
def _step_rows(model: SensingModel) -> tuple[FloatArray, FloatArray]:
    """``x_one`` and ``x_zero - x_one`` of the range and fov steps as ``(2, 1)`` columns."""
    x_one = (model.range_full_m, model.cos_fov_full)
    x_zero = (model.range_m, model.cos_fov_edge)
    for one, zero in zip(x_one, x_zero, strict=True):
        _check_ends(one, zero)
    columns = (
        np.array([[x_one[0]], [x_one[1]]]),
        np.array([[x_zero[0] - x_one[0]], [x_zero[1] - x_one[1]]]),
    )
    for a in columns:
        a.flags.writeable = False
    return columns


@dataclass(frozen=True)
class EdgeWeights:
    """Per-edge weight factors and their derivatives, all arrays of shape ``(E,)``.

    ``cos_axis`` is ``c_i . b_ij``; the edge weight is ``w = w_range * w_fov``.
    """

    w_range: FloatArray
    dw_range_dd: FloatArray
    w_fov: FloatArray
    dw_fov_dcos: FloatArray
    cos_axis: FloatArray

    @property
    def w(self) -> FloatArray:
        """Edge weights ``w_ij = w_range(d_ij) w_fov(c_i . b_ij)`` (paper 003 eq. 18)."""
        return self.w_range * self.w_fov


def edge_weights(
    p_ned: ArrayLike, yaw_rad: ArrayLike, edges: ArrayLike, model: SensingModel
) -> EdgeWeights:
    """Weights of every edge ``(i, j)`` seen by ``i``'s body-x camera (paper 003 eq. 17-18).

    ``p_ned`` is ``(N, 3)``, ``yaw_rad`` is ``(N,)`` and ``edges`` is ``(E, 2)``.
    """
    b, d = bearings_world(p_ned, edges)
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    c_axis = camera_axis_ned(np.asarray(yaw_rad, dtype=float)[e[:, 0]])
    cos_axis = np.einsum("ed,ed->e", c_axis[:, : b.shape[1]], b)
    w_r, dw_r = range_weight(d, model)
    w_f, dw_f = fov_weight(cos_axis, model)
    return EdgeWeights(w_r, dw_r, w_f, dw_f, cos_axis)
