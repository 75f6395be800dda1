"""``bearingflock gcs estimate --replay``: paper 001's EKF on a gcs record MCAP file."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from groundstation.cli import app
from groundstation.gcs.record import Recorder
from messages.codec import encode
from messages.envelope import kind_of, pack
from messages.keys import peer_key
from messages.peer import BearingShare, MotionShare, TargetBearing
from messages.sim import Truth
from onboard.geometry import rot_z

IDS = (1, 2, 3)


def _truth(t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """World positions, velocities, yaws and yaw rates of 3 multicopters, all moving."""
    p = np.array(
        [
            [0.5 * np.sin(0.4 * t), 0.3 * t, -2.0],
            [3.0 + 1.5 * np.sin(0.9 * t), 1.0, -2.5 + 0.3 * np.sin(0.5 * t)],
            [1.0 + 1.2 * np.cos(0.6 * t), 3.0 + 1.2 * np.sin(0.6 * t), -1.5],
        ]
    )
    v = np.array(
        [
            [0.2 * np.cos(0.4 * t), 0.3, 0.0],
            [1.35 * np.cos(0.9 * t), 0.0, 0.15 * np.cos(0.5 * t)],
            [-0.72 * np.sin(0.6 * t), 0.72 * np.cos(0.6 * t), 0.0],
        ]
    )
    yaw = np.array([0.2 + 0.1 * t, 2.0 - 0.05 * t, -1.0 + 0.3 * np.sin(0.3 * t)])
    rate = np.array([0.1, -0.05, 0.09 * np.cos(0.3 * t)])
    return p, v, yaw, rate


def _record(
    path,
    duration_s: float = 30.0,
    garbage: int = 3,
    silent_after_s: float = 1e9,
    ghost: bool = False,
    envelopes: bool = True,
) -> None:
    """Odometry at 25 Hz, camera frames and truth at 6.25 Hz, as a recorder writes them.

    Vehicle 3's odometry stops after ``silent_after_s``; ``ghost`` adds a bearing to vehicle 9,
    which sends nothing. ``envelopes``: a tick's payloads in one peer envelope, as the daemons
    publish them (issue 27); else one sample per payload, as recordings made before."""
    rec = Recorder(path, "alpha", tlog=False)
    dt = 0.04
    for k in range(int(duration_s / dt)):
        t = k * dt
        p, v, yaw, rate = (x.tolist() for x in _truth(t))
        p, v = np.array(p), np.array(v)
        wall = 1000.0 + t
        for a, i in enumerate(IDS):
            tick = []
            r = rot_z(yaw[a])
            vb = [float(x) for x in r.T @ v[a]]
            motion = MotionShare(
                sender=i, seq=k, stamp_s=t, v_body=tuple(vb), yaw_rate_rad_s=rate[a],
                yaw_rad=yaw[a],
            )  # fmt: skip
            if i != 3 or t < silent_after_s:
                tick.append(motion)
            if k % 4 == 0:
                others = [b for b in range(3) if b != a]
                beta = [r.T @ (p[b] - p[a]) / np.linalg.norm(p[b] - p[a]) for b in others]
                frame = BearingShare(
                    sender=i, seq=k, stamp_s=t, yaw_rad=yaw[a],
                    bearings=[
                        TargetBearing(target=IDS[b], beta_body=tuple(float(x) for x in v))
                        for b, v in zip(others, beta, strict=True)
                    ]
                    + ([TargetBearing(target=9, beta_body=(1.0, 0.0, 0.0))] if ghost else []),
                )  # fmt: skip
                tick.append(frame)
            if envelopes and tick:
                rec.zenoh_sample(peer_key("alpha", i), pack(i, k, tick).data, wall)
            for m in [] if envelopes else tick:
                rec.zenoh_sample(f"bf/alpha/{i}/peer/{kind_of(m)}", encode(m), wall)
            if k % 4 == 0:
                truth = Truth(
                    sender=i, seq=k, stamp_s=t, p_ned=tuple(p[a].tolist()), v_ned=tuple(v[a].tolist()),
                    yaw_rad=yaw[a], yaw_rate_rad_s=rate[a],
                )  # fmt: skip
                rec.zenoh_sample(f"bf/alpha/{i}/truth", encode(truth), wall)
    for _ in range(garbage):
        rec.zenoh_sample(peer_key("alpha", 1), b"\xc1 not msgpack", 1000.0)
    rec.close()


@pytest.mark.parametrize("envelopes", [True, False], ids=["envelopes", "one_per_kind"])
def test_replay_recovers_scale_and_poses_of_a_moving_team(tmp_path, envelopes):
    path = tmp_path / "flight.mcap"
    _record(path, envelopes=envelopes)
    res = CliRunner().invoke(app, ["gcs", "estimate", "--replay", str(path), "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout.strip().splitlines()[-1])
    assert out["vehicles"] == [1, 2, 3] and out["reference"] == 1
    assert out["frames"] == 3 * 188
    assert abs(out["final_scale"] - 1.0) < 0.02
    assert out["scale_error"] < 0.02
    assert max(out["position_error_m"].values()) < 0.1
    assert max(out["rotation_error_deg"].values()) < 2.0
    assert out["skipped"]["undecodable_malformed"] == 3


def test_replay_needs_a_recording_and_live_mode_checks_its_options(tmp_path):
    res = CliRunner().invoke(app, ["gcs", "estimate", "--zenoh", "none"])
    assert res.exit_code == 2 and "listens on Zenoh" in res.output
    res = CliRunner().invoke(app, ["gcs", "estimate", "--duration", "-1"])
    assert res.exit_code == 2 and "--duration" in res.output
    not_mcap = tmp_path / "x.mcap"
    not_mcap.write_bytes(b"nope")
    res = CliRunner().invoke(app, ["gcs", "estimate", "--replay", str(not_mcap)])
    assert res.exit_code == 2
    empty = tmp_path / "empty.mcap"
    Recorder(empty, "alpha", tlog=False).close()
    res = CliRunner().invoke(app, ["gcs", "estimate", "--replay", str(empty), "--json"])
    assert res.exit_code == 1
    assert json.loads(res.stdout.strip().splitlines()[-1])["skipped"] == {
        "fewer_than_2_vehicles_with_odometry": 1
    }


def test_silent_vehicle_and_unknown_targets_are_counted_not_fatal(tmp_path):
    path = tmp_path / "gappy.mcap"
    _record(path, duration_s=4.0, garbage=0, silent_after_s=2.0, ghost=True)
    res = CliRunner().invoke(app, ["gcs", "estimate", "--replay", str(path), "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout.strip().splitlines()[-1])
    assert out["frames"] == 3 * 25
    # last odometry of vehicle 3 at 1.96 s: stale (> 0.5 s) at the frame times 2.56..3.84 s,
    # 9 predictions (one per frame time)
    assert out["skipped"]["stale_odometry"] == 9
    assert out["skipped"]["bearing_to_unknown_vehicle"] == 3 * 25
    assert all(np.isfinite(v).all() for v in out["p_ref_m"].values())


def test_replay_plots_the_estimate_converging_to_the_truth(tmp_path):
    path = tmp_path / "flight.mcap"
    _record(path, garbage=0)
    out = tmp_path / "plots"
    res = CliRunner().invoke(
        app, ["gcs", "estimate", "--replay", str(path), "--json", "--plot", str(out)]
    )
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout.strip().splitlines()[-1])
    names = [p.rsplit("/", 1)[-1] for p in summary["plots"]]
    assert names == ["ekf_distances.png", "ekf_scale_error.png", "ekf_sigma.png"]
    for p in summary["plots"]:
        assert open(p, "rb").read(8) == b"\x89PNG\r\n\x1a\n"


def test_replay_history_starts_on_the_ring_prior_and_ends_at_the_true_distances(tmp_path):
    from groundstation.gcs.ekf_replay import HISTORY_PERIOD_S, replay_estimate

    path = tmp_path / "flight.mcap"
    _record(path, garbage=0)
    r = replay_estimate(path)
    t = np.array([x.t_s for x in r.history])
    assert len(t) > 50 and np.all(np.diff(t) >= HISTORY_PERIOD_S - 1e-9)

    def err(x):
        d = r.true_distances(x.t_s)
        est = [np.linalg.norm(x.p_ref_m[a] - x.p_ref_m[b]) for a, b in r.pairs()]
        return np.max(np.abs(np.array(est) / d - 1.0))

    assert err(r.history[0]) > 0.1  # the ring prior knows nothing of the scale
    assert err(r.history[-1]) < 0.02
    assert r.history[-1].sigma_p_m[0] == 0.0 and np.all(r.history[-1].sigma_p_m[1:] > 0)
    assert np.all(r.history[-1].sigma_p_m[1:] < r.history[0].sigma_p_m[1:])


def test_plot_needs_a_replay():
    res = CliRunner().invoke(app, ["gcs", "estimate", "--plot", "/tmp/x", "--zenoh", "none"])
    assert res.exit_code == 2 and "--plot needs --replay" in res.output
