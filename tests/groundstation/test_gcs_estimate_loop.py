"""The estimation loop of ``bearingflock gcs estimate`` (:mod:`groundstation.gcs.ekf_loop`) fed
with synthetic samples: a silent vehicle dropped and re-added, a silent reference handing over,
bad samples counted, the disagreement alarm against the daemons' estimates."""

from __future__ import annotations

import math

import numpy as np
import pytest

from groundstation.gcs.ekf_loop import EkfLoop, EkfLoopConfig, rebase
from messages.peer import BearingShare, MotionShare, TargetBearing
from onboard.estimation.se3_ekf import Se3EkfState, full_poses, initial_state, relative_poses
from onboard.geometry import rot_z

IDS = (1, 2, 3)


def _truth(t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """World positions, velocities, yaws and yaw rates of 3 moving multicopters."""
    p = np.array(
        [
            [0.5 * np.sin(0.4 * t), 0.3 * t, -2.0],
            [3.0 + 1.5 * np.sin(0.9 * t), 1.0, -2.5],
            [1.0 + 1.2 * np.cos(0.6 * t), 3.0 + 1.2 * np.sin(0.6 * t), -1.5],
        ]
    )
    v = np.array(
        [
            [0.2 * np.cos(0.4 * t), 0.3, 0.0],
            [1.35 * np.cos(0.9 * t), 0.0, 0.0],
            [-0.72 * np.sin(0.6 * t), 0.72 * np.cos(0.6 * t), 0.0],
        ]
    )
    yaw = np.array([0.2 + 0.1 * t, 2.0 - 0.05 * t, -1.0])
    rate = np.array([0.1, -0.05, 0.0])
    return p, v, yaw, rate


def _feed(
    loop: EkfLoop,
    t0: float,
    t1: float,
    silent: tuple[int, ...] = (),
    daemon_offset: dict[int, np.ndarray] | None = None,
) -> None:
    """Odometry at 20 Hz, frames and daemon estimates at 5 Hz; ``silent`` vehicles send nothing;
    the daemons report the truth (shifted by ``daemon_offset``) in a frame rotated and moved
    away from the world's (their shared frame is arbitrary)."""
    dt = 0.05
    for k in range(round(t0 / dt), round(t1 / dt)):
        t = k * dt
        p, v, yaw, rate = _truth(t)
        for a, i in enumerate(IDS):
            if i in silent:
                continue
            r = rot_z(yaw[a])
            loop.add_motion(
                MotionShare(
                    sender=i, seq=k, stamp_s=t, v_body=tuple((r.T @ v[a]).tolist()),
                    yaw_rate_rad_s=float(rate[a]), yaw_rad=float(yaw[a]),
                )
            )  # fmt: skip
        if k % 4:
            continue
        for a, i in enumerate(IDS):
            if i in silent:
                continue
            r = rot_z(yaw[a])
            others = [b for b in range(3) if b != a and IDS[b] not in silent]
            beta = [r.T @ (p[b] - p[a]) / np.linalg.norm(p[b] - p[a]) for b in others]
            loop.add_frame(
                BearingShare(
                    sender=i, seq=k, stamp_s=t, yaw_rad=float(yaw[a]),
                    bearings=[
                        TargetBearing(target=IDS[b], beta_body=tuple(v.tolist()))
                        for b, v in zip(others, beta, strict=True)
                    ],
                )
            )  # fmt: skip
            off = (daemon_offset or {}).get(i, np.zeros(3))
            q = rot_z(0.7) @ p[a] + np.array([10.0, -4.0, 0.0]) + off
            loop.add_daemon_estimate(i, t, q, float(yaw[a]) + 0.7)


def _truth_state(t: float, sigma_m: float = 0.05) -> Se3EkfState:
    p, _, yaw, _ = _truth(t)
    p_ref, r_ref = relative_poses(p, np.array([rot_z(y) for y in yaw]))
    return initial_state(p_ref, r_ref, sigma_m, 0.01)


def test_live_team_joins_and_a_silent_vehicle_is_dropped_then_re_added():
    loop = EkfLoop(EkfLoopConfig(silent_s=1.0))
    _feed(loop, 0.0, 2.0)
    assert loop.ids == [1, 2, 3] and loop.state is not None and len(loop.state.p_ref) == 2
    assert [e.kind for e in loop.events] == ["joined", "joined", "joined"]
    _feed(loop, 2.0, 5.0, silent=(3,))
    assert loop.ids == [1, 2] and len(loop.state.p_ref) == 1
    drop = [e for e in loop.events if e.kind == "dropped"]
    assert len(drop) == 1 and drop[0].vehicle == 3 and "silent for" in drop[0].message
    assert 1.0 < drop[0].t_s - 1.95 <= 1.25  # the first frame after 1 s of silence
    _feed(loop, 5.0, 7.0)
    assert loop.ids == [1, 2, 3] and len(loop.state.p_ref) == 2
    assert loop.event_counts == {"joined": 3, "dropped": 1, "re_added": 1}
    assert "re-added" in loop.events[-1].message
    assert np.all(np.isfinite(loop.state.cov)) and np.all(np.isfinite(loop.state.p_ref))
    s = loop.summary()
    assert s["vehicles"] == [1, 2, 3] and s["updates"] == loop.updates > 0
    assert s["event_counts"]["dropped"] == 1


def _error_3_from_2(loop: EkfLoop) -> float:
    """Position error (m) of vehicle 3 in vehicle 2's frame, whoever the filter's reference is."""
    p, _, yaw, _ = _truth(loop.t_s)
    p_true, _ = relative_poses(p[1:], np.array([rot_z(y) for y in yaw[1:]]))
    p_all, r_all = full_poses(loop.state.p_ref, loop.state.rot_ref_body)
    k2, k3 = loop.ids.index(2), loop.ids.index(3)
    p_est, _ = relative_poses(p_all[[k2, k3]], r_all[[k2, k3]])
    return float(np.linalg.norm(p_est[0] - p_true[0]))


def test_a_silent_reference_hands_over_and_keeps_the_estimate():
    loop = EkfLoop(EkfLoopConfig(silent_s=1.0))
    _feed(loop, 0.0, 0.1)
    loop.state = _truth_state(0.0)  # a converged filter: the hand-over must keep it
    _feed(loop, 0.1, 2.0)
    _feed(loop, 2.0, 3.0, silent=(1,))
    assert loop.ids == [1, 2, 3]
    before = _error_3_from_2(loop)
    _feed(loop, 3.0, 3.2, silent=(1,))  # the frame at 3.0 s: 1 is silent for more than 1 s
    assert loop.ids == [2, 3] and len(loop.state.p_ref) == 1
    kinds = [e.kind for e in loop.events]
    assert "reference_changed" in kinds and loop.events[kinds.index("dropped")].vehicle == 1
    assert before < 0.3 and _error_3_from_2(loop) < before + 0.03  # not reset to a prior
    assert np.sqrt(np.max(np.diag(loop.state.cov)[:3])) < 0.5


def test_rebase_is_its_own_inverse_and_matches_relative_poses():
    state = _truth_state(1.3)
    rng = np.random.default_rng(4)
    a = rng.normal(size=(12, 12))
    state = Se3EkfState(state.p_ref, state.rot_ref_body, a @ a.T * 0.01)
    once = rebase(state)
    p, _, yaw, _ = _truth(1.3)
    order = [1, 0, 2]  # vehicle 2 is the reference, then 1 and 3
    p_true, r_true = relative_poses(p[order], np.array([rot_z(yaw[k]) for k in order]))
    assert np.allclose(once.p_ref, p_true) and np.allclose(once.rot_ref_body, r_true)
    twice = rebase(once)
    assert np.allclose(twice.p_ref, state.p_ref) and np.allclose(twice.cov, state.cov, atol=1e-7)


def test_nan_and_stale_samples_are_counted_and_skipped():
    loop = EkfLoop()
    _feed(loop, 0.0, 2.0)
    updates = loop.updates
    nan = MotionShare(
        sender=2, seq=0, stamp_s=2.0, v_body=(math.nan, 0.0, 0.0), yaw_rate_rad_s=0.0, yaw_rad=0.0
    )
    loop.add_motion(nan)
    bad = BearingShare(
        sender=1, seq=0, stamp_s=2.0, yaw_rad=0.0,
        bearings=[
            TargetBearing(target=2, beta_body=(math.nan, 0.0, 1.0)),
            TargetBearing(target=3, beta_body=(0.0, 0.0, 1.0)),
        ],
    )  # fmt: skip
    assert loop.add_frame(bad)  # the good bearing still updates
    late = BearingShare(
        sender=1,
        seq=0,
        stamp_s=0.5,
        yaw_rad=0.0,
        bearings=[TargetBearing(target=2, beta_body=(1.0, 0.0, 0.0))],
    )
    assert not loop.add_frame(late)
    loop.add_daemon_estimate(2, 2.0, (math.inf, 0.0, 0.0), 0.0)
    assert loop.counts["nonfinite_odometry"] == 1
    assert loop.counts["bad_bearing"] == 1
    assert loop.counts["stale_sample"] == 1
    assert loop.counts["nonfinite_daemon_estimate"] == 1
    assert loop.updates == updates + 1 and np.all(np.isfinite(loop.state.p_ref))
    assert loop.latest[2].stamp_s < 2.0  # the NaN odometry was not kept


@pytest.mark.parametrize("offset_m", [0.0, 3.0])
def test_disagreement_with_the_daemons_raises_one_alarm_event(offset_m):
    loop = EkfLoop(EkfLoopConfig(max_disagreement_m=1.0, settle_s=2.0, alarm_hold_s=0.5))
    _feed(loop, 0.0, 0.1)
    loop.state = _truth_state(0.0)
    shift = {3: np.array([offset_m, 0.0, 0.0])}
    _feed(loop, 0.1, 1.9, daemon_offset=shift)
    assert not loop.alarms  # not settled yet
    _feed(loop, 1.9, 2.3, daemon_offset=shift)
    assert not loop.alarms  # settled, but the disagreement has not lasted alarm_hold_s
    _feed(loop, 2.3, 3.0, daemon_offset=shift)
    dis = loop.disagreements()
    assert dis[2] < 0.2  # the daemons' frame is arbitrary: relative poses compare
    if offset_m == 0.0:
        assert dis[3] < 0.2 and not loop.alarms and "disagreement" not in loop.event_counts
        return
    assert dis[3] == pytest.approx(3.0, abs=0.2)
    assert loop.alarms == {3} and loop.event_counts["disagreement"] == 1  # a rising edge
    assert "ALARM vehicle 3" in next(e.message for e in loop.events if e.kind == "disagreement")
    assert loop.summary()["poses"]["3"]["alarm"] is True
    _feed(loop, 3.0, 4.0)  # the daemons agree again
    assert not loop.alarms and loop.event_counts["agreement"] == 1


def test_scale_is_the_formations_size_and_compares_with_the_daemons():
    loop = EkfLoop()
    _feed(loop, 0.0, 0.1)
    loop.state = _truth_state(0.0)
    _feed(loop, 0.1, 1.0)
    p, *_ = _truth(loop.t_s)
    d = [np.linalg.norm(p[a] - p[b]) for a, b in ((0, 1), (0, 2), (1, 2))]
    s = loop.scale()
    assert s["scale_m"] == pytest.approx(np.sqrt(np.mean(np.square(d))), rel=0.02)
    assert s["daemon_scale_ratio"] == pytest.approx(1.0, abs=0.02)
    assert 0.0 < s["scale_rel_sigma"] < 0.1


def test_from_nothing_to_the_metric_scale_without_a_false_alarm():
    """Newcomers enter along a member's bearing: the filter converges from no knowledge (a
    ring prior put them on the wrong side and it settled 15-20 times too large), and the
    settling time keeps its early overconfidence from raising an alarm."""
    loop = EkfLoop()
    _feed(loop, 0.0, 12.0)
    p, *_ = _truth(loop.t_s)
    d = [np.linalg.norm(p[a] - p[b]) for a, b in ((0, 1), (0, 2), (1, 2))]
    assert loop.scale()["scale_m"] == pytest.approx(np.sqrt(np.mean(np.square(d))), rel=0.03)
    assert max(loop.disagreements().values()) < 0.2
    assert not loop.alarms and "disagreement" not in loop.event_counts


def test_monitor_shows_the_ekf_columns_and_turns_the_disagreeing_vehicle_red():
    from pymavlink.dialects.v20 import ardupilotmega as dialect
    from rich.console import Console

    from groundstation.gcs.mavlink_state import MavlinkState
    from groundstation.gcs.monitor import MonitorConfig, render, snapshot

    loop = EkfLoop(EkfLoopConfig(max_disagreement_m=1.0, settle_s=2.0, alarm_hold_s=0.5))
    _feed(loop, 0.0, 0.1)
    loop.state = _truth_state(0.0)
    _feed(loop, 0.1, 3.0, daemon_offset={3: np.array([3.0, 0.0, 0.0])})
    mav, parser, now = MavlinkState(), dialect.MAVLink(None), 50.0
    for vehicle in loop.ids:  # heartbeats of the three vehicles (system id = vehicle + 1)
        enc = dialect.MAVLink(None, srcSystem=vehicle + 1, srcComponent=1)
        (msg,) = parser.parse_buffer(
            dialect.MAVLink_heartbeat_message(2, 3, 209, 4, 4, 3).pack(enc)
        )
        mav.fold(msg, now - 0.5)
    plain = snapshot(mav, None, now, MonitorConfig())
    snap = snapshot(mav, None, now, MonitorConfig(), ekf=loop.summary())
    assert "ekf" not in plain and "ekf_alarm" not in plain["vehicles"][0]
    rows = {r["id"]: r for r in snap["vehicles"]}
    assert rows[3]["ekf_alarm"] and rows[3]["red"] and rows[3]["ekf_disagreement_m"] > 2.5
    assert not rows[2]["ekf_alarm"] and not rows[2]["red"] and rows[2]["ekf_disagreement_m"] < 0.2
    assert 0.0 < rows[2]["ekf_sigma_p_m"] < 0.5
    assert snap["ekf"]["scale_m"] == pytest.approx(loop.scale()["scale_m"], abs=1e-3)
    console = Console(record=True, width=200)
    console.print(render(snap))
    text = console.export_text()
    assert "EKF sd m" in text and "EKF (paper 001" in text
    (row3,) = [ln for ln in text.splitlines() if ln.strip().startswith("3 ")]
    assert "ekf_disagreement" in row3
