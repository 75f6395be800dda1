"""Camera model: OpenCV-compatible projection and undistortion, body mounting, field of view."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from onboard.vision.camera import CameraModel

DIST = (-0.28, 0.09, 0.001, -0.0015, -0.012)


@pytest.fixture
def cam() -> CameraModel:
    return CameraModel(640, 480, 330.0, 332.0, 318.5, 241.0, DIST)


def test_projection_matches_opencv(cam: CameraModel) -> None:
    rng = np.random.default_rng(0)
    x_cam = np.column_stack(
        [rng.uniform(-2, 2, 50), rng.uniform(-1.5, 1.5, 50), rng.uniform(2, 9, 50)]
    )
    uv, front = cam.project_cam(x_cam)
    ref, _ = cv2.projectPoints(x_cam, np.zeros(3), np.zeros(3), cam.k_matrix, cam.dist_coeffs)
    assert front.all()
    np.testing.assert_allclose(uv, ref.reshape(-1, 2), atol=1e-9)


def test_undistortion_matches_opencv_and_inverts_projection(cam: CameraModel) -> None:
    rng = np.random.default_rng(1)
    uv = rng.uniform([20, 20], [620, 460], (200, 2))
    ours = cam.pixels_to_normalized(uv)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    ref = cv2.undistortPoints(
        uv.reshape(-1, 1, 2), cam.k_matrix, cam.dist_coeffs, None, np.eye(3), np.eye(3), crit
    )
    np.testing.assert_allclose(ours, ref.reshape(-1, 2), atol=1e-7)
    np.testing.assert_allclose(cam.normalized_to_pixels(ours), uv, atol=1e-6)


def test_body_frame_mapping_forward_right_down() -> None:
    cam = CameraModel.from_fov(640, 480, 90.0)
    centre = cam.pixels_to_rays_body([cam.cx, cam.cy])
    right = cam.pixels_to_rays_body([cam.cx + 100, cam.cy])
    down = cam.pixels_to_rays_body([cam.cx, cam.cy + 100])
    np.testing.assert_allclose(centre, [1, 0, 0], atol=1e-12)
    assert right[1] > 0.2 and abs(right[2]) < 1e-12
    assert down[2] > 0.2 and abs(down[1]) < 1e-12
    uv, front = cam.project_body(np.array([5.0, 1.0, -0.5]))
    assert front and uv[0] > cam.cx and uv[1] < cam.cy


def test_extrinsics_mount_and_offset() -> None:
    cam = CameraModel(
        640, 480, 320, 320, 320, 240, mount_rpy_deg=(0.0, -30.0, 0.0), t_body_cam_m=(0.1, 0, 0.05)
    )
    # optical axis pitched 30 degrees down: body direction (cos30, 0, sin30) (FRD, z down)
    axis = cam.pixels_to_rays_body([cam.cx, cam.cy])
    np.testing.assert_allclose(
        axis, [math.cos(math.radians(30)), 0, math.sin(math.radians(30))], atol=1e-12
    )
    p_body = np.array([4.0, -1.0, 2.0])
    beta, rng = cam.bearing_range_body(cam.body_to_cam(p_body))
    np.testing.assert_allclose(beta * rng, p_body, atol=1e-12)


def test_field_of_view() -> None:
    cam = CameraModel.from_fov(640, 480, 90.0)
    assert cam.hfov_deg == pytest.approx(90.0, abs=0.2)
    assert cam.vfov_deg == pytest.approx(2 * math.degrees(math.atan(240 / 320)), abs=0.2)
    assert cam.in_image([[0, 0], [639, 479]]).all()
    assert not cam.in_image([[-1, 0], [np.nan, 3], [640, 10]]).any()


def test_invalid_intrinsics_rejected() -> None:
    with pytest.raises(ValueError):
        CameraModel(640, 480, -1.0, 320, 320, 240)
    with pytest.raises(ValueError):
        CameraModel(0, 480, 320, 320, 320, 240)


def test_bearing_range_of_one_point_matches_the_vectorized_form() -> None:
    cam = CameraModel(
        640, 480, 300.0, 310.0, 322.0, 238.0, DIST, (3.0, -20.0, 10.0), (0.1, -0.05, 0.02)
    )
    pts = np.random.default_rng(4).normal(0.0, 3.0, (20, 3)) + np.array([0.0, 0.0, 8.0])
    bearings, ranges = cam.bearing_range_body(pts)
    for p, b, r in zip(pts, bearings, ranges, strict=True):
        b1, r1 = cam.bearing_range_body(p)
        assert b1.shape == (3,)
        np.testing.assert_allclose(b1, b, rtol=0, atol=1e-15)
        assert float(r1) == pytest.approx(float(r), rel=1e-15)
