"""The marker pipeline on rendered images: accuracy, identities, bad frames, config files."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from messages.image import FrameError
from onboard.vision.camera import CameraModel
from onboard.vision.config import VisionConfigError, load_camera, load_markers
from onboard.vision.markers import MarkerSpec
from onboard.vision.pipeline import VisionPipeline
from sim.render import Renderer, RenderMarker, make_background, place_in_view

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
COLOURS = {1: (0, 0, 220), 2: (0, 200, 0), 3: (220, 90, 0)}


@pytest.fixture(scope="module")
def setup() -> tuple[Renderer, list[MarkerSpec]]:
    cam = load_camera(EXAMPLES / "camera.toml")
    return Renderer(cam, make_background(7, texture_px=512)), load_markers(
        EXAMPLES / "markers.toml"
    )


def _scene(renderer: Renderer, rng: np.random.Generator, max_range_m: float, extra=()):
    """Observer pose and the five example markers at separated pixels, 2..max_range_m away."""
    pose = (
        np.array([0.0, 0.0, -5.0]),
        math.radians(rng.uniform(-8, 8)),
        math.radians(rng.uniform(-8, 8)),
        rng.uniform(-np.pi, np.pi),
    )
    r_ned_body = renderer.camera_pose(*pose)[0] @ renderer.camera.r_body_cam.T
    pixels = np.array([[110, 110], [320, 110], [530, 110], [200, 340], [440, 340]], float)
    pixels += rng.uniform(-20, 20, pixels.shape)
    markers, truth = [], {}
    for vid, uv in zip((1, 2, 3, 4, 5, *extra), pixels, strict=False):
        d = rng.uniform(2.0, max_range_m)
        p, rot = place_in_view(
            renderer, pose, uv, d, math.radians(rng.uniform(0, 40)), rng.uniform(0, 6.3)
        )
        if vid in COLOURS:
            markers.append(RenderMarker("disc", 0.5, p, rot, color_bgr=COLOURS[vid]))
        else:
            markers.append(RenderMarker("tag", 0.5, p, rot, tag_id=vid))
        truth[vid] = r_ned_body.T @ (p - pose[0])
    return pose, markers, truth


def test_rendered_accuracy_small_study(setup) -> None:
    renderer, specs = setup
    pipe = VisionPipeline(renderer.camera, specs)
    rng = np.random.default_rng(11)
    bearing_err, range_err = {"disc": [], "tag": []}, {"disc": [], "tag": []}
    for k in range(4):
        pose, markers, truth = _scene(renderer, rng, 10.0)
        img = renderer.render(*pose, markers, blur_sigma_px=0.6, noise_std=2.0, seed=k)
        dets = pipe.process(img)
        assert sorted(d.vehicle_id for d in dets) == sorted(truth)  # all found, no false identity
        for d in dets:
            p = truth[d.vehicle_id]
            rng_true = np.linalg.norm(p)
            bearing_err[d.kind].append(
                math.degrees(math.acos(min(1.0, d.bearing_body @ p / rng_true)))
            )
            range_err[d.kind].append(abs(d.range_m - rng_true) / rng_true)
            assert abs(np.linalg.norm(d.bearing_body) - 1.0) < 1e-12 and 0.0 <= d.quality <= 1.0
    for kind in ("disc", "tag"):
        assert np.median(bearing_err[kind]) < 0.5
        assert max(bearing_err[kind]) < 1.0
    assert np.median(range_err["disc"]) < 0.03
    assert np.median(range_err["tag"]) < 0.02


def test_unconfigured_markers_are_not_reported(setup) -> None:
    renderer, specs = setup
    pipe = VisionPipeline(renderer.camera, specs)
    pose = (np.array([0.0, 0.0, -5.0]), 0.0, 0.0, 0.3)
    stray = []
    for uv, kind in (([200, 240], "tag"), ([440, 240], "disc")):
        p, rot = place_in_view(renderer, pose, uv, 5.0)
        stray.append(RenderMarker(kind, 0.5, p, rot, tag_id=17, color_bgr=(0, 220, 220)))  # yellow
    assert pipe.process(renderer.render(*pose, stray)) == []


def test_grey_frames_work_for_tags_only(setup) -> None:
    renderer, specs = setup
    pose = (np.array([0.0, 0.0, -5.0]), 0.0, 0.0, 0.0)
    p, rot = place_in_view(renderer, pose, [300, 200], 4.0)
    img = renderer.render(*pose, [RenderMarker("tag", 0.5, p, rot, tag_id=4)])
    tags = VisionPipeline(renderer.camera, [s for s in specs if s.kind == "tag"])
    dets = tags.process(img[:, :, 1].copy())
    assert [d.vehicle_id for d in dets] == [4]
    with pytest.raises(FrameError) as exc:
        VisionPipeline(renderer.camera, [s for s in specs if s.kind == "disc"]).process(
            img[:, :, 1].copy()
        )
    assert exc.value.reason == "size"


@pytest.mark.parametrize(
    ("frame", "reason"),
    [
        (None, "empty"),
        (np.zeros((0, 0, 3), np.uint8), "empty"),
        (np.zeros((480, 640, 3), np.float32), "dtype"),
        (np.zeros((240, 320, 3), np.uint8), "size"),
        (np.zeros((480, 640, 4), np.uint8), "size"),
    ],
)
def test_bad_frames_raise_one_error_type(setup, frame, reason: str) -> None:
    renderer, specs = setup
    with pytest.raises(FrameError) as exc:
        VisionPipeline(renderer.camera, specs).process(frame)
    assert exc.value.reason == reason


def test_levelled_bearings_remove_roll_and_pitch(setup) -> None:
    renderer, specs = setup
    pipe = VisionPipeline(renderer.camera, specs)
    roll, pitch = math.radians(6.0), math.radians(-9.0)
    pose = (np.array([0.0, 0.0, -5.0]), roll, pitch, 0.4)
    p, rot = place_in_view(renderer, pose, [330, 250], 6.0)
    dets = pipe.process(
        renderer.render(*pose, [RenderMarker("disc", 0.5, p, rot, color_bgr=COLOURS[2])])
    )
    ids, beta_level, _ = pipe.bearings_level(dets, roll, pitch)
    heading = np.array(
        [[math.cos(0.4), math.sin(0.4), 0], [-math.sin(0.4), math.cos(0.4), 0], [0, 0, 1]]
    )
    truth = heading @ (p - pose[0])
    assert ids == [2]
    assert math.degrees(math.acos(beta_level[0] @ truth / np.linalg.norm(truth))) < 0.2


def test_config_files(tmp_path: Path) -> None:
    cam = load_camera(EXAMPLES / "camera.toml")
    assert isinstance(cam, CameraModel) and cam.hfov_deg == pytest.approx(90.0, abs=0.2)
    specs = load_markers(EXAMPLES / "markers.toml")
    assert [s.id for s in specs] == [1, 2, 3, 4, 5] and specs[3].family == "apriltag_36h11"
    bad = {
        "camera.toml": "width = 640\nheight = 480\nfx = 320.0\n",
        "m1.toml": '[[marker]]\nid = 1\nkind = "disc"\nsize_m = 0.5\n',
        "m2.toml": '[[marker]]\nid = 1\nkind = "tag"\nfamily = "nope"\nsize_m = 0.5\n',
        "m3.toml": '[[marker]]\nid = 1\nkind = "tag"\nsize_m = 0.5\n[[marker]]\nid = 1\nkind = "tag"\nsize_m = 0.4\n',
        "m4.toml": "this is not toml [",
    }
    for name, text in bad.items():
        (tmp_path / name).write_text(text)
        loader = load_camera if name.startswith("camera") else load_markers
        with pytest.raises(VisionConfigError):
            loader(tmp_path / name)
    with pytest.raises(VisionConfigError):
        load_camera(tmp_path / "missing.toml")
