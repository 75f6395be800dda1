"""Detector internals that make the pipeline fast and complete: the direct-fit-first ellipse,
colour candidates, contour normals, the tag threshold and corner refinement, edge-of-image tags."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

import onboard.vision.discs as discs
from onboard.vision.camera import CameraModel
from onboard.vision.conics import (
    ellipse_geometry,
    fit_ellipse_direct,
    ransac_ellipse,
    robust_ellipse,
    robust_ellipses,
)
from onboard.vision.edges import contour_normals
from onboard.vision.markers import MarkerSpec
from onboard.vision.pipeline import VisionPipeline
from onboard.vision.tags import (
    TagDetector,
    TagDetectorConfig,
    refine_quad_normalized,
    threshold_constant,
)
from sim.render import Renderer, RenderMarker, make_background, place_in_view

COLOURS = {1: (0, 0, 220), 2: (0, 200, 0), 3: (220, 90, 0)}
HSV_RANGES = {
    1: ((170, 120, 60), (10, 255, 255)),
    2: ((50, 120, 60), (70, 255, 255)),
    3: ((100, 120, 60), (125, 255, 255)),
}
POSE = (np.array([0.0, 0.0, -5.0]), 0.05, -0.04, 0.7)


@pytest.fixture(scope="module")
def renderer() -> Renderer:
    return Renderer(CameraModel.from_fov(640, 480, 90.0), make_background(3, texture_px=512))


def _disc_specs() -> list[MarkerSpec]:
    return [
        MarkerSpec(i, "disc", 0.5, color_hsv_min=lo, color_hsv_max=hi)
        for i, (lo, hi) in HSV_RANGES.items()
    ]


def _ellipse(t: np.ndarray) -> np.ndarray:
    co, si = math.cos(0.4), math.sin(0.4)
    x, y = 7.0 * np.cos(t), 3.0 * np.sin(t)
    return np.column_stack([10.0 + co * x - si * y, -5.0 + si * x + co * y])


def _same_conic(q1: np.ndarray, q2: np.ndarray) -> float:
    a, b = q1 / np.linalg.norm(q1), q2 / np.linalg.norm(q2)
    return float(min(np.abs(a - b).max(), np.abs(a + b).max()))


def test_robust_ellipse_is_the_direct_fit_on_a_clean_contour() -> None:
    rng = np.random.default_rng(0)
    pts = _ellipse(np.linspace(0, 2 * np.pi, 80, endpoint=False)) + rng.normal(0, 0.02, (80, 2))
    fit = robust_ellipse(pts, 0.2, np.random.default_rng(1))
    assert fit.iterations == 0 and fit.inliers.all()
    assert _same_conic(fit.conic, fit_ellipse_direct(pts)) < 1e-9
    # ... and RANSAC on the same points lands on the same ellipse
    ransac = ransac_ellipse(pts, 0.2, np.random.default_rng(1))
    g, h = ellipse_geometry(fit.conic), ellipse_geometry(ransac.conic)
    np.testing.assert_allclose(g.center, h.center, atol=1e-3)
    assert g.semi_minor == pytest.approx(h.semi_minor, abs=1e-3)


def test_robust_ellipse_falls_back_to_ransac_with_outliers() -> None:
    rng = np.random.default_rng(2)
    good = _ellipse(rng.uniform(0, 2 * np.pi, 120)) + rng.normal(0, 0.03, (120, 2))
    bad = rng.uniform([0, -15], [20, 5], (40, 2))
    fit = robust_ellipse(np.vstack([good, bad]), 0.2, rng)
    assert fit.iterations > 0
    g = ellipse_geometry(fit.conic)
    np.testing.assert_allclose(g.center, [10.0, -5.0], atol=0.05)
    assert (g.semi_major, g.semi_minor) == pytest.approx((7.0, 3.0), abs=0.05)
    assert fit.inliers[:120].mean() > 0.95 and fit.inliers[120:].mean() < 0.2


@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_contour_normals_point_outward(direction: float) -> None:
    t = direction * np.linspace(0, 2 * np.pi, 40, endpoint=False)
    centre = np.array([5.0, -3.0])
    pts = centre + 4.0 * np.column_stack([np.cos(t), np.sin(t)])
    n = contour_normals(pts)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    radial = (pts - centre) / 4.0
    assert np.min(np.sum(n * radial, axis=1)) > 0.99


def _disc_scene(renderer: Renderer) -> np.ndarray:
    markers = []
    for vid, (uv, d) in zip(
        COLOURS, (([120, 150], 4.0), ([400, 300], 9.0), ([560, 90], 16.0)), strict=True
    ):
        p, rot = place_in_view(renderer, POSE, uv, d, math.radians(30), 1.0 + vid)
        markers.append(RenderMarker("disc", 0.5, p, rot, color_bgr=COLOURS[vid]))
    # a second, half-hidden blob of colour 2 and a saturated stray (yellow) blob
    p, rot = place_in_view(renderer, POSE, [300, 120], 7.0)
    markers.append(RenderMarker("disc", 0.3, p, rot, color_bgr=COLOURS[2]))
    p, rot = place_in_view(renderer, POSE, [250, 380], 5.0)
    markers.append(RenderMarker("disc", 0.6, p, rot, color_bgr=(0, 220, 220)))
    return renderer.render(*POSE, markers, blur_sigma_px=0.6, noise_std=2.0, seed=5)


def test_colour_candidates_hold_every_blob(renderer: Renderer, monkeypatch) -> None:
    img = _disc_scene(renderer)
    specs = _disc_specs()
    boxes = discs.colour_candidates(img, specs, 64)
    assert 5 <= len(boxes) <= 8  # the five coloured blobs (+ little noise), not the texture
    fast = discs.DiscDetector(renderer.camera, specs).detect(img)
    # the same detector searching the whole frame for each colour finds exactly the same
    h, w = img.shape[:2]
    monkeypatch.setattr(discs, "colour_candidates", lambda *a: np.array([[0, 0, w, h]]))
    full = discs.DiscDetector(renderer.camera, specs).detect(img)
    assert [d.vehicle_id for d in fast] == [d.vehicle_id for d in full] == [1, 2, 3]
    for a, b in zip(fast, full, strict=True):
        np.testing.assert_array_equal(a.bearing_body, b.bearing_body)
        assert a.range_m == b.range_m and a.quality == b.quality


def test_candidate_box_too_small_grows_to_hold_its_blob(renderer: Renderer, monkeypatch) -> None:
    """A box that cuts a disc (a thin part missed by the subsampled mask) is grown until the
    disc's blob fits: same detection as with the whole frame."""
    img = _disc_scene(renderer)
    specs = _disc_specs()
    h, w = img.shape[:2]
    monkeypatch.setattr(discs, "colour_candidates", lambda *a: np.array([[0, 0, w, h]]))
    full = discs.DiscDetector(renderer.camera, specs).detect(img)
    ref = next(d for d in full if d.vehicle_id == 1)  # the 4 m disc, about 40 px across
    u, v = (round(c) for c in ref.center_px)
    monkeypatch.setattr(discs, "colour_candidates", lambda *a: np.array([[u - 3, v - 3, 6, 6]]))
    dets = discs.DiscDetector(renderer.camera, specs).detect(img)
    assert [d.vehicle_id for d in dets] == [1]
    np.testing.assert_array_equal(dets[0].bearing_body, ref.bearing_body)
    assert dets[0].range_m == ref.range_m


