"""Reshaping functions of paper 002 and the conditions the convergence proofs need.

* ``f_R`` (eq. 15): ``f_R(x) = 1 - (1 + b x) exp(-b x)``, increasing, quadratic near 0
  (``f_R ~ b^2 x^2 / 2``), saturating for large ``x``; ``f_R'(x) = b^2 x exp(-b x)``, so the SO(3)
  gradient factor ``f_R'(x) / x = b^2 exp(-b x)`` is smooth at 0. ``square`` is the unreshaped
  ``x^2 / 2`` (the baseline the global-convergence benchmark compares against).
* ``f_T`` (eq. 16): any increasing function quadratic near 0; shipped: ``x^2``.
* ``f_C`` (eq. 18-21): decreasing on ``[-1, 1]`` with ``f_C(c) + (1 - c) f_C'(c) <= 0`` (eq. 21).
  Shipped: ``1 - c`` (the flight stack's law, eq. 21 holds with equality) and
  ``1 - c + a (1 - c)^2`` (eq. 21 gives ``-a (1 - c)^2 <= 0`` for ``a >= 0``).
* ``f_D`` (eq. 22-23): differentiable with ``sign(f_D'(x)) = sign(x)``; shipped: ``w x^2`` and the
  Huber function ``w (sqrt(1 + (x/delta)^2) - 1) delta^2`` (pseudo-Huber, robust to range outliers).
  The weight ``w`` expresses how much a range is trusted against a bearing: with bearing noise
  ``sigma_b`` (rad) at distance ``d`` and range noise ``sigma_r`` (m), ``w ~ (sigma_b d / sigma_r)^2``
  puts both on the same footing (paper 002, "Bearing and distance estimation and control").

Every function is elementwise on arrays: ``value(x)`` and ``deriv(x)`` keep the shape of ``x``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import FloatArray

B_DEFAULT = 2.0
"""``b`` of eq. 15 (paper 002 fig. 4)."""


def _a(x: ArrayLike) -> FloatArray:
    return np.asarray(x, dtype=float)


@dataclass(frozen=True)
class ReshapeR:
    """``f_R`` for rotation costs (paper 002 eq. 15); ``b = None`` is the plain ``x^2 / 2``."""

    b: float | None = B_DEFAULT

    def value(self, x: ArrayLike) -> FloatArray:
        x = _a(x)
        if self.b is None:
            return 0.5 * x * x
        return 1.0 - (1.0 + self.b * x) * np.exp(-self.b * x)

    def deriv(self, x: ArrayLike) -> FloatArray:
        x = _a(x)
        if self.b is None:
            return x.copy()
        return self.b * self.b * x * np.exp(-self.b * x)

    def deriv_over_x(self, x: ArrayLike) -> FloatArray:
        """``f_R'(x) / x``, smooth at ``x = 0`` (the factor of the SO(3) gradient)."""
        x = _a(x)
        if self.b is None:
            return np.ones_like(x)
        return self.b * self.b * np.exp(-self.b * x)

    def curvature_bound(self) -> float:
        """``max_x max(|f_R''(x)|, |f_R'(x) / x|)``: ``b^2`` (``1`` unreshaped)."""
        return 1.0 if self.b is None else self.b * self.b


@dataclass(frozen=True)
class ReshapeT:
    """``f_T(x) = x^2`` (paper 002 eq. 6, 16)."""

    def value(self, x: ArrayLike) -> FloatArray:
        x = _a(x)
        return x * x

    def deriv_over_x(self, x: ArrayLike) -> FloatArray:
        """``f_T'(x) / x = 2``: the gradient of ``f_T(|r|)`` is ``2 r``."""
        return np.full_like(_a(x), 2.0)

    def curvature_bound(self) -> float:
        return 2.0


@dataclass(frozen=True)
class ReshapeC:
    """``f_C(c) = (1 - c) + a (1 - c)^2`` (paper 002 eq. 18-21); ``a = 0`` is ``1 - c``, the law
    of :mod:`onboard.control.formation`."""

    a: float = 0.0

    def value(self, c: ArrayLike) -> FloatArray:
        u = 1.0 - _a(c)
        return u + self.a * u * u

    def deriv(self, c: ArrayLike) -> FloatArray:
        u = 1.0 - _a(c)
        return -1.0 - 2.0 * self.a * u

    def gradient_bound(self) -> float:
        """``max_{c in [-1, 1]} |f_C(c)| + |f_C'(c)|``: bounds ``|grad_{T_i} phi_ij|`` (eq. 20)."""
        return (2.0 + 4.0 * self.a) + (1.0 + 4.0 * self.a)


@dataclass(frozen=True)
class ReshapeD:
    """``f_D`` for distance terms (paper 002 eq. 22-23): ``w x^2`` (``delta = None``) or the
    pseudo-Huber ``w delta^2 (sqrt(1 + (x / delta)^2) - 1)``."""

    w: float = 1.0
    delta: float | None = None

    def value(self, x: ArrayLike) -> FloatArray:
        x = _a(x)
        if self.delta is None:
            return self.w * x * x
        return self.w * self.delta**2 * (np.sqrt(1.0 + (x / self.delta) ** 2) - 1.0)

    def deriv(self, x: ArrayLike) -> FloatArray:
        x = _a(x)
        if self.delta is None:
            return 2.0 * self.w * x
        return self.w * x / np.sqrt(1.0 + (x / self.delta) ** 2)

    def curvature_bound(self) -> float:
        return 2.0 * self.w if self.delta is None else self.w


def fc_condition(f: ReshapeC, c: ArrayLike) -> FloatArray:
    """Left side of paper 002 eq. 21, ``f_C(c) + (1 - c) f_C'(c)`` (must be ``<= 0``)."""
    c = _a(c)
    return f.value(c) + (1.0 - c) * f.deriv(c)


def fd_sign_condition(f: ReshapeD, x: ArrayLike) -> bool:
    """``sign(f_D'(x)) == sign(x)`` at every ``x`` (paper 002, after eq. 23)."""
    x = _a(x)
    return bool(np.all(np.sign(f.deriv(x)) == np.sign(x)))


F_R = ReshapeR()
"""Eq. 15 with ``b = 2``."""
F_R_PLAIN = ReshapeR(b=None)
"""Unreshaped ``x^2 / 2``."""
F_T = ReshapeT()
F_C = ReshapeC()
"""``f_C(c) = 1 - c``."""
F_D = ReshapeD()
"""``f_D(x) = x^2``."""
