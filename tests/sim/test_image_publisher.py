"""The simulator's rendered camera rig: ball silhouettes, marker colours, tag boxes, and images
that the onboard pipeline turns back into the true bearings."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from messages.codec import decode
from messages.image import Image, image_from_payload, image_key
from onboard.vision.camera import CameraModel
from onboard.vision.markers import MarkerSpec
from onboard.vision.pipeline import VisionPipeline
from sim.image_publisher import (
    ImagePublisher,
    Poses,
    RenderConfig,
    ball_silhouette,
    hsv_range_bgr,
    true_poses,
)
from sim.render import make_background
from sim.world import World

BALLS = [
    MarkerSpec(1, "disc", 0.6, color_hsv_min=(170, 120, 60), color_hsv_max=(10, 255, 255)),
    MarkerSpec(2, "disc", 0.6, color_hsv_min=(50, 120, 60), color_hsv_max=(70, 255, 255)),
    MarkerSpec(3, "tag", 0.5, family="apriltag_36h11"),
]


def heading_bearing(p: np.ndarray, yaw: float, i: int, j: int) -> np.ndarray:
    """``R_z(yaw_i)^T (p_j - p_i) / d``: the virtual camera's (levelled) bearing."""
    d = p[j] - p[i]
    c, s = math.cos(yaw), math.sin(yaw)
    b = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], d[2]])
    return b / np.linalg.norm(b)


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(
        math.acos(float(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1)))
    )


@pytest.fixture(scope="module")
def room():
    return make_background(0, texture_px=256)


def test_ball_silhouette_is_the_tangent_circle() -> None:
    rng = np.random.default_rng(0)
    c = np.array([1.0, -2.0, -5.0])
    p = c + np.array([4.0, 1.5, -0.7])
    centre, rot, diameter = ball_silhouette(p, 0.8, c)
    r = 0.4
    for th in rng.uniform(0, 2 * np.pi, 8):
        q = centre + 0.5 * diameter * (math.cos(th) * rot[:, 0] + math.sin(th) * rot[:, 1])
        assert np.linalg.norm(q - p) == pytest.approx(r, abs=1e-12)  # on the ball
        assert (q - c) @ (q - p) == pytest.approx(0.0, abs=1e-12)  # the ray touches it
    assert rot[:, 2] @ (c - centre) > 0  # faces the camera
    assert ball_silhouette(p, 2.0 * np.linalg.norm(p - c) + 0.1, c) is None


@pytest.mark.parametrize(
    "lo,hi", [((170, 120, 60), (10, 255, 255)), ((50, 120, 60), (70, 255, 255))]
)
def test_render_colour_lies_in_its_hsv_range(lo, hi) -> None:
    bgr = np.array([[hsv_range_bgr(lo, hi)]], dtype=np.uint8)
    h, s, v = (int(x) for x in cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV)[0, 0])
    in_hue = lo[0] <= h <= hi[0] if lo[0] <= hi[0] else (h >= lo[0] or h <= hi[0])
    assert in_hue and s >= lo[1] and v >= lo[2]


def _poses(p: np.ndarray, yaw: np.ndarray, roll: float = 0.0, pitch: float = 0.0) -> Poses:
    n = len(p)
    return Poses(1.25, p, np.full(n, roll), np.full(n, pitch), yaw)


def test_rendered_frames_give_back_the_true_bearings(room) -> None:
    cam = CameraModel.from_fov(320, 240, 100.0)
    p = np.array([[0.0, 0.0, -5.0], [5.0, 1.0, -5.5], [4.0, -1.5, -4.6], [3.0, -0.3, -5.0]])
    yaw = np.array([0.05, math.pi, 2.0, -0.4])
    out = []
    pub = ImagePublisher([cam], BALLS, RenderConfig(seed=3), "t", lambda k, d: out.append((k, d)),
                         ids=[0, 1, 2, 3], background=room)  # fmt: skip
    frames = list(pub.frames(_poses(p, yaw, roll=0.04, pitch=-0.03), frame_index=0))
    assert [k for k, _ in frames] == [image_key("t", i) for i in range(4)]
    msg = decode(frames[0][1], Image)
    assert (msg.sender, msg.camera_id, msg.stamp_s) == (0, 0, 1.25)
    pipe = VisionPipeline(cam, BALLS)
    dets = pipe.process(image_from_payload(msg))
    assert [d.vehicle_id for d in dets] == [1, 2, 3]
    ids, beta, _ = pipe.bearings_level(dets, 0.04, -0.03)
    for j, b in zip(ids, beta, strict=True):
        err = angle_deg(b, heading_bearing(p, yaw[0], 0, j))
        # balls: exact up to pixels; tag: centre of a face, up to 0.2 m off the body origin at 3 m
        assert err < (0.3 if j != 3 else 4.0), (j, err)


