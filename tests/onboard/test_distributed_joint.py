"""Paper 002's third mutual-localization stage (eq. 13 + 16, onboard/distributed/joint.py):
gradients against finite differences (rotations through the exponential map), the joint flow
from the two-stage result, and the three stages on noiseless relative poses."""

from __future__ import annotations

import numpy as np

from onboard.distributed.joint import (
    joint_costs,
    joint_gradients,
    localize_joint,
    mutual_localization,
    world_bearings,
)
from onboard.distributed.metrics import position_error_m, rotation_error_deg
from onboard.distributed.rotation import relative_rotations
from onboard.geometry import so3_exp


def _problem(seed: int, n: int = 8, rot_noise_rad: float = 0.0, bearing_noise_rad: float = 0.0):
    rng = np.random.default_rng(seed)
    und = {(i, (i + 1) % n) for i in range(n)} | {(i, (i + 3) % n) for i in range(n)}
    e = np.array(sorted(und))
    p = rng.uniform(-5, 5, (n, 3))
    r = so3_exp(rng.normal(0, 1.0, (n, 3)))
    d = p[e[:, 1]] - p[e[:, 0]]
    beta = np.einsum("eba,eb->ea", r[e[:, 0]], d / np.linalg.norm(d, axis=1)[:, None])
    beta = beta + rng.normal(0, bearing_noise_rad, beta.shape)
    beta /= np.linalg.norm(beta, axis=1)[:, None]
    meas = relative_rotations(r, e) @ so3_exp(rng.normal(0, rot_noise_rad, (len(e), 3)))
    return rng, e, p, r, beta, meas


def _total(rot, t, lam, e, meas, beta) -> float:
    return float(np.sum(joint_costs(rot, t, lam, e, meas, beta)))


def test_joint_gradients_match_finite_differences() -> None:
    rng, e, _, _, beta, meas = _problem(1, rot_noise_rad=0.1, bearing_noise_rad=0.05)
    n = 8
    rot = so3_exp(rng.normal(0, 1.0, (n, 3)))
    t = rng.normal(0, 3, (n, 3))
    lam = rng.uniform(1, 4, len(e))
    g = joint_gradients(rot, t, lam, e, meas, beta)
    h = 1e-6
    for i in (0, 3, 7):
        for k in range(3):
            d = np.zeros((n, 3))
            d[i, k] = h
            up = _total(rot @ so3_exp(d), t, lam, e, meas, beta)
            dn = _total(rot @ so3_exp(-d), t, lam, e, meas, beta)
            assert abs((up - dn) / (2 * h) - g.g_rot[i, k]) < 1e-5 * (1 + abs(g.g_rot[i, k]))
            tp, tm = t.copy(), t.copy()
            tp[i, k] += h
            tm[i, k] -= h
            fd = (_total(rot, tp, lam, e, meas, beta) - _total(rot, tm, lam, e, meas, beta)) / (
                2 * h
            )
            assert abs(fd - g.g_t[i, k]) < 1e-5 * (1 + abs(fd))
    for m in (0, 5, len(e) - 1):
        lp, lm = lam.copy(), lam.copy()
        lp[m] += h
        lm[m] -= h
        fd = (_total(rot, t, lp, e, meas, beta) - _total(rot, t, lm, e, meas, beta)) / (2 * h)
        assert abs(fd - g.g_lam[m]) < 1e-5 * (1 + abs(fd))


def test_joint_flow_from_two_stage_result_descends_and_keeps_lambda() -> None:
    """Noisy relative poses (3 deg rotations, 2 deg bearings): stages 1-2, then the joint flow
    from their result. Its cost never rises, ends below the start, ``lambda >= 1`` throughout."""
    rng, e, p, r, beta, meas = _problem(2, rot_noise_rad=0.03, bearing_noise_rad=0.035)
    res = mutual_localization(
        e,
        meas,
        beta,
        so3_exp(rng.normal(0, 2.0, (8, 3))),
        rng.normal(0, 5, (8, 3)),
        rng.uniform(1, 4, len(e)),
        rounds=(2000, 3000, 0),
    )
    j = localize_joint(
        e, meas, beta, res.rotations.rot, res.translations.t, res.translations.lam, 1500
    )
    assert np.all(np.diff(j.cost) <= 1e-12 * j.cost[0])
    assert j.cost[-1] < 0.9 * j.cost[0]
    assert j.lam_min_seen >= 1.0 and np.all(j.lam >= 1.0)
    # the joint start is the two-stage result, priced by the joint cost
    two = _total(res.rotations.rot, res.translations.t, res.translations.lam, e, meas, beta)
    assert abs(j.cost[0] - two) < 1e-9 * two
    assert rotation_error_deg(j.rot, r) < 10.0
    assert position_error_m(j.t, p) < 2.0


def test_three_stages_recover_the_truth_from_noiseless_relative_poses() -> None:
    rng, e, p, r, beta, meas = _problem(3)
    res = mutual_localization(
        e,
        meas,
        beta,
        so3_exp(rng.normal(0, 2.0, (8, 3))),
        rng.normal(0, 5, (8, 3)),
        rng.uniform(1, 4, len(e)),
        rounds=(3000, 3000, 500),
    )
    j = res.joint
    assert rotation_error_deg(j.rot, r) < 1e-4
    assert position_error_m(j.t, p) < 1e-4 * 10.0
    assert j.lam_min_seen >= 1.0
    assert j.cost[-1] < 1e-10
    u = world_bearings(j.rot, e, beta)
    d = j.t[e[:, 1]] - j.t[e[:, 0]]
    assert np.allclose(d, j.lam[:, None] * u, atol=1e-5)
