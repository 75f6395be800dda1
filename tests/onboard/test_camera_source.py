"""The camera bearing source: rendered images in, levelled bearings to fleet members out; bad
frames counted and skipped; attitude taken at the frame's stamp; rig frames gathered by stamp."""

from __future__ import annotations

import math
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from messages.codec import encode
from messages.image import Image, image_payload
from onboard.daemon.camera_source import (
    AttitudeHistory,
    AttitudeSample,
    CameraImageSource,
    DeviceCapture,
)
from onboard.daemon.peers import DropCounter
from onboard.vision.camera import CameraModel
from onboard.vision.markers import MarkerSpec
from onboard.vision.pipeline import VisionPipeline
from sim.image_publisher import ImagePublisher, Poses, RenderConfig
from sim.render import make_background

MARKERS = [
    MarkerSpec(1, "disc", 0.6, color_hsv_min=(170, 120, 60), color_hsv_max=(10, 255, 255)),
    MarkerSpec(2, "disc", 0.6, color_hsv_min=(50, 120, 60), color_hsv_max=(70, 255, 255)),
    MarkerSpec(7, "disc", 0.6, color_hsv_min=(100, 120, 60), color_hsv_max=(125, 255, 255)),
]
FRONT = CameraModel.from_fov(320, 240, 100.0)
BACK = CameraModel(320, 240, FRONT.fx, FRONT.fy, FRONT.cx, FRONT.cy, mount_rpy_deg=(0, 0, 180))
ROLL, PITCH, YAW = 0.05, -0.04, 0.3
STAMP = 2.5
# vehicle 0 (the observer), 1 ahead, 2 behind, 7 (not in the fleet) ahead
P_NED = np.array([[0.0, 0.0, -5.0], [5.0, 2.5, -5.6], [-4.0, -0.5, -4.5], [4.5, -0.5, -5.0]])
IDS = [0, 1, 2, 7]


def heading_bearing(j: int) -> np.ndarray:
    d = P_NED[j] - P_NED[0]
    c, s = math.cos(YAW), math.sin(YAW)
    b = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], d[2]])
    return b / np.linalg.norm(b)


@pytest.fixture(scope="module")
def payloads() -> list[bytes]:
    """The two rig images of vehicle 0 at ``STAMP``, as Zenoh payloads."""
    pub = ImagePublisher([FRONT, BACK], MARKERS, RenderConfig(seed=1), "t", lambda k, d: None,
                         ids=IDS, background=make_background(0, texture_px=256))  # fmt: skip
    n = len(IDS)
    poses = Poses(STAMP, P_NED, np.full(n, ROLL), np.full(n, PITCH), np.full(n, YAW))
    return [data for key, data in pub.frames(poses, 0) if key == "bf/t/0/camera/image"]


def make_source(drops: DropCounter, attitude=None, cameras=(FRONT, BACK)) -> CameraImageSource:
    if attitude is None:

        def attitude() -> AttitudeSample:
            return AttitudeSample(STAMP, ROLL, PITCH)

    return CameraImageSource(
        0, [VisionPipeline(c, MARKERS) for c in cameras], [0, 1, 2], drops, attitude, start=False
    )


def test_detections_become_levelled_bearings_to_fleet_members(payloads) -> None:
    drops = DropCounter()
    src = make_source(drops)
    for data in payloads:
        src.on_payload(data)
    assert src.step() == 2
    frame = src.poll()
    assert frame is not None and src.poll() is None  # returned once
    assert [m.target for m in frame] == [1, 2]  # front sees 1 (and 7), back sees 2
    for m in frame:
        assert m.stamp_s == STAMP
        err = math.degrees(
            math.acos(min(1.0, float(np.dot(m.beta_body, heading_bearing(m.target)))))
        )
        assert err < 0.3, (m.target, err)
    assert drops.snapshot() == {"camera_unknown_target": 1}  # the marker of vehicle 7
    assert src.age_s(STAMP + 0.1) == pytest.approx(0.1)


