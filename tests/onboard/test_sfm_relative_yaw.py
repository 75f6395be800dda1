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


def _moving(t):
    """Two vehicles crossing and turning: positions (2, 3) and yaws (2,) at time ``t``."""
    p = np.array([[0.3 * t, 0.0, -2.0], [2.5, 1.0 - 0.4 * t, -2.4]])
    return p, np.array([0.2 + 0.5 * t, -1.0 - 0.3 * t])


@pytest.mark.parametrize("late_frames", [0, 3])
def test_unsynchronized_cameras_pair_by_interpolation(late_frames):
    """Real cameras are not synchronized and SITL instances' clocks differ by 10-20 ms: the
    peer's frames fall between the own ones (here 13.7 ms after them, at 30 Hz), never within
    the 5 ms of a stamp match. Interpolated, every peer frame still makes a pair, whether it
    arrives at once or ``late_frames`` own frames later, and the relative yaw is right to well
    under a camera's noise (~1 mrad)."""
    off_i, off_j = 0.7, -2.2
    edge = RelativeYawEdge(gain=1.0)
    worst = 0.0
    in_flight: list[tuple[float, float, tuple]] = []
    for k in range(60):
        t_own, t_peer = k / 30.0, k / 30.0 + 0.0137
        p, yaw = _moving(t_own)
        edge.add_own(t_own, yaw[0] + off_i, _pair(p, yaw)[0])
        p, yaw = _moving(t_peer)
        in_flight.append((t_peer, yaw[1] + off_j, _pair(p, yaw)[1]))
        if len(in_flight) > late_frames:
            edge.add_peer(*in_flight.pop(0))
        if edge.offset_rad is not None:
            psi = edge.psi(yaw[0] + off_i, yaw[1] + off_j)
            worst = max(worst, abs(math.remainder(psi - (yaw[1] - yaw[0]), math.tau)))
    assert edge.pairs >= 58 - late_frames
    assert worst < 2e-4


def test_sample_at_takes_a_near_frame_interpolates_or_refuses():
    from collections import deque

    from onboard.estimation.relative_yaw import sample_at

    s = deque(
        [(0.0, 3.1, (1.0, 0.0, 0.0)), (0.1, -3.1, (0.0, 1.0, 0.0)), (0.5, 0.0, (1.0, 0.0, 0.0))]
    )
    assert sample_at(s, 0.003) == s[0]  # within the stamp tolerance: the frame itself
    t, yaw, b = sample_at(s, 0.05)
    assert t == 0.05
    assert yaw == pytest.approx(math.pi, abs=1e-12) or yaw == pytest.approx(-math.pi, abs=1e-12)
    assert b == pytest.approx((math.sqrt(0.5), math.sqrt(0.5), 0.0))  # renormalized
    assert sample_at(s, 0.3) is None  # frames 0.4 s apart: a gap, not interpolated
    assert sample_at(s, -0.1) is None and sample_at(s, 0.6) is None  # outside the frames


def test_synchronized_cameras_do_not_interpolate_over_a_lost_frame():
    """Frames with equal stamps (one shutter, the headless runner's): a peer frame that was
    lost leaves its own frame unpaired, as the compiled engine does, instead of being
    interpolated from the peer's frames around it."""
    edge = RelativeYawEdge(gain=1.0)
    lost = {3, 7}
    for k in range(12):
        t = k / 50.0
        p, yaw = _moving(t)
        b_ij, b_ji = _pair(p, yaw)
        edge.add_own(t, yaw[0], b_ij)
        if k not in lost:
            edge.add_peer(t, yaw[1], b_ji)
    assert edge.pairs == 12 - len(lost)
