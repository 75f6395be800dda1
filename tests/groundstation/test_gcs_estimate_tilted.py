"""The ground station's EKF loop (:mod:`groundstation.gcs.ekf_loop`) fed a tilted team's raw
sensors: un-levelled body bearings, gyro and body velocity plus the autopilot's attitude
(ATTITUDE and ATTITUDE_QUATERNION) give the scale and poses of the levelled samples; bad
attitude is counted and skipped."""

from __future__ import annotations

import math

import numpy as np
import pytest

from groundstation.gcs.ekf_loop import EkfLoop, EkfLoopConfig
from messages.peer import BearingShare, MotionShare, TargetBearing
from onboard.estimation.se3_ekf import initial_state, relative_poses
from onboard.estimation.se3_inputs import euler_from_rotation
from onboard.geometry import rot_z
from sim.se3_runner import TiltedTeam, TiltedTeamConfig, tilted_team

ATT_SIGMA_RAD = math.radians(0.3)
CFG = EkfLoopConfig(
    bearing_sigma_rad=math.radians(1.0),
    velocity_sigma_m_s=0.05,
    rate_sigma_rad_s=0.01,
    attitude_sigma_rad=ATT_SIGMA_RAD,
    settle_s=1e9,
)


def _quaternion(rot: np.ndarray) -> tuple[float, float, float, float]:
    """``(w, x, y, z)`` of a rotation (from its ZYX angles, half-angle products)."""
    roll, pitch, yaw = (0.5 * a for a in euler_from_rotation(rot))
    cr, sr, cp, sp, cy, sy = (f(a) for a in (roll, pitch, yaw) for f in (math.cos, math.sin))
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


@pytest.fixture(scope="module")
def team() -> TiltedTeam:
    return tilted_team(TiltedTeamConfig(duration_s=12.0, attitude_noise_rad=ATT_SIGMA_RAD))


@pytest.fixture(scope="module")
def levelled(team) -> EkfLoop:
    loop = _loop(team)
    _feed_levelled(loop, team)
    return loop


def _loop(team: TiltedTeam) -> EkfLoop:
    """A known team, both loops from the same prior: the true relative heading poses 30% too
    large, yaws 10 degrees off."""
    n = team.p_ned.shape[1]
    loop = EkfLoop(CFG, fixed_ids=list(range(n)))
    p, r = relative_poses(team.p_ned[0], rot_z(team.yaw_rad[0]))
    loop.state = initial_state(1.3 * p, r @ rot_z(np.full(n - 1, 0.17)), 1.5, 0.5)
    return loop


def _feed_levelled(loop: EkfLoop, team: TiltedTeam) -> None:
    n = team.p_ned.shape[1]
    for k, t in enumerate(team.t_s):
        for i in range(n):
            mine = np.flatnonzero(team.edges[:, 0] == i)
            loop.add_frame(
                BearingShare(
                    sender=i,
                    stamp_s=float(t),
                    yaw_rad=float(team.yaw_rad[k, i]),
                    bearings=[
                        TargetBearing(int(team.edges[e, 1]), tuple(team.beta_level[k, e]))
                        for e in mine
                    ],
                )
            )
        for i in range(n):
            loop.add_motion(
                MotionShare(
                    sender=i,
                    stamp_s=float(t),
                    v_body=tuple(team.v_heading_m_s[k, i]),
                    yaw_rate_rad_s=float(team.yaw_rate_rad_s[k, i]),
                    yaw_rad=float(team.yaw_rad[k, i]),
                )
            )


def _feed_raw(loop: EkfLoop, team: TiltedTeam, bad: bool = False) -> None:
    """Even vehicles send ATTITUDE, odd ones ATTITUDE_QUATERNION; samples up to 50 ms after a
    frame are in before it. ``bad``: a NaN attitude, non-unit and out-of-range quaternions, a
    repeated stamp and a frame of a vehicle without attitude are mixed in."""
    n = team.p_ned.shape[1]
    a = 0
    for k, t in enumerate(team.t_s):
        while a < len(team.attitude_t_s) and team.attitude_t_s[a] <= t + 0.05:
            ta = float(team.attitude_t_s[a])
            for i in range(n):
                rot = team.attitude_rot[a, i]
                if i % 2 == 0:
                    loop.add_attitude(i, ta, *euler_from_rotation(rot))
                else:
                    loop.add_attitude_quaternion(i, ta, _quaternion(rot))
            if bad and a % 25 == 7:
                loop.add_attitude(0, ta + 0.001, float("nan"), 0.0, 0.0)
                loop.add_attitude_quaternion(1, ta + 0.001, (1.05, 0.0, 0.0, 0.0))
                loop.add_attitude_quaternion(3, ta + 0.001, (math.cos(0.8), math.sin(0.8), 0, 0))
                loop.add_attitude(2, ta, *euler_from_rotation(team.attitude_rot[a, 2]))
            a += 1
        if bad and k % 50 == 3:
            loop.add_body_frame(9, float(t), [(0, (1.0, 0.0, 0.0))])
        for i in range(n):
            mine = np.flatnonzero(team.edges[:, 0] == i)
            loop.add_body_frame(
                i, float(t), [(int(team.edges[e, 1]), team.beta_body[k, e]) for e in mine]
            )
        for i in range(n):
            loop.add_body_motion(i, float(t), team.v_body_m_s[k, i], team.w_body_rad_s[k, i])