def test_without_levelling_the_tilt_would_show(payloads) -> None:
    """The same frames levelled with a wrong (zero) attitude miss by about the tilt."""
    src = make_source(DropCounter(), attitude=lambda: AttitudeSample(STAMP, 0.0, 0.0))
    for data in payloads:
        src.on_payload(data)
    src.step()
    frame = src.poll()
    errs = [
        math.degrees(math.acos(min(1.0, float(np.dot(m.beta_body, heading_bearing(m.target))))))
        for m in frame
    ]
    assert min(errs) > 1.0


def _image(**changes) -> bytes:
    msg = image_payload(np.full((240, 320, 3), 90, np.uint8), sender=0, stamp_s=1.0)
    fields = {f: getattr(msg, f) for f in msg.__struct_fields__} | changes
    return encode(Image(**fields))


def test_bad_frames_are_counted_and_skipped(payloads) -> None:
    drops = DropCounter()
    src = make_source(drops)
    src.on_payload(b"\xc1 not msgpack")
    src.on_payload(_image(sender=3))
    src.on_payload(_image(camera_id=5))
    src.step()
    src.on_payload(_image(width=640))
    src.step()
    src.on_payload(_image(data=b"\xff\xd8 not a jpeg"))
    src.step()
    src.on_payload(_image(data=b""))
    src.step()
    src.on_frame(0, 1.5, None)
    src.step()
    src.on_frame(0, 1.6, np.zeros((240, 320, 3), np.float32))
    src.step()
    src.on_frame(0, 1.7, np.zeros((100, 320, 3), np.uint8))
    src.step()
    src.on_frame(0, float("nan"), np.zeros((240, 320, 3), np.uint8))
    assert drops.snapshot() == {
        "camera_malformed": 1,
        "camera_sender": 1,
        "camera_id": 1,
        "camera_size": 2,
        "camera_encoding": 1,
        "camera_empty": 2,
        "camera_dtype": 1,
        "camera_nonfinite": 1,
    }
    for data in payloads:  # and the next good frames still work
        src.on_payload(data)
    src.step()
    frame = src.poll()
    assert frame is not None and [m.target for m in frame] == [1, 2]


def test_no_attitude_near_the_stamp_drops_the_frame(payloads) -> None:
    drops = DropCounter()
    src = make_source(drops, attitude=lambda: AttitudeSample(STAMP - 1.0, ROLL, PITCH))
    for data in payloads:
        src.on_payload(data)
    src.step()
    assert src.poll() is None
    assert drops.snapshot()["camera_no_attitude"] == 1


def test_rig_frames_are_gathered_by_stamp() -> None:
    drops = DropCounter()
    src = make_source(drops, attitude=lambda: AttitudeSample(1.0, 0.0, 0.0))
    src.history.max_gap_s = 10.0
    blank = np.full((240, 320, 3), 90, np.uint8)
    src.on_frame(0, 1.0, blank)
    src.step()
    assert src.poll() is None  # camera 1 of t=1.0 still missing
    src.on_frame(0, 1.1, blank)  # a newer stamp first: t=1.0 goes out incomplete
    src.step()
    assert src.poll() == () and src.stats.incomplete == 1 and src.age_s(1.0) == 0.0
    src.on_frame(1, 1.0, blank)  # too late now
    src.step()
    assert src.stats.late == 1
    src.on_frame(1, 1.1, blank)
    src.step()
    assert src.poll() == () and src.age_s(1.1) == 0.0 and src.stats.incomplete == 1


def test_queued_frames_of_one_camera_keep_only_the_newest() -> None:
    src = make_source(DropCounter(), cameras=(FRONT,))
    blank = np.full((240, 320, 3), 90, np.uint8)
    for t in (1.0, 1.1, 1.2):
        src.on_frame(0, t, blank)
    assert src.step() == 1 and src.stats.skipped == 2


