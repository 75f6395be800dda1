"""The rendered camera: geometry against the camera model, determinism, options."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from onboard.vision.camera import CameraModel
from onboard.vision.tags import dictionary
from sim.render import Renderer, RenderMarker, make_background, marker_rotation, place_in_view

DIST = (-0.2, 0.05, 0.0, 0.0, 0.0)


@pytest.fixture(scope="module")
def background():
    return make_background(5, texture_px=256)


def test_marker_rotation_is_right_handed_and_faces_normal() -> None:
    r = marker_rotation([-1.0, 0.2, 0.1])
    np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    assert r[:, 1] @ [0, 0, -1] > 0.9  # marker y is up
    with pytest.raises(ValueError):
        marker_rotation([0, 0, 1.0])


@pytest.mark.parametrize("dist", [(0.0,) * 5, DIST])
def test_disc_drawn_where_the_camera_model_projects_it(background, dist) -> None:
    cam = CameraModel(640, 480, 330.0, 330.0, 322.0, 238.0, dist)
    ren = Renderer(cam, background)
    pose = (np.array([1.0, -2.0, -4.0]), 0.05, -0.1, 0.7)
    p, rot = place_in_view(ren, pose, [400.0, 300.0], 4.0, math.radians(30), 1.0)
    img = ren.render(*pose, [RenderMarker("disc", 0.6, p, rot, color_bgr=(255, 0, 255))])
    bg = ren.render(*pose).astype(float)
    # pixel = (1 - c) bg + c colour  =>  c = <pixel - bg, colour - bg> / |colour - bg|^2
    diff = np.array([255.0, 0.0, 255.0]) - bg
    cover = np.sum((img - bg) * diff, axis=2) / np.sum(diff * diff, axis=2)
    # boundary of the disc, projected with the camera model
    t = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    pts = p + 0.3 * (np.cos(t)[:, None] * rot[:, 0] + np.sin(t)[:, None] * rot[:, 1])
    r_ned_cam, c_ned = ren.camera_pose(*pose)
    uv, front = cam.project_cam((pts - c_ned) @ r_ned_cam)
    assert front.all()
    poly = uv.astype(np.float32)
    # covered area equals the projected polygon's area (anti-aliased coverage), to 1%
    assert cover.sum() == pytest.approx(cv2.contourArea(poly), rel=0.01)
    # pixels well inside / well outside are fully covered / empty
    v, u = np.mgrid[0:480, 0:640]
    signed = np.array(
        [
            cv2.pointPolygonTest(poly, (float(a), float(b)), True)
            for a, b in zip(u[::7, ::7].ravel(), v[::7, ::7].ravel(), strict=True)
        ]
    )
    sampled = cover[::7, ::7].ravel()
    assert np.all(sampled[signed > 1.0] > 0.97) and np.all(sampled[signed < -1.0] < 0.03)


def test_tag_is_detected_with_corners_at_projection(background) -> None:
    cam = CameraModel.from_fov(640, 480, 90.0)
    ren = Renderer(cam, background)
    pose = (np.array([0.0, 0.0, -5.0]), 0.0, 0.0, 0.0)
    p, rot = place_in_view(ren, pose, [300.0, 260.0], 3.0, math.radians(20), 0.3)
    img = ren.render(*pose, [RenderMarker("tag", 0.5, p, rot, family="apriltag_36h11", tag_id=23)])
    det = cv2.aruco.ArucoDetector(dictionary("apriltag_36h11"), cv2.aruco.DetectorParameters())
    corners, ids, _ = det.detectMarkers(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    assert ids is not None and ids.ravel().tolist() == [23]
    h = 0.25
    local = np.array([[-h, h], [h, h], [h, -h], [-h, -h]])
    r_ned_cam, c_ned = ren.camera_pose(*pose)
    uv, _ = cam.project_cam((p + local @ rot[:, :2].T - c_ned) @ r_ned_cam)
    assert np.max(np.abs(corners[0].reshape(4, 2) - uv)) < 1.5


def test_back_of_tag_shows_no_code(background) -> None:
    cam = CameraModel.from_fov(640, 480, 90.0)
    ren = Renderer(cam, background)
    pose = (np.array([0.0, 0.0, -5.0]), 0.0, 0.0, 0.0)
    p, rot = place_in_view(ren, pose, [320.0, 240.0], 3.0)
    back = rot @ np.diag([-1.0, 1.0, -1.0])  # turned around
    img = ren.render(*pose, [RenderMarker("tag", 0.5, p, back, tag_id=3)])
    det = cv2.aruco.ArucoDetector(dictionary("apriltag_36h11"), cv2.aruco.DetectorParameters())
    assert det.detectMarkers(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))[1] is None


def test_seeded_and_options(background) -> None:
    cam = CameraModel.from_fov(320, 240, 90.0)
    ren = Renderer(cam, background)
    pose = (np.array([2.0, 1.0, -3.0]), 0.0, 0.1, -1.0)
    clean = ren.render(*pose)
    assert clean.shape == (240, 320, 3) and clean.dtype == np.uint8
    assert clean.std() > 10  # textured
    a = ren.render(*pose, noise_std=3.0, seed=4)
    np.testing.assert_array_equal(a, ren.render(*pose, noise_std=3.0, seed=4))
    assert not np.array_equal(a, ren.render(*pose, noise_std=3.0, seed=5))
    assert abs(float((a.astype(float) - clean).std()) - 3.0) < 0.5
    blurred = ren.render(*pose, blur_sigma_px=2.0)
    grad = lambda im: np.abs(np.diff(im.astype(float), axis=1)).mean()  # noqa: E731
    assert grad(blurred) < 0.7 * grad(clean)
    np.testing.assert_array_equal(make_background(5, texture_px=256).atlas, background.atlas)
