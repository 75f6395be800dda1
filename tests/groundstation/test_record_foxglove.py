"""Recordings Foxglove shows as they are: every channel JSON with a JSON Schema that validates
its messages, the team in Foxglove's 3D schemas, MAVLink also as a ``.tlog`` that pymavlink
reads, and recordings of the earlier schema-less format still read (issue 29)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import msgspec
import numpy as np
from mcap.writer import Writer
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2
from typer.testing import CliRunner

from groundstation.gcs.foxglove_scene import (
    EDGE_BOTH_ALPHA,
    FRUSTUM_LENGTH_M,
    NED_IN_ENU,
    SCENE_SCHEMA_NAME,
    SCENE_TOPIC,
    TRANSFORMS_SCHEMA_NAME,
    TRANSFORMS_TOPIC,
    SceneBuilder,
    align_estimates,
    weight_color,
    yaw_quaternion,
)
from groundstation.gcs.record import (
    CHUNK_BYTES,
    LIVELINESS_ENCODING,
    ZENOH_ENCODING,
    Recorder,
    Source,
    iter_records,
    read_recording,
    tlog_path,
)
from groundstation.gcs_cli import gcs_app
from messages.codec import decode, encode
from messages.envelope import pack, unpack
from messages.image import Image
from messages.peer import MotionShare
from messages.rigidity import RigidityEigenShare
from messages.sim import CameraBearings, SimClock, Truth
from tests.groundstation.standin import StandinConfig, scripted_status

T0 = 1_700_000_000.0


def mavlink_frames(sysid: int) -> list:
    """Real MAVLink 2 frames of system ``sysid``, parsed back as a listener hands them over."""
    mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=1)
    parser = mavlink2.MAVLink(None)
    out = []
    for msg in (
        mavlink2.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3),
        mavlink2.MAVLink_global_position_int_message(1000, 1, 2, 3, 4, 5, 6, 7, 8),
        mavlink2.MAVLink_statustext_message(6, b"Takeoff detected"),
        mavlink2.MAVLink_attitude_message(10, math.nan, 0.25, 0.3, 0.0, 0.0, 0.0),
        mavlink2.MAVLink_battery_status_message(
            0, 0, 0, 2500, [4000] * 10, 100, 10, 5, 80, 600, 1, [0] * 4, 0, 0
        ),  # arrays, laid out on the wire in another order than declared
    ):
        raw = bytes(msg.pack(mav))
        out.append((parser.parse_char(raw), raw))
    return out


def write_team(path: Path, chunk_bytes: int = CHUNK_BYTES) -> Recorder:
    """Two flying stand-in agents with truth and camera bearings, clock, a broken sample, a
    liveliness token and MAVLink of both vehicles, over 2 s."""
    rec = Recorder(path, "alpha", chunk_bytes=chunk_bytes)
    cfg = StandinConfig("alpha", [0, 1])
    rec.alive("bf/alpha/0/alive", True, T0)
    for k in range(20):
        t = T0 + 0.1 * k
        for i in (0, 1):
            status = scripted_status(cfg, i, 0.1 * k, k, "flying")
            rec.zenoh_sample(f"bf/alpha/{i}/status", encode(status), t)
            truth = Truth(sender=i, p_ned=(4.0 * i, 0.1 * k, -5.0), v_ned=(0.0, 1.0, 0.0),
                          yaw_rad=0.3 * i, yaw_rate_rad_s=0.0)  # fmt: skip
            rec.zenoh_sample(f"bf/alpha/{i}/truth", encode(truth), t)
            cam = CameraBearings(sender=i, targets=[1 - i], beta_body=[(1.0, 0.0, 0.0)])
            rec.zenoh_sample(f"bf/alpha/{i}/camera/bearings", encode(cam), t)
        clock = SimClock(sender=0, t_s=0.1 * k, step=k, speedup=1.0, lockstep=False)
        rec.zenoh_sample("bf/alpha/sim/clock", encode(clock), t)
    eigen = RigidityEigenShare(sender=1, lambda_hat=0.5, targets=[0], state=np.arange(4.0),
                               per_target=np.array([0.25, -1.0]), round=3)  # fmt: skip
    motion = MotionShare(sender=1, v_body=(0.5, 0.0, 0.0), yaw_rate_rad_s=0.1, yaw_rad=0.2)
    rec.zenoh_sample("bf/alpha/1/peer", pack(1, 1, [motion, eigen]).data, T0 + 1.0)
    jpeg = Image(sender=0, width=2, height=1, data=b"\xff\xd8 not really")
    rec.zenoh_sample("bf/alpha/0/camera/image", encode(jpeg), T0 + 1.0)
    rec.zenoh_sample("bf/alpha/1/status", b"\x00broken", T0 + 2.0)
    for sysid in (1, 2):
        for k, (msg, raw) in enumerate(mavlink_frames(sysid)):
            rec.mavlink(msg, raw, T0 + 0.01 * k + sysid)
    rec.alive("bf/alpha/0/alive", False, T0 + 3.0)
    rec.close()
    return rec


def test_every_channel_has_a_json_schema_that_validates_its_messages(tmp_path, recording_schemas):
    path = tmp_path / "team.mcap"
    write_team(path)
    names, problems = recording_schemas(path)
    assert problems == []
    assert names["bf/alpha/0/status"] == "bearingflock.VehicleStatus"
    assert names["bf/alpha/0/truth"] == "bearingflock.Truth"
    assert names["bf/alpha/sim/clock"] == "bearingflock.SimClock"
    assert names["bf/alpha/0/alive"] == "bearingflock.Liveliness"
    assert names["mavlink/2/GLOBAL_POSITION_INT"] == "mavlink.GLOBAL_POSITION_INT"
    assert names["bf/alpha/1/peer"] == "bearingflock.PeerEnvelope"
    assert names["bf/alpha/0/camera/image"] == "bearingflock.Image"
    assert names[SCENE_TOPIC] == SCENE_SCHEMA_NAME
    assert names[TRANSFORMS_TOPIC] == TRANSFORMS_SCHEMA_NAME


def test_a_message_that_breaks_its_schema_is_found(tmp_path, recording_schemas):
    """The checker itself can fail: a status with a string where a number belongs."""
    path = tmp_path / "bad.mcap"
    rec = Recorder(path, "alpha", tlog=False)
    status = scripted_status(StandinConfig("alpha", [0]), 0, 0.0, 0, "flying")
    rec.zenoh_sample("bf/alpha/0/status", encode(status), T0)
    with rec._lock:
        ch = rec._channels[("bf/alpha/0/status", "bearingflock.VehicleStatus")]
        rec._writer.add_message(ch, 1, b'{"type": "vehicle.status", "armed": "yes"}', 1, 1)
    rec.close()
    _names, problems = recording_schemas(path)
    assert len(problems) == 1 and problems[0].startswith("bf/alpha/0/status")


def test_the_scene_shows_true_and_estimated_poses_and_the_sensing_edges(tmp_path):
    path = tmp_path / "team.mcap"
    write_team(path)
    scenes = [json.loads(r.data) for r in iter_records(path) if r.topic == SCENE_TOPIC]
    tfs = [json.loads(r.data) for r in iter_records(path) if r.topic == TRANSFORMS_TOPIC]
    assert 15 <= len(scenes) == len(tfs) <= 21  # one per 0.1 s of log time over 2 s
    frames = {t["child_frame_id"]: t for t in tfs[-1]["transforms"]}
    assert set(frames) == {"ned", "truth/0", "truth/1", "estimate/0", "estimate/1"}
    ts = frames["truth/1"]["timestamp"]
    k = round((ts["sec"] + ts["nsec"] / 1e9 - T0) / 0.1)
    # written on tick k's first sample (vehicle 0's status): vehicle 1's latest truth is k - 1's
    assert k >= 17 and frames["truth/1"]["translation"] == {"x": 4.0, "y": 0.1 * (k - 1),
                                                            "z": -5.0}  # fmt: skip
    assert frames["truth/1"]["rotation"]["z"] == math.sin(0.15)
    ids = {e["id"]: e for e in scenes[-1]["entities"]}
    assert {"truth 0", "truth 1", "estimate 0", "estimate 1", "edges"} <= set(ids)
    edges = ids["edges"]["lines"][0]
    assert len(edges["points"]) == 4  # 0 -> 1 and 1 -> 0, each two points
    # coloured by rigidity weight (daemon default camera: 120 deg, 15 m): 1 -> 0 lies behind
    # vehicle 1's camera (weight 0, red), 0 -> 1 straight ahead of vehicle 0's (weight 1, green)
    assert (
        edges["colors"][0]
        == weight_color(1.0, EDGE_BOTH_ALPHA)
        == {"r": 0.0, "g": 1.0, "b": 0.1, "a": 0.95}
    )
    assert edges["colors"][2] == weight_color(0.0, EDGE_BOTH_ALPHA)  # fmt: skip
    frustum = ids["frustum 1"]
    assert frustum["frame_id"] == "truth/1" and frustum["frame_locked"]
    pts = frustum["lines"][0]["points"]  # 8 rays and the 8 segments of the ring at their tips
    assert len(pts) == 32 and all(
        math.isclose(math.hypot(p["x"], p["y"], p["z"]), FRUSTUM_LENGTH_M)
        and math.isclose(p["x"], FRUSTUM_LENGTH_M * math.cos(math.radians(60.0)))
        for p in pts[1:16:2]
    )


def test_alarms_name_themselves_in_red_on_the_estimate(tmp_path):
    cfg = StandinConfig("alpha", [0, 1])
    scene = SceneBuilder()
    status = scripted_status(cfg, 0, 0.0, 0, "flying")
    scene.add(msgspec.structs.replace(status, alarms=["ticks_late", "peer_lost:1"]), 0)
    _tfs, update = scene.messages(0)
    texts = {e["id"]: e["texts"][0] for e in update["entities"] if e.get("texts")}
    assert texts["estimate 0"]["text"] == "estimate 0: ticks_late peer_lost:1"
    assert texts["estimate 0"]["color"]["r"] == 1.0
    assert "frustum 0" in {e["id"] for e in update["entities"]}  # no truth: on the estimate


def test_estimates_are_drawn_after_the_best_similarity_onto_the_truth():
    truth = {i: (np.array(p, dtype=float), 0.0) for i, p in enumerate([(0, 0, -5), (4, 0, -5),
                                                                         (0, 3, -6)])}  # fmt: skip
    c, s = math.cos(2.0), math.sin(2.0)
    est = {
        i: (np.array([0.5 * (c * p[0] - s * p[1]) + 7, 0.5 * (s * p[0] + c * p[1]) - 1,
                      0.5 * p[2]]), 2.0)  # the heading turns with the frame
        for i, (p, _y) in truth.items()
    }  # fmt: skip
    shown = align_estimates(est, truth)
    for i in truth:
        assert np.allclose(shown[i][0], truth[i][0], atol=1e-9)
        assert math.isclose(math.remainder(shown[i][1], 2 * math.pi), 0.0, abs_tol=1e-9)
    assert align_estimates(est, {0: truth[0]}) is est  # one common vehicle: nothing to fit


def test_replay_gets_the_wire_bytes_back(tmp_path):
    path = tmp_path / "team.mcap"
    write_team(path)
    recs = [r for r in iter_records(path) if r.source == Source.ZENOH]
    status = [r for r in recs if r.topic == "bf/alpha/0/status"]
    cfg = StandinConfig("alpha", [0, 1])
    assert status[3].encoding == ZENOH_ENCODING
    assert status[3].data == encode(scripted_status(cfg, 0, 0.1 * 3, 3, "flying"))
    assert [r.data for r in recs if r.topic == "bf/alpha/1/status"][-1] == b"\x00broken"
    envelope = [r.data for r in recs if r.topic == "bf/alpha/1/peer"]
    motion, back = unpack(envelope[0], sender=1).payloads
    assert isinstance(motion, MotionShare) and motion.v_body == (0.5, 0.0, 0.0)
    assert back.state.tolist() == [0.0, 1.0, 2.0, 3.0] and back.per_target.tolist() == [0.25, -1]
    image = [r.data for r in recs if r.topic == "bf/alpha/0/camera/image"]
    assert decode(image[0], Image).data == b"\xff\xd8 not really"
    alive = [r.data for r in iter_records(path) if r.encoding == LIVELINESS_ENCODING]
    assert alive == [b"1", b"0"]


def test_mavlink_goes_to_a_tlog_that_pymavlink_reads(tmp_path):
    path = tmp_path / "team.mcap"
    write_team(path)
    log = mavutil.mavlink_connection(str(tlog_path(path)))
    got = []
    while (msg := log.recv_match()) is not None:
        got.append((msg.get_srcSystem(), msg.get_type(), round(msg._timestamp, 6)))
    want = [
        (sysid, name, round(T0 + 0.01 * k + sysid, 6))
        for sysid in (1, 2)
        for k, name in enumerate(
            ["HEARTBEAT", "GLOBAL_POSITION_INT", "STATUSTEXT", "ATTITUDE", "BATTERY_STATUS"]
        )
    ]
    assert got == want
    att = [json.loads(r.data) for r in iter_records(path) if r.topic == "mavlink/1/ATTITUDE"]
    assert att[0]["roll"] is None and att[0]["pitch"] == 0.25  # NaN is null in JSON


def test_a_recording_of_the_earlier_schema_less_format_is_still_read(tmp_path):
    path = tmp_path / "old.mcap"
    status = encode(scripted_status(StandinConfig("alpha", [0]), 0, 0.0, 0, "flying"))
    with path.open("wb") as f:
        w = Writer(f)
        w.start()
        z = w.register_channel("bf/alpha/0/status", "msgpack", 0, {"source": "zenoh"})
        a = w.register_channel("bf/alpha/0/alive", LIVELINESS_ENCODING, 0, {})
        m = w.register_channel("mavlink/1", "mavlink", 0, {"source": "mavlink"})
        w.add_message(a, 1, b"1", 1, 0)
        w.add_message(z, 2, status, 2, 0)
        w.add_message(m, 3, bytes(mavlink_frames(1)[0][1]), 3, 0)
        w.finish()
    recs = list(iter_records(path))
    assert [(r.topic, r.encoding, r.source) for r in recs] == [
        ("bf/alpha/0/alive", LIVELINESS_ENCODING, Source.LIVELINESS),
        ("bf/alpha/0/status", ZENOH_ENCODING, Source.ZENOH),
        ("mavlink/1", "mavlink", Source.MAVLINK),
    ]
    assert recs[1].data == status


def test_a_file_cut_anywhere_reads_back_up_to_its_last_whole_chunk(tmp_path):
    """What a killed recorder leaves (issue 23, defect 10): the reader recovers every message of
    the whole chunks before the cut, in log-time order, and says the file was not closed."""
    path = tmp_path / "team.mcap"
    write_team(path, chunk_bytes=4096)
    full = read_recording(path)
    assert full.complete and full.describe(path) == ""
    data = path.read_bytes()
    counts = []
    for frac in (0.2, 0.5, 0.8, 0.999):
        cut = tmp_path / f"cut{frac}.mcap"
        cut.write_bytes(data[: int(len(data) * frac)])
        part = read_recording(cut)
        assert not part.complete and "was not closed" in part.describe(cut)
        assert [r.log_time_ns for r in part.records] == sorted(r.log_time_ns for r in part.records)
        assert {(r.topic, r.log_time_ns, r.data) for r in part.records} <= {
            (r.topic, r.log_time_ns, r.data) for r in full.records
        }
        counts.append(len(part.records))
    assert counts == sorted(counts) and 0 < counts[0] < counts[-1], counts


def test_a_payload_type_this_version_does_not_know_is_skipped_and_said(tmp_path):
    path = tmp_path / "newer.mcap"
    rec = Recorder(path, "alpha", tlog=False)
    status = scripted_status(StandinConfig("alpha", [0]), 0, 0.0, 0, "flying")
    rec.zenoh_sample("bf/alpha/0/status", encode(status), T0)
    with rec._lock:  # what a newer version would write: a schema this one has no struct for
        rec._write(
            "bf/alpha/0/future", ("bearingflock.FromTheFuture", b"{}"), b"{}", 2, Source.ZENOH
        )
    rec.close()
    recording = read_recording(path)
    assert recording.unreadable == 1 and recording.complete
    assert [r.topic for r in recording.records if r.source == Source.ZENOH] == ["bf/alpha/0/status"]
    res = CliRunner().invoke(gcs_app, ["plot", str(path), "--out", str(tmp_path / "p")])
    assert res.exit_code == 0 and "skipped 1 messages of payload types" in res.output


def _rotate(q: dict[str, float], v: np.ndarray) -> np.ndarray:
    """``v`` rotated by the unit quaternion ``q`` (Hamilton, x y z w)."""
    u, w = np.array([q["x"], q["y"], q["z"]]), q["w"]
    return v + 2.0 * np.cross(u, np.cross(u, v) + w * v)


def test_the_ned_frame_sits_in_foxglove_s_z_up_world_and_yaw_turns_north_to_east():
    # north is ENU y, east is ENU x, down is -z
    assert np.allclose(_rotate(NED_IN_ENU, np.array([1.0, 0, 0])), [0, 1, 0])
    assert np.allclose(_rotate(NED_IN_ENU, np.array([0, 1.0, 0])), [1, 0, 0])
    assert np.allclose(_rotate(NED_IN_ENU, np.array([0, 0, 1.0])), [0, 0, -1])
    # a vehicle yawed +90 deg (NED) has its nose east
    assert np.allclose(_rotate(yaw_quaternion(math.pi / 2), np.array([1.0, 0, 0])), [0, 1, 0])
