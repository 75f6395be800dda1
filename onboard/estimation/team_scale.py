"""One metric scale for the whole team: the SfM distances fused through the bearings' shape.

Not in the papers; an experiment against issue 22 (docs/equations.md "Fused team scale").
Bearings fix a framework's shape up to scale (angle rigidity, docs/papers.md paper 003): in a triangle
``(a, b, c)`` the angle at each vertex comes from that vertex's own two bearings (one camera,
one body frame: no relative yaw needed), and by the law of sines the side opposite a vertex is
proportional to the sine of its angle. All pairs of a rigid framework therefore share ONE
scale, and each edge's SfM estimate ``1/chihat_ij`` (paper 000 eq. 8) is one noisy measurement
of it. An edge integrates its odometry's velocity bias open loop while the team moves along
its bearings (paper 000: only ``P u`` informs ``chihat``), and the edges of one team pick up
different parts of the vehicles' biases, so their errors partly cancel in the fused scale.

The fusion is a weighted least squares in log distances ``x_e = log d_e``:

    minimize  sum_e w_e (x_e - log(1/chihat_e))^2
            + K sum_triangles sum_(e, f) ((x_e - x_f) - log(sin A_e / sin A_f))^2,

with ``A_e`` the triangle's angle opposite edge ``e`` and ``K = shape_weight * max w``: the
shape is near-hard, the SfM edges vote on the scale with weight ``w_e`` (their excitation
``lambda_e``, paper 000 eq. 9, plus a floor). For one triangle the solution is
``x_e = c + log sin A_e`` with ``c`` the ``w``-weighted mean of ``log(1/chihat_e) - log sin
A_e``. Plain floats and one small numpy solve: it runs at the camera rate, not every step.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

Edge = tuple[int, int]
Vec3 = tuple[float, float, float]

MIN_SINE = 0.05
"""A triangle with an angle whose sine is below this (about 3 degrees, or within 3 degrees of
180: collinear vehicles) has no usable shape; it is left out of the fusion."""


def vertex_angle(b1: Vec3, b2: Vec3) -> float:
    """The angle (rad) between two unit bearings measured by one camera."""
    c = b1[0] * b2[0] + b1[1] * b2[1] + b1[2] * b2[2]
    return math.acos(min(max(c, -1.0), 1.0))


def triangle_log_shape(angles_rad: Sequence[float]) -> tuple[float, float, float] | None:
    """``log sin A`` of a triangle's three vertex angles: the log side lengths opposite them,
    up to one common constant (law of sines). ``None`` when the triangle is (near) degenerate
    (:data:`MIN_SINE`) or the angles do not add up to ``pi`` within 0.2 rad (bearings from
    instants too far apart, or a wrong association)."""
    if len(angles_rad) != 3 or not all(math.isfinite(a) for a in angles_rad):
        return None
    if abs(sum(angles_rad) - math.pi) > 0.2:
        return None
    s = [math.sin(a) for a in angles_rad]
    if min(s) < MIN_SINE:
        return None
    return (math.log(s[0]), math.log(s[1]), math.log(s[2]))


def fused_distances(
    pairs: Sequence[Edge],
    distance_m: Mapping[Edge, float],
    weight: Mapping[Edge, float],
    triangles: Sequence[tuple[tuple[Edge, Edge, Edge], tuple[float, float, float]]],
    shape_weight: float = 1e4,
) -> dict[Edge, float]:
    """Every pair's distance on the team's fused scale (module docstring).

    ``pairs``: the unordered pairs (``a < b``) to solve for; ``distance_m``: the SfM distance
    measured on some of them, ``weight``: its weight (> 0); ``triangles``: ``((e_a, e_b, e_c),
    (l_a, l_b, l_c))``, three pairs of ``pairs`` and the log shape of the side each is
    (:func:`triangle_log_shape`). Returns the pairs whose distance is determined: measured, or
    tied by triangles to a measured pair; a pair with neither is left out. Non-finite or
    non-positive distances and weights are ignored."""
    index = {e: k for k, e in enumerate(pairs)}
    meas = [
        (index[e], math.log(d), w)
        for e, d in distance_m.items()
        if e in index
        and math.isfinite(d)
        and d > 0.0
        and math.isfinite(w := float(weight.get(e, 0.0)))
        and w > 0.0
    ]
    if not meas:
        return {}
    k_shape = shape_weight * max(w for _, _, w in meas)
    rows: list[tuple[dict[int, float], float, float]] = [({k: 1.0}, x, w) for k, x, w in meas]
    # connectivity: measured pairs, then whatever the triangles tie to them
    known = {k for k, _, _ in meas}
    tris = [([index[e] for e in es], ls) for es, ls in triangles if all(e in index for e in es)]
    for ks, ls in tris:
        for m in range(2):
            rows.append(({ks[m]: 1.0, ks[m + 1]: -1.0}, ls[m] - ls[m + 1], k_shape))
    grown = True
    while grown:
        grown = False
        for ks, _ in tris:
            if any(k in known for k in ks) and not all(k in known for k in ks):
                known.update(ks)
                grown = True
    a = np.zeros((len(rows), len(pairs)))
    b = np.zeros(len(rows))
    for r, (coef, rhs, w) in enumerate(rows):
        sw = math.sqrt(w)
        for k, c in coef.items():
            a[r, k] = c * sw
        b[r] = rhs * sw
    x = np.linalg.lstsq(a, b, rcond=None)[0]
    return {pairs[k]: float(math.exp(x[k])) for k in sorted(known)}