def test_tag_box_is_seen_from_every_side(room) -> None:
    cam = CameraModel.from_fov(320, 240, 90.0)
    pub = ImagePublisher([cam], BALLS, RenderConfig(), "t", lambda k, d: None, background=room)
    pipe = VisionPipeline(cam, BALLS)
    for az in np.radians([0.0, 50.0, 100.0, 180.0, 260.0]):
        p = np.array(
            [[0.0, 0.0, -5.0], [0, 0, 0], [0, 0, 0], [4.0 * math.cos(az), 4.0 * math.sin(az), -5.0]]
        )
        yaw = np.array([az, 0.0, 0.0, 0.3])
        img = pub.render(_poses(p, yaw), 0, 0, 0)
        assert [d.vehicle_id for d in pipe.process(img)] == [3], math.degrees(az)


def test_own_marker_is_not_drawn_and_rig_cameras_look_their_way(room) -> None:
    front = CameraModel.from_fov(320, 240, 90.0)
    back = CameraModel(320, 240, front.fx, front.fy, front.cx, front.cy, mount_rpy_deg=(0, 0, 180))
    pub = ImagePublisher([front, back], BALLS, RenderConfig(), "t", lambda k, d: None,
                         ids=[1, 2], background=room)  # fmt: skip
    p = np.array([[0.0, 0.0, -5.0], [-4.0, 0.5, -5.0]])  # vehicle 2 behind vehicle 1
    poses = _poses(p, np.zeros(2))
    seen = [
        [d.vehicle_id for d in VisionPipeline(c, BALLS).process(pub.render(poses, 0, k, 0))]
        for k, c in enumerate((front, back))
    ]
    assert seen == [[], [2]]


def test_hook_renders_at_its_rate_off_the_simulator_thread(room) -> None:
    cam = CameraModel.from_fov(160, 120, 90.0)
    got: list[tuple[str, bytes]] = []
    world = World(np.array([[0.0, 0.0, -5.0], [4.0, 0.0, -5.0]]), np.array([0.0, math.pi]))
    pub = ImagePublisher([cam], BALLS[:2], RenderConfig(rate_hz=5.0), "t",
                         lambda k, d: got.append((k, d)), ids=[1, 2], background=room)  # fmt: skip
    try:
        for _ in range(100):  # 1 s of simulation at 10 ms
            world.step(0.01)
            pub(world.t_s, world)
            assert pub.wait_idle(10.0)  # the worker finishes each frame before the next
    finally:
        pub.close()
    stamps = sorted({decode(d, Image).stamp_s for _, d in got})
    # the first tick (0.01 s), then every 0.2 s of simulation time up to 1.0 s
    assert len(stamps) == 6 and pub.stats.skipped == 0
    assert np.allclose(stamps[1:], [0.2, 0.4, 0.6, 0.8, 1.0])
    assert pub.stats.published == 12


def test_true_poses_tilt_with_acceleration() -> None:
    world = World(np.array([[0.0, 0.0, -5.0]]), np.array([0.0]))
    world.command_velocity(0, (2.0, 0.0, 0.0), body=False)
    world.step(0.05)
    poses = true_poses(world.t_s, world)
    assert poses.pitch_rad[0] < -0.01 and abs(poses.roll_rad[0]) < 1e-9  # nose down to accelerate


def test_render_options_are_checked(tmp_path) -> None:
    import typer
    from typer.testing import CliRunner

    from groundstation.demo_cli import write_camera_rig
    from sim.cli import sim

    app = typer.Typer()
    app.command()(sim)
    run = CliRunner().invoke
    cams, markers = write_camera_rig(tmp_path, 3)
    r = run(app, ["--render-camera", str(cams[0])])
    assert r.exit_code == 2 and "--markers and --zenoh" in r.output
    bad = tmp_path / "bad.toml"
    bad.write_text("[[marker]]\nid = 1\nkind = 'ball'\nsize_m = 0.5\n")
    args = ["--render-camera", str(cams[0]), "--zenoh", "tcp/127.0.0.1:1", "--port-base", "31100"]
    r = run(app, [*args, "--markers", str(bad)])
    assert r.exit_code == 2 and "kind must be" in r.output
    r = run(app, [*args, "--markers", str(markers), "--render-rate", "0"])
    assert r.exit_code == 2 and "render rate" in r.output
