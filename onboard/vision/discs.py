"""Coloured circular targets (paper 002, "Bearing estimation through direct observation").

Once per frame, every pixel saturated and bright enough for *some* marker colour is found with
one ``cv2.inRange`` (hue ignored) and grouped into blobs (``cv2.connectedComponentsWithStats``):
their bounding boxes are the only places a disc can be (:func:`colour_candidates`). Then, for
each colour of interest (one per vehicle, so the colour is the identity), inside those boxes only:

1. threshold the HSV image to the marker's colour range (``cv2.inRange``, hue wrapping through red);
2. take the outer contours of the largest blobs (``cv2.findContours``);
3. move each contour point to the sub-pixel edge (see below), undistort it to normalized
   coordinates (paper 002: "apply ``K^-1``"), and fit an ellipse robustly: the direct
   least-squares fit when it already explains 95% of the points, else adaptive 5-point RANSAC
   (eq. 35) then a direct fit on the inliers (:func:`onboard.vision.conics.robust_ellipse`);
4. turn the conic into the disc's centre (eq. 33-34) -> bearing (body FRD) and range.

Among a colour's blobs the detector keeps the one with the largest ``area x inlier ratio``,
so each vehicle is reported at most once (blobs are fitted largest first, and a blob no larger
than the best score so far cannot win, so it is not fitted).

Edge bias: ``findContours`` returns the centres of the blob's border pixels (those with a
4-neighbour outside). For a straight edge with unit outward normal ``n`` those centres lie
uniformly between 0 and ``max(|n_x|, |n_y|)`` pixels inside the edge, i.e. on average
``max(|n_x|, |n_y|) / 2`` inside. Shifting each point outward by that much removes a bias of about
half a pixel on the radius, which would otherwise be a 6% range error on a 16-pixel disc.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from onboard.geometry import FloatArray, IntArray
from onboard.vision.camera import CameraModel
from onboard.vision.conics import (
    EllipseGeometry,
    disc_poses_from_conic,
    ellipse_geometry,
    robust_ellipse,
)
from onboard.vision.edges import contour_normals, refine_edge_points
from onboard.vision.markers import Detection, MarkerSpec


@dataclass(frozen=True)
class DiscDetectorConfig:
    """Tuning of :class:`DiscDetector` (pixel units)."""

    min_area_px: float = 6.0
    """Blobs smaller than this (contour area) are ignored."""
    max_blobs_per_color: int = 3
    max_candidates: int = 64
    """Largest number of saturated blobs (largest first) searched for marker colours per frame."""
    inlier_threshold_px: float = 0.75
    """Largest Sampson distance of a contour point that counts as an inlier."""
    direct_inlier_ratio: float = 0.95
    """The direct ellipse fit is kept (no RANSAC) when this share of points are inliers."""
    p_success: float = 0.99
    """RANSAC success probability ``p`` of eq. 35."""
    max_iterations: int = 256
    min_inlier_ratio: float = 0.5
    edge_offset_px: float = 0.0
    """Extra outward shift of the contour (calibrates a threshold that is not at 50% coverage)."""
    seed: int = 0
    """RANSAC draws are seeded per frame: the same frame always gives the same detections."""


def outward_shift(contour_px: FloatArray, edge_offset_px: float = 0.0) -> FloatArray:
    """Move closed-contour points outward by ``max(|n_x|, |n_y|)/2 + edge_offset_px`` pixels
    (the mean inset of border-pixel centres, see the module docstring)."""
    p = np.asarray(contour_px, dtype=float)
    return _shift_along(p, contour_normals(p), edge_offset_px)


def _shift_along(p: FloatArray, normal: FloatArray, edge_offset_px: float) -> FloatArray:
    shift = 0.5 * np.max(np.abs(normal), axis=1) + edge_offset_px
    return p + shift[:, None] * normal


def chroma(image_bgr: np.ndarray) -> np.ndarray:
    """``max(B, G, R) - min(B, G, R)`` as float32: linear in a coloured marker's pixel coverage
    over a grey background, so its mid level marks the sub-pixel edge."""
    img = image_bgr.astype(np.float32)
    return img.max(axis=2) - img.min(axis=2)


def hsv_mask(hsv: np.ndarray, hsv_min: Sequence[int], hsv_max: Sequence[int]) -> np.ndarray:
    """Binary mask of pixels within the HSV range; ``h_min > h_max`` wraps the hue through 0."""
    lo = np.asarray(hsv_min, dtype=np.uint8)
    hi = np.asarray(hsv_max, dtype=np.uint8)
    if lo[0] <= hi[0]:
        return cv2.inRange(hsv, lo, hi)
    first = cv2.inRange(hsv, lo, np.array([179, hi[1], hi[2]], dtype=np.uint8))
    second = cv2.inRange(hsv, np.array([0, lo[1], lo[2]], dtype=np.uint8), hi)
    return cv2.bitwise_or(first, second)


def colour_candidates(
    hsv: np.ndarray, specs: Sequence[MarkerSpec], min_area_px: float, max_candidates: int
) -> IntArray:
    """Bounding boxes ``(K, 4)`` as ``x, y, w, h`` of the blobs that may hold a disc of ``specs``.

    One ``inRange`` keeps the pixels whose saturation and value are inside *some* marker's range
    (any hue: the union of all the colour ranges); the outer contours of that mask
    (``cv2.findContours``) enclosing at least ``min_area_px`` give the boxes, at most
    ``max_candidates`` of them (largest first). A marker's own colour mask is a subset of this
    one, so each of its blobs lies inside one of the boxes.
    """
    lo = [0, min(s.color_hsv_min[1] for s in specs), min(s.color_hsv_min[2] for s in specs)]
    hi = [255, max(s.color_hsv_max[1] for s in specs), max(s.color_hsv_max[2] for s in specs)]
    mask = cv2.inRange(hsv, np.array(lo, dtype=np.uint8), np.array(hi, dtype=np.uint8))
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    areas = np.array([cv2.contourArea(c) for c in contours], dtype=float)
    keep = np.flatnonzero(areas >= min_area_px)
    keep = keep[np.argsort(-areas[keep], kind="stable")][:max_candidates]
    return np.array([cv2.boundingRect(contours[k]) for k in keep], dtype=np.int64).reshape(-1, 4)


class DiscDetector:
    """Detects the coloured discs of ``specs`` (kind ``"disc"``) in BGR images of ``camera``."""

    def __init__(
        self,
        camera: CameraModel,
        specs: Sequence[MarkerSpec],
        config: DiscDetectorConfig | None = None,
    ) -> None:
        self.camera = camera
        self.specs = [s for s in specs if s.kind == "disc"]
        for s in self.specs:
            if s.color_hsv_min is None or s.color_hsv_max is None:
                raise ValueError(f"disc marker {s.id} needs color_hsv_min and color_hsv_max")
        self.config = config or DiscDetectorConfig()
        self._bounds = [
            (np.array(s.color_hsv_min, dtype=np.uint8), np.array(s.color_hsv_max, dtype=np.uint8))
            for s in self.specs
        ]

    def detect(self, image_bgr: np.ndarray, hsv: np.ndarray | None = None) -> list[Detection]:
        """Detections of every configured disc (at most one per vehicle)."""
        if not self.specs:
            return []
        if hsv is None:
            hsv = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2HSV)
        cfg = self.config
        boxes = colour_candidates(hsv, self.specs, cfg.min_area_px, cfg.max_candidates)
        rng = np.random.default_rng(cfg.seed)
        out = []
        for spec, bounds in zip(self.specs, self._bounds, strict=True):
            det = self._detect_one(image_bgr, hsv, boxes, spec, bounds, rng)
            if det is not None:
                out.append(det)
        return out

    def _blobs(
        self, hsv: np.ndarray, boxes: IntArray, bounds: tuple[np.ndarray, np.ndarray]
    ) -> list[tuple[float, np.ndarray]]:
        """``(area, contour)`` of the blobs of one colour (HSV ``bounds``) inside ``boxes``,
        largest first."""
        found = []
        h, w = hsv.shape[:2]
        for x, y, bw, bh in boxes:
            u0, v0 = max(int(x) - 1, 0), max(int(y) - 1, 0)
            u1, v1 = min(int(x + bw) + 1, w), min(int(y + bh) + 1, h)
            mask = hsv_mask(hsv[v0:v1, u0:u1], *bounds)
            contours, _ = cv2.findContours(
                mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE, offset=(u0, v0)
            )
            for c in contours:
                if len(c) >= 5:
                    area = cv2.contourArea(c)
                    if area >= self.config.min_area_px:
                        found.append((area, c))
        found.sort(key=lambda item: -item[0])
        return found[: self.config.max_blobs_per_color]

    def _detect_one(
        self,
        image_bgr: np.ndarray,
        hsv: np.ndarray,
        boxes: IntArray,
        spec: MarkerSpec,
        bounds: tuple[np.ndarray, np.ndarray],
        rng: np.random.Generator,
    ) -> Detection | None:
        best: tuple[float, Detection] | None = None
        for area, contour in self._blobs(hsv, boxes, bounds):
            if best is not None and area <= best[0]:
                break  # score = area x quality <= area: this blob and smaller ones cannot win
            edge_px = self._edge_points(image_bgr, contour[:, 0, :].astype(float), area)
            det = self._fit_blob(edge_px, spec, rng)
            if det is None:
                continue
            score = area * det.quality
            if best is None or score > best[0]:
                best = (score, det)
        return None if best is None else best[1]

    def _edge_points(
        self, image_bgr: np.ndarray, contour_px: FloatArray, area: float
    ) -> FloatArray:
        """Sub-pixel edge points of a blob: mid-level crossings of the chroma along the contour
        normals (:mod:`onboard.vision.edges`); points without a crossing fall back to
        :func:`outward_shift`."""
        cfg = self.config
        reach_out = 2.0
        reach_in = min(2.0, 0.6 * math.sqrt(area / math.pi))
        h, w = image_bgr.shape[:2]
        x, y, bw, bh = cv2.boundingRect(contour_px.astype(np.int32))
        pad = math.ceil(reach_out) + 2
        u0, v0 = max(x - pad, 0), max(y - pad, 0)
        u1, v1 = min(x + bw + pad, w), min(y + bh + pad, h)
        score = chroma(image_bgr[v0:v1, u0:u1])
        normals = contour_normals(contour_px)
        offset = np.array([u0, v0], dtype=float)
        refined, ok = refine_edge_points(
            score, contour_px - offset, normals, reach_in, reach_out, min_contrast=20.0
        )
        fallback = _shift_along(contour_px, normals, cfg.edge_offset_px)
        return np.where(ok[:, None], refined + offset + cfg.edge_offset_px * normals, fallback)

    def _fit_blob(
        self, edge_px: FloatArray, spec: MarkerSpec, rng: np.random.Generator
    ) -> Detection | None:
        cfg = self.config
        cam = self.camera
        xy = cam.pixels_to_normalized(edge_px)
        try:
            fit = robust_ellipse(
                xy,
                cfg.inlier_threshold_px * cam.pixel_angle_rad,
                rng,
                direct_inlier_ratio=cfg.direct_inlier_ratio,
                p_success=cfg.p_success,
                max_iterations=cfg.max_iterations,
            )
            centers, _ = disc_poses_from_conic(fit.conic, 0.5 * spec.size_m)
            geom = ellipse_geometry(fit.conic)
        except (ValueError, np.linalg.LinAlgError):
            return None
        if fit.inlier_ratio < cfg.min_inlier_ratio:
            return None
        # The two poses of eq. 33-34 differ by a small fraction of the range: use their mean.
        center_cam = centers.mean(axis=0)
        bearing, rng_m = cam.bearing_range_body(center_cam)
        if not (np.all(np.isfinite(bearing)) and math.isfinite(float(rng_m))):
            return None
        center_uv = cam.project_cam(center_cam)[0]
        return Detection(
            vehicle_id=spec.id,
            kind="disc",
            bearing_body=bearing,
            range_m=float(rng_m),
            quality=float(fit.inlier_ratio),
            center_px=(float(center_uv[0]), float(center_uv[1])),
            outline_px=cam.normalized_to_pixels(_ellipse_points(geom)),
        )


def _ellipse_points(geom: EllipseGeometry, n: int = 48) -> FloatArray:
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    c, s = math.cos(geom.major_angle_rad), math.sin(geom.major_angle_rad)
    x = geom.semi_major * np.cos(t)
    y = geom.semi_minor * np.sin(t)
    return np.stack([geom.center[0] + c * x - s * y, geom.center[1] + s * x + c * y], axis=1)
