"""Relative yaw on a reciprocal edge: exact on noiseless data, at any time between frames,
whatever the odometry offsets and the order in which frames arrive."""

import math

import numpy as np
import pytest

from onboard.estimation.relative_yaw import RelativeYawEdge, is_usable_pair, yaw_offset
from onboard.geometry import bearings_body, relative_yaw


def _pair(p, yaw):
    b, _ = bearings_body(p, yaw, np.array([[0, 1], [1, 0]]))
    return tuple(b[0]), tuple(b[1])


def test_offset_is_exact_for_random_configurations():
    rng = np.random.default_rng(3)
    for _ in range(50):
        p = rng.normal(size=(2, 3)) * 3
        yaw = rng.uniform(-math.pi, math.pi, 2)
        off = rng.uniform(-math.pi, math.pi, 2)
        b_ij, b_ji = _pair(p, yaw)
        if not is_usable_pair(b_ij, b_ji):
            continue
        o = yaw_offset(b_ij, b_ji, yaw[0] + off[0], yaw[1] + off[1])
        psi = math.remainder(yaw[1] + off[1] - yaw[0] - off[0] + o, math.tau)
        assert math.remainder(psi - (yaw[1] - yaw[0]), math.tau) == pytest.approx(0.0, abs=1e-12)


def test_scalar_offset_matches_the_geometry_function():
    rng = np.random.default_rng(4)
    for _ in range(200):
        b = rng.normal(size=(2, 3))
        b_ij, b_ji = (tuple(v / np.linalg.norm(v)) for v in b)
        yaw_i, yaw_j = rng.uniform(-math.pi, math.pi, 2)
        psi = float(relative_yaw(np.array(b_ij), np.array(b_ji)))
        expected = math.remainder(psi - (yaw_j - yaw_i), math.tau)
        assert yaw_offset(b_ij, b_ji, yaw_i, yaw_j) == pytest.approx(expected, abs=1e-14)


@pytest.mark.parametrize("peer_first", [False, True])
def test_tracker_follows_rotating_agents_between_frames(peer_first):
    off_i, off_j = 1.3, -2.9  # unknown odometry offsets
    edge = RelativeYawEdge(gain=1.0)
    p = np.array([[0.0, 0.0, -2.0], [2.5, 1.0, -2.4]])
    for k in range(5):
        t = 0.02 * k
        yaw = np.array([0.2 + 0.8 * t, -1.0 - 0.5 * t])
        b_ij, b_ji = _pair(p, yaw)
        own = (t, yaw[0] + off_i, b_ij)
        peer = (t, yaw[1] + off_j, b_ji)
        if peer_first:
            edge.add_peer(*peer)
            edge.add_own(*own)
        else:
            edge.add_own(*own)
            edge.add_peer(*peer)
    assert edge.pairs == 5
    t = 0.137  # between frames
    yaw = np.array([0.2 + 0.8 * t, -1.0 - 0.5 * t])
    psi = edge.psi(yaw[0] + off_i, yaw[1] + off_j)
    assert math.remainder(psi - (yaw[1] - yaw[0]), math.tau) == pytest.approx(0.0, abs=1e-12)


def test_unmatched_or_vertical_pairs_are_ignored():
    edge = RelativeYawEdge()
    assert edge.psi(0.0, 0.0) is None
    edge.add_own(0.0, 0.0, (1.0, 0.0, 0.0))
    edge.add_peer(0.5, 0.0, (-1.0, 0.0, 0.0))  # stamps 0.5 s apart: no pair
    assert edge.psi(0.0, 0.0) is None
    edge.add_own(1.0, 0.0, (0.0, 0.0, 1.0))
    edge.add_peer(1.0, 0.0, (0.0, 0.0, -1.0))  # vertical: undefined
    assert edge.offset_rad is None and edge.pairs == 0
