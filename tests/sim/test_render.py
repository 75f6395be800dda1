"""The rendered camera: geometry against the camera model, determinism, options."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from onboard.vision.camera import CameraModel
from onboard.vision.tags import dictionary
from sim.render import (
    Background,
    Renderer,
    RenderMarker,
    make_background,
    marker_rotation,
    place_in_view,
    tag_cells,
)

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
    ids = det.detectMarkers(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))[1]
    assert ids is None or ids.size == 0, ids  # OpenCV 4 says None, OpenCV 5 an empty array


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


def _wall_hit(c: np.ndarray, d: np.ndarray, half: float, height: float) -> tuple[int, float]:
    """Independent ray-box intersection for one ray, face by face: ``(face, u)`` of the first
    wall the ray from ``c`` along ``d`` reaches (faces -x, +x, -y, +y, ceiling, ground; ``u``
    the in-plane texture coordinate in [0, 1])."""
    walls = [(0, -half), (0, half), (1, -half), (1, half), (2, -height), (2, 0.0)]
    best = (math.inf, -1)
    for face, (axis, level) in enumerate(walls):
        if d[axis] != 0.0 and (level - c[axis]) / d[axis] > 0.0:
            best = min(best, ((level - c[axis]) / d[axis], face))
    t, face = best
    hit = c + t * d
    u = hit[1] if face < 2 else hit[0]
    return face, (u + half) / (2.0 * half)


def test_background_is_the_wall_each_pixel_ray_hits() -> None:
    """A room whose faces have distinct grey levels (face) or one grey ramp along the texture's
    u axis: every pixel shows the face, and the place on it, that a per-ray intersection with
    the six walls gives."""
    size, half, height = 64, 10.0, 6.0
    ramp = np.tile(np.linspace(0.0, 250.0, size), (size, 1))
    flat = np.concatenate([np.full((size, size), 20.0 + 40.0 * k) for k in range(6)], axis=1)
    ones = np.ones((6, 3))
    cam = CameraModel.from_fov(160, 120, 100.0)
    faces = Renderer(cam, Background(half, height, flat.astype(np.uint8), ones))
    us = Renderer(cam, Background(half, height, np.tile(ramp, (1, 6)).astype(np.uint8), ones))
    rng = np.random.default_rng(3)
    checked = 0
    for _ in range(6):
        pose = (
            rng.uniform([-8, -8, -5], [8, 8, -1]),
            *rng.uniform([-0.4, -0.4, -3], [0.4, 0.4, 3]),
        )
        img_face = faces.render(*pose)[..., 0].astype(float)
        img_u = us.render(*pose)[..., 0].astype(float)
        r_ned_cam, c_ned = faces.camera_pose(*pose)
        for v, u in rng.integers([1, 1], [119, 159], size=(40, 2)):
            patch = img_face[v - 1 : v + 2, u - 1 : u + 2]
            if np.ptp(patch) > 0:
                continue  # next to a face edge: bilinear mixing of two faces
            d = r_ned_cam @ cam.pixels_to_rays_cam(np.array([u, v], dtype=float))
            face, frac_u = _wall_hit(c_ned, d, half, height)
            assert img_face[v, u] == 20.0 + 40.0 * face
            assert img_u[v, u] == pytest.approx(250.0 * frac_u, abs=1.5)
            checked += 1
    assert checked > 150


def test_tag_cells_counts_border_and_data_cells() -> None:
    assert tag_cells("apriltag_36h11") == 8
    assert tag_cells("4x4_50") == 6