def test_worker_thread_delivers(payloads) -> None:
    src = CameraImageSource(
        0,
        [VisionPipeline(c, MARKERS) for c in (FRONT, BACK)],
        [0, 1, 2],
        DropCounter(),
        lambda: AttitudeSample(STAMP, ROLL, PITCH),
    )
    try:
        for data in payloads:
            src.on_payload(data)
        deadline = time.monotonic() + 10.0
        frame = None
        while frame is None and time.monotonic() < deadline:
            time.sleep(0.01)
            frame = src.poll()
        assert frame is not None and [m.target for m in frame] == [1, 2]
    finally:
        src.close()


def test_attitude_history_interpolates_and_knows_its_limits() -> None:
    h = AttitudeHistory(horizon_s=1.0, max_gap_s=0.1)
    assert h.at(0.0) is None
    h.add(AttitudeSample(0.0, 0.0, 1.0))
    h.add(AttitudeSample(0.1, 0.2, 0.0))
    h.add(AttitudeSample(0.05, 9.0, 9.0))  # out of order: ignored
    h.add(AttitudeSample(0.2, float("nan"), 0.0))  # not finite: ignored
    assert h.at(0.025) == pytest.approx((0.05, 0.75))
    assert h.at(0.15) == pytest.approx((0.2, 0.0))  # nearest, within the gap
    assert h.at(0.25) is None
    h.add(AttitudeSample(1.5, 0.3, 0.3))  # older than the horizon falls out
    assert h.at(0.0) is None
    assert h.at(0.8) is None  # the gap 0.1 .. 1.5 is too long to interpolate


def test_device_capture_reads_a_video_file(tmp_path: Path) -> None:
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (320, 240))
    assert writer.isOpened()
    for k in range(5):
        writer.write(np.full((240, 320, 3), 60 + 20 * k, np.uint8))
    writer.release()
    drops = DropCounter()
    t = iter(np.arange(1.0, 2.0, 0.1))
    src = make_source(drops, attitude=lambda: AttitudeSample(1.2, 0.0, 0.0), cameras=(FRONT,))
    src.history.max_gap_s = 10.0
    cap = DeviceCapture(str(path), src, lambda: float(next(t)))
    cap.wait(10.0)
    cap.close()
    assert cap.frames == 5
    src.step()  # only the newest queued frame is processed
    assert src.poll() == () and src.stats.frames >= 1 and drops.total == 0
    with pytest.raises(OSError):
        DeviceCapture(str(tmp_path / "missing.avi"), src, lambda: 0.0)


# ------------------------------------------------------------------ ranges (paper 002 eq. 22)
def true_range(j: int) -> float:
    return float(np.linalg.norm(P_NED[j] - P_NED[0]))


def test_disc_ranges_go_out_with_their_bearings(payloads) -> None:
    drops = DropCounter()
    src = make_source(drops)
    for data in payloads:
        src.on_payload(data)
    src.step()
    assert src.frame_ranges() == ()  # nothing polled yet
    frame = src.poll()
    ranges = src.frame_ranges()
    assert [m.target for m in frame] == [r.target for r in ranges] == [1, 2]
    for r in ranges:
        assert r.stamp_s == STAMP  # the frame's stamp, as its bearings
        assert abs(r.range_m - true_range(r.target)) < 0.05 * true_range(r.target), r
    assert src.stats.ranges == 2 and drops.snapshot() == {"camera_unknown_target": 1}
    assert src.poll() is None and src.frame_ranges() == ranges  # the last polled set's


class _Ranges(VisionPipeline):
    """The real pipeline with the ranges of some vehicles replaced (a faulty fit)."""

    def __init__(self, camera, ranges: dict[int, float]) -> None:
        super().__init__(camera, MARKERS)
        self.ranges = ranges

    def process(self, image):
        return [
            replace(d, range_m=self.ranges.get(d.vehicle_id, d.range_m))
            for d in super().process(image)
        ]