def test_unlevelled_bearings_and_attitude_give_the_levelled_scale_and_poses(team, levelled):
    """12 s, 4 vehicles tilting up to 15 degrees, 1 degree bearings, 0.3 degree attitude noise:
    the raw path ends within 2 cm, 0.3 degree of yaw and 0.3% of scale of the levelled one, and
    both within 5 cm and 2% of the truth."""
    lev, raw = levelled, _loop(team)
    _feed_raw(raw, team)
    assert raw.updates == lev.updates == len(team.t_s) * team.p_ned.shape[1]
    assert raw.counts == lev.counts == {}
    p_true = relative_poses(team.p_ned[-1], rot_z(team.yaw_rad[-1]))[0]
    true_size = math.sqrt(np.mean(np.sum(p_true**2, axis=1)))
    poses_lev, poses_raw = lev.poses(), raw.poses()
    for i in range(1, 4):
        p_l, yaw_l, _ = poses_lev[i]
        p_r, yaw_r, _ = poses_raw[i]
        assert np.linalg.norm(p_r - p_l) < 0.02
        assert abs(math.remainder(yaw_r - yaw_l, math.tau)) < math.radians(0.3)
        assert np.linalg.norm(p_r - p_true[i - 1]) < 0.05
        yaw_true = team.yaw_rad[-1, i] - team.yaw_rad[-1, 0]
        assert abs(math.remainder(yaw_r - yaw_true, math.tau)) < math.radians(1.0)
    s_l, s_r = lev.scale()["scale_m"], raw.scale()["scale_m"]
    assert s_r == pytest.approx(s_l, rel=0.003)
    est = np.array([poses_raw[i][0] for i in range(1, 4)])
    assert math.sqrt(np.mean(np.sum(est**2, axis=1))) == pytest.approx(true_size, rel=0.02)


def test_body_bearings_without_levelling_would_miss(team, levelled):
    """The raw bearings fed as if they were levelled (what a caller without the attitude
    would do): positions off by several times the levelled error."""
    lev, wrong = levelled, _loop(team)
    unlevelled = TiltedTeam(**{**team.__dict__, "beta_level": team.beta_body})
    _feed_levelled(wrong, unlevelled)
    p_true = relative_poses(team.p_ned[-1], rot_z(team.yaw_rad[-1]))[0]
    err = [
        max(np.linalg.norm(lp.poses()[i][0] - p_true[i - 1]) for i in range(1, 4))
        for lp in (lev, wrong)
    ]
    assert err[1] > 0.2 and err[1] > 5 * err[0]


def test_bad_attitude_is_counted_and_skipped(team):
    """Every bad sample is counted by name and changes nothing: the estimate is the clean
    run's to 1e-12."""
    short = TiltedTeam(
        **{
            k: (v[: 5 * 50 + 1] if k not in ("edges", "attitude_t_s", "attitude_rot") else v)
            for k, v in team.__dict__.items()
        }
    )
    clean, dirty = _loop(short), _loop(short)
    _feed_raw(clean, short)
    _feed_raw(dirty, short, bad=True)
    c = dirty.counts
    assert c["nonfinite_attitude"] == c["non_unit_quaternion"] == c["attitude_out_of_range"]
    assert c["nonfinite_attitude"] > 10 and c["stale_attitude"] == c["nonfinite_attitude"]
    assert c["no_attitude"] == 5  # vehicle 9: frames at 0.06, 1.06, .., 4.06 s
    assert set(c) == {
        "nonfinite_attitude",
        "non_unit_quaternion",
        "attitude_out_of_range",
        "stale_attitude",
        "no_attitude",
    }
    np.testing.assert_allclose(dirty.state.p_ref, clean.state.p_ref, atol=1e-12)
    np.testing.assert_allclose(dirty.state.cov, clean.state.cov, atol=1e-12)


def test_body_samples_without_attitude_or_with_nan_are_counted():
    loop = EkfLoop(CFG, fixed_ids=[0, 1])
    assert loop.add_body_frame(0, 1.0, [(1, (1.0, 0.0, 0.0))]) is False
    loop.add_body_motion(0, 1.0, (1.0, 0.0, 0.0), (0.0, 0.0, 0.1))
    assert loop.counts == {"no_attitude": 2}
    loop.add_attitude(0, 1.0, 0.1, 0.05, 0.3)
    loop.add_body_motion(0, 1.0, (float("nan"), 0.0, 0.0), (0.0, 0.0, 0.1))
    loop.add_body_motion(0, 1.0, (1.0, 0.0), (0.0, 0.0, 0.1))
    assert loop.counts["nonfinite_odometry"] == 2
    loop.add_body_frame(0, 1.0, [(1, (float("nan"), 0.0, 0.0)), (1, (2.0, 0.0, 0.0))])
    assert loop.counts["bad_bearing"] == 2  # the NaN one, the non-unit one
    # the attitude 1 s later than the motion's stamp is too far (0.25 s): not used
    loop.add_body_motion(0, 2.0, (1.0, 0.0, 0.0), (0.0, 0.0, 0.1))
    assert loop.counts["no_attitude"] == 3
    loop.add_body_motion(0, 1.1, (1.0, 0.0, 0.0), (0.0, 0.0, 0.1))
    m = loop.latest[0]
    assert m.yaw_rad == pytest.approx(0.3) and np.linalg.norm(m.v_body) == pytest.approx(1.0)
    assert m.v_body[2] == pytest.approx(-math.sin(0.05))  # pitched up: forward flight climbs