def test_overlapping_boxes_give_each_blob_once(renderer: Renderer) -> None:
    img = _disc_scene(renderer)
    det = discs.DiscDetector(renderer.camera, _disc_specs())
    h, w = img.shape[:2]
    once = det._blobs(img, np.array([[0, 0, w, h]]))
    twice = det._blobs(img, np.array([[0, 0, w, h], [0, 0, w, h]]))
    assert [len(b) for b in once] == [1, 2, 1]  # colour 2: the disc and the half-hidden blob
    assert [[a for a, _ in b] for b in twice] == [[a for a, _ in b] for b in once]


def test_saturated_mask_holds_every_hsv_match() -> None:
    """The candidate mask (no HSV conversion) contains every pixel ``inRange`` on OpenCV's HSV
    keeps, for every (max, min) channel pair, and little more (one saturation step)."""
    v, low = np.meshgrid(np.arange(256), np.arange(256), indexing="ij")
    keep = low <= v
    v, low = v[keep].astype(np.uint8), low[keep].astype(np.uint8)
    mid = ((v.astype(int) + low) // 2).astype(np.uint8)
    img = np.stack([low, mid, v], axis=1).reshape(-1, 1, 3)  # B = min, G between, R = max
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    for s_min, v_min in ((120, 60), (40, 0), (200, 150), (1, 1), (0, 0)):
        exact = cv2.inRange(hsv, np.array([0, s_min, v_min]), np.array([255, 255, 255])) > 0
        fast = discs.saturated_mask(img, s_min, v_min) > 0
        assert not np.any(exact & ~fast)
        near = cv2.inRange(hsv, np.array([0, max(s_min - 1, 0), v_min]), np.array([255] * 3)) > 0
        assert not np.any(fast & ~near)


def test_subsample2_keeps_even_pixels() -> None:
    rng = np.random.default_rng(0)
    for h, w in ((480, 640), (7, 10), (6, 9)):
        img = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
        planes = discs.subsample2(img)
        assert len(planes) == 3 and all(p.flags.c_contiguous for p in planes)
        np.testing.assert_array_equal(np.stack(planes, axis=2), img[::2, ::2])


def test_threshold_constant_follows_contrast(renderer: Renderer) -> None:
    grey = cv2.cvtColor(renderer.render(*POSE), cv2.COLOR_BGR2GRAY)
    c1 = threshold_constant(grey, 0.3, 3.0)
    low = np.clip(0.4 * (grey.astype(float) - 128.0) + 128.0, 0, 255).astype(np.uint8)
    assert threshold_constant(low, 0.3, 3.0) == pytest.approx(0.4 * c1, rel=0.05)
    assert threshold_constant(np.full_like(grey, 90), 0.3, 3.0) == 3.0


def _tag_scene(renderer: Renderer, placements, contrast: float = 1.0) -> np.ndarray:
    markers = []
    for tag_id, uv, d in placements:
        p, rot = place_in_view(renderer, POSE, uv, d, math.radians(20), 0.5 * tag_id)
        markers.append(RenderMarker("tag", 0.5, p, rot, tag_id=tag_id))
    img = renderer.render(*POSE, markers, blur_sigma_px=0.6, noise_std=2.0, seed=1)
    return np.clip(contrast * (img.astype(float) - 128.0) + 128.0, 0, 255).astype(np.uint8)


def _tag_specs() -> list[MarkerSpec]:
    return [MarkerSpec(i, "tag", 0.5) for i in (4, 5)]


def test_low_contrast_tags_are_found(renderer: Renderer) -> None:
    pipe = VisionPipeline(renderer.camera, _tag_specs())
    img = _tag_scene(renderer, [(4, [200, 200], 5.0), (5, [450, 300], 8.0)], contrast=0.3)
    assert [d.vehicle_id for d in pipe.process(img)] == [4, 5]


def _black_square_px(renderer: Renderer, p: np.ndarray, rot: np.ndarray) -> np.ndarray:
    r_ned_cam, c_ned = renderer.camera_pose(*POSE)
    square = 0.25 * np.array([[-1, 1], [1, 1], [1, -1], [-1, -1]], dtype=float)
    uv, _ = renderer.camera.project_cam((p + square @ rot[:, :2].T - c_ned) @ r_ned_cam)
    return uv


def test_tag_whose_quiet_zone_leaves_the_image_is_found(renderer: Renderer) -> None:
    """The black square fully inside, its white margin cut by the image edge: OpenCV's default
    ``minDistanceToBorder`` of 3 px dropped such tags (most misses of in-view tags)."""
    cam = renderer.camera
    pipe = VisionPipeline(cam, _tag_specs())
    size = np.array([cam.width - 1, cam.height - 1], dtype=float)
    for uv, axis, side in (
        ([320, 30], 1, 0),
        ([30, 240], 0, 0),
        ([610, 300], 0, 1),
        ([400, 450], 1, 1),
    ):
        uv = np.array(uv, dtype=float)
        for _ in range(4):  # slide the tag until its black square is 2 px from that edge
            p, rot = place_in_view(renderer, POSE, uv, 4.0)
            corners = _black_square_px(renderer, p, rot)[:, axis]
            margin = corners.min() if side == 0 else size[axis] - corners.max()
            uv[axis] += (2.0 - margin) * (1.0 if side == 0 else -1.0)
        assert 1.5 < margin < 2.5  # black square inside, its quiet zone (over 5 px) cut
        img = renderer.render(
            *POSE, [RenderMarker("tag", 0.5, p, rot, tag_id=5)], blur_sigma_px=0.6, noise_std=2.0
        )
        dets = pipe.process(img)
        assert [d.vehicle_id for d in dets] == [5], uv
        r_ned_body = renderer.camera_pose(*POSE)[0] @ cam.r_body_cam.T
        p_body = r_ned_body.T @ (p - POSE[0])
        err = math.degrees(math.acos(dets[0].bearing_body @ p_body / np.linalg.norm(p_body)))
        assert err < 0.2
        assert dets[0].range_m == pytest.approx(np.linalg.norm(p_body), rel=0.02)


def test_refined_corners_match_the_projection(renderer: Renderer) -> None:
    cam = renderer.camera
    p, rot = place_in_view(renderer, POSE, [300, 260], 5.0, math.radians(35), 0.8)
    grey = cv2.cvtColor(
        renderer.render(*POSE, [RenderMarker("tag", 0.5, p, rot, tag_id=4)], blur_sigma_px=0.6),
        cv2.COLOR_BGR2GRAY,
    )
    truth = _black_square_px(renderer, p, rot)
    rough = truth + np.random.default_rng(0).uniform(-0.7, 0.7, truth.shape)
    xy = refine_quad_normalized(cam, grey, rough, 8)
    assert xy is not None
    assert np.max(np.linalg.norm(cam.normalized_to_pixels(xy) - truth, axis=1)) < 0.15
    assert np.max(np.linalg.norm(rough - truth, axis=1)) > 0.4  # the refinement did the work


def test_bad_tag_threshold_window_rejected(renderer: Renderer) -> None:
    for window in (1, 4):
        with pytest.raises(ValueError):
            TagDetector(
                renderer.camera, _tag_specs(), TagDetectorConfig(threshold_window_px=window)
            )


def test_tag_cut_by_the_image_edge_is_not_reported(renderer: Renderer) -> None:
    """Its corners are unknown: no detection (rather than a wrong bearing and range)."""
    pipe = VisionPipeline(renderer.camera, _tag_specs())
    for u in (26.0, 20.0):  # black square 1.4 and 8 px beyond the left edge
        p, rot = place_in_view(renderer, POSE, [u, 200], 6.0)
        assert -9.0 < _black_square_px(renderer, p, rot)[:, 0].min() < -1.0
        img = renderer.render(
            *POSE, [RenderMarker("tag", 0.5, p, rot, tag_id=5)], blur_sigma_px=0.6, noise_std=2.0
        )
        assert pipe.process(img) == []


def test_robust_ellipses_match_one_by_one() -> None:
    """The batched fit gives each set what robust_ellipse gives it alone: direct fit, refit on
    the inliers, RANSAC (the only one drawing), and None for a set that cannot be fitted."""
    rng = np.random.default_rng(7)
    clean = _ellipse(np.linspace(0, 2 * np.pi, 90, endpoint=False)) + rng.normal(0, 0.02, (90, 2))
    few_out = clean.copy()
    few_out[::40] += 0.5  # 3 of 90 off: refit on the inliers, no RANSAC
    good = _ellipse(rng.uniform(0, 2 * np.pi, 120)) + rng.normal(0, 0.03, (120, 2))
    many_out = np.vstack([good, rng.uniform([0, -15], [20, 5], (40, 2))])
    sets = [clean + 5.0, few_out, many_out, clean[:4], clean * 0.01]
    batch = robust_ellipses(sets, 0.2, np.random.default_rng(3))
    for pts, fit in zip(sets, batch, strict=True):
        try:
            alone = robust_ellipse(pts, 0.2, np.random.default_rng(3))
        except ValueError:
            assert fit is None
            continue
        assert fit is not None
        assert fit.iterations == alone.iterations
        np.testing.assert_array_equal(fit.inliers, alone.inliers)
        assert _same_conic(fit.conic, alone.conic) < 1e-9
    assert batch[0].iterations == 0 and batch[0].inliers.all()
    assert batch[1].iterations == 0 and not batch[1].inliers.all()
    assert batch[2].iterations > 0
    assert batch[3] is None