@pytest.mark.parametrize(
    ("bad", "reason"),
    [
        (float("nan"), "camera_nonfinite"),
        (float("inf"), "camera_nonfinite"),
        (-2.0, "camera_out_of_range"),
        (0.0, "camera_out_of_range"),
        (1e7, "camera_out_of_range"),
    ],
)
def test_implausible_ranges_are_counted_and_dropped_the_bearing_kept(payloads, bad, reason):
    drops = DropCounter()
    src = CameraImageSource(0, [_Ranges(FRONT, {}), _Ranges(BACK, {2: bad})], [0, 1, 2], drops,
                            lambda: AttitudeSample(STAMP, ROLL, PITCH), start=False)  # fmt: skip
    for data in payloads:
        src.on_payload(data)
    src.step()
    assert [m.target for m in src.poll()] == [1, 2]  # both bearings
    assert [r.target for r in src.frame_ranges()] == [1]  # vehicle 2's range is not passed
    assert drops.snapshot() == {"camera_unknown_target": 1, reason: 1}


def test_ranges_off_gives_bearings_only(payloads) -> None:
    drops = DropCounter()
    src = CameraImageSource(0, [_Ranges(FRONT, {1: float("nan")}), _Ranges(BACK, {})], [0, 1, 2],
                            drops, lambda: AttitudeSample(STAMP, ROLL, PITCH), start=False,
                            ranges=False)  # fmt: skip
    for data in payloads:
        src.on_payload(data)
    src.step()
    assert [m.target for m in src.poll()] == [1, 2] and src.frame_ranges() == ()
    assert drops.snapshot() == {"camera_unknown_target": 1}  # nothing looked at, nothing counted


def _telemetry():
    """A real telemetry snapshot of a PX4 autopilot hovering (the daemon's odometry reads it)."""
    from pymavlink.dialects.v20 import common as dialect

    from messages import mavlink as mv
    from onboard.autopilot.base import Flavour, LinkConfig, LinkCounters, StreamState
    from onboard.autopilot.states import Saturated, TelemetryState, snapshot

    st = TelemetryState(flavour=Flavour.PX4)
    t = time.monotonic()
    st.apply(dialect.MAVLink_heartbeat_message(2, 12, mv.BASE_MODE_CUSTOM, 0, 3, 3), t)
    st.apply(dialect.MAVLink_attitude_message(1000, 0.0, 0.0, 0.3, 0, 0, 0.0), t)
    st.apply(dialect.MAVLink_local_position_ned_message(1000, 0, 0, -5.0, 0, 0, 0), t)
    return snapshot(st, t, LinkConfig(), 1, StreamState.IDLE,
                    Saturated((0.0, 0.0, 0.0), 0.0, False, False), LinkCounters())  # fmt: skip


def test_the_daemon_hands_a_frames_ranges_to_the_core(payloads, tmp_path) -> None:
    """``AgentDaemon._measurements``: the polled frame's ranges ride with its bearings into
    ``own.ranges``, once; the core's camera layer keeps them per target."""
    from types import SimpleNamespace

    from groundstation.demo import DemoPorts, plan_formation, write_demo_files
    from onboard.daemon.clock import WallClock
    from onboard.daemon.config import load_fleet
    from onboard.daemon.loop import AgentDaemon

    path = write_demo_files(tmp_path, plan_formation(3, seed=1), DemoPorts(zenoh=1, mavlink=2,
                            gcs=3), "t", "formation-active", localization="paper002")  # fmt: skip
    fleet = load_fleet(path)
    assert fleet.camera_ranges  # paper002 without the rigidity layer: on by default
    src = make_source(DropCounter())
    daemon = AgentDaemon(fleet, 0, SimpleNamespace(), SimpleNamespace(), src, WallClock(),
                         DropCounter(), "x")  # fmt: skip
    for data in payloads:
        src.on_payload(data)
    src.step()
    own = daemon._measurements(STAMP + 0.05, _telemetry())
    assert [r.target for r in own.ranges] == [1, 2]
    assert all(r.stamp_s == STAMP for r in own.ranges)
    again = daemon._measurements(STAMP + 0.06, _telemetry())
    assert again.bearings == () and again.ranges == ()  # a frame is handed over once
    daemon.core.step(own.t_s, own)
    assert daemon.core.bearings.out_targets == [1, 2]  # the demo's complete graph
    assert daemon.core.bearings.range_out == {r.target: (STAMP, r.range_m) for r in own.ranges}
