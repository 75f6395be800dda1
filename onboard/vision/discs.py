"""Coloured circular targets (paper 002, "Bearing estimation through direct observation").

Once per frame, on the image subsampled by 2, every pixel saturated and bright enough for
*some* marker colour is found (hue ignored; from ``max - min`` of B, G, R and a lookup table, no
HSV conversion) and grouped into blobs (``cv2.findContours``): their bounding boxes, scaled
back to full resolution, are the only places a disc can be (:func:`colour_candidates`). Then,
inside those boxes only, at full resolution (each box converted to HSV once), for each colour
of interest (one per vehicle, so the colour is the identity):

1. threshold the HSV image to the marker's colour range (``cv2.inRange``, hue wrapping through red);
2. take the outer contours of the largest blobs (``cv2.findContours``);
3. move each contour point to the sub-pixel edge (see below), undistort it to normalized
   coordinates (paper 002: "apply ``K^-1``"), and fit an ellipse robustly: the direct
   least-squares fit when it already explains 95% of the points, else adaptive 5-point RANSAC
   (eq. 35) then a direct fit on the inliers (:func:`onboard.vision.conics.robust_ellipse`);
4. turn the conic into the disc's centre (eq. 33-34) -> bearing (body FRD) and range.

Steps 3-4 run for the largest blob of every colour together (one set of numpy calls for all
the discs of a frame: the per-call cost, not the arithmetic, dominates at a few hundred points).

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

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from onboard.geometry import FloatArray, IntArray
from onboard.vision.camera import CameraModel
from onboard.vision.conics import (
    EllipseGeometry,
    RansacEllipse,
    disc_poses_from_conic,
    ellipse_geometry,
    robust_ellipses,
)
from onboard.vision.edges import (
    contour_normals,
    profile_crossings,
    profile_offsets,
    sample_profiles,
)
from onboard.vision.markers import Detection, MarkerSpec

_REACH_OUT_PX = 2.0
"""Edge profiles reach this far out of a blob (and in, up to 0.6 x its radius)."""
_STEP_PX = 0.25
"""Edge profile sampling step."""
_MIN_CHROMA_SPREAD = 20.0
"""An edge profile whose chroma varies less than this has no usable crossing."""


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
    b, g, r = cv2.split(image_bgr)
    return cv2.subtract(cv2.max(cv2.max(b, g), r), cv2.min(cv2.min(b, g), r), dtype=cv2.CV_32F)


def hsv_ranges(
    hsv_min: Sequence[int], hsv_max: Sequence[int]
) -> list[tuple[np.ndarray, np.ndarray]]:
    """``inRange`` bounds (uint8) covering the HSV range: one pair, or two when
    ``h_min > h_max`` (the hue wraps through 0: ``h_min..179`` and ``0..h_max``)."""
    lo = np.asarray(hsv_min, dtype=np.uint8)
    hi = np.asarray(hsv_max, dtype=np.uint8)
    if lo[0] <= hi[0]:
        return [(lo, hi)]
    return [
        (lo, np.array([179, hi[1], hi[2]], dtype=np.uint8)),
        (np.array([0, lo[1], lo[2]], dtype=np.uint8), hi),
    ]


def _mask_of_ranges(hsv: np.ndarray, ranges: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """Union of ``cv2.inRange`` over ``ranges`` (see :func:`hsv_ranges`)."""
    mask = cv2.inRange(hsv, *ranges[0])
    for lo, hi in ranges[1:]:
        mask = cv2.bitwise_or(mask, cv2.inRange(hsv, lo, hi))
    return mask


def subsample2(image_bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The B, G and R planes of every other row and column of a BGR image (pixel ``(2i, 2j)``
    -> ``(i, j)``), contiguous.

    For an even width, rows ``2i`` viewed as pairs of pixels are one 6-channel image whose
    channels 0-2 are the kept pixels: one ``cv2.mixChannels`` copy (faster than ``cv2.resize``
    then ``cv2.split``).
    """
    h, w = image_bgr.shape[:2]
    if w % 2 or not image_bgr.flags.c_contiguous:
        return tuple(np.ascontiguousarray(image_bgr[::2, ::2, k]) for k in range(3))
    planes = tuple(np.empty(((h + 1) // 2, w // 2), dtype=image_bgr.dtype) for _ in range(3))
    cv2.mixChannels([image_bgr.reshape(h, w // 2, 6)[::2]], planes, [0, 0, 1, 1, 2, 2])
    return planes


def saturated_mask(image_bgr: np.ndarray, s_min: int, v_min: int) -> np.ndarray:
    """Mask of the pixels whose OpenCV HSV saturation may reach ``s_min`` and whose value
    reaches ``v_min``, without the HSV conversion.

    ``V = max(B, G, R)`` and ``S = round(255 (V - min(B, G, R)) / V)``, so
    ``V - min >= ceil((s_min - 1) V / 255)`` holds whenever ``S >= s_min`` (checked
    exhaustively in the tests): a superset of ``inRange(hsv, (0, s_min, v_min), (255, 255,
    255))``, by at most a rounding step of saturation. The threshold per ``V`` is a lookup
    table, which also rejects ``V < v_min`` (and black, whose ``S`` is 0).
    """
    return saturated_mask_planes(*cv2.split(image_bgr), s_min, v_min)


def saturated_mask_planes(
    b: np.ndarray, g: np.ndarray, r: np.ndarray, s_min: int, v_min: int
) -> np.ndarray:
    """:func:`saturated_mask` of an image given as its B, G and R planes."""
    v = cv2.max(cv2.max(b, g), r)
    spread = cv2.subtract(v, cv2.min(cv2.min(b, g), r))
    return cv2.compare(spread, cv2.LUT(v, _spread_table(s_min, v_min)), cv2.CMP_GE)


@functools.cache
def _spread_table(s_min: int, v_min: int) -> np.ndarray:
    """``V -> ceil((s_min - 1) V / 255)`` (at least 0); 255 where ``V < v_min`` or, for
    ``s_min > 0``, ``V = 0`` (no spread below 255 passes there)."""
    v = np.arange(256)
    table = np.clip(-((-(s_min - 1) * v) // 255), 0, 255)
    table[v < max(v_min, 1 if s_min > 0 else 0)] = 255
    table = table.astype(np.uint8)
    table.flags.writeable = False
    return table


def colour_candidates(
    image_bgr: np.ndarray, specs: Sequence[MarkerSpec], max_candidates: int
) -> IntArray:
    """Full-resolution boxes ``(K, 4)`` as ``x, y, w, h`` of the blobs that may hold a disc of
    ``specs``, found on the image subsampled by 2 (every other row and column).

    The pixels saturated and bright enough for *some* marker colour (any hue: the smallest
    saturation and value minimum of the colour ranges, :func:`saturated_mask`) form a mask
    whose outer contours (``cv2.findContours``) spanning at least two samples give the boxes,
    at most ``max_candidates`` of them (largest first). A box covers its blob's samples and the
    pixels between them and the next samples (outside the blob): a disc's own colour blob at
    full resolution lies inside it (:meth:`DiscDetector._blobs` grows a box whose blob reaches
    its edge). Subsampling makes this pass 4x cheaper than at full resolution, and the smallest
    discs resolved (8 px across at 20 m) still span several samples.
    """
    s_min = min(s.color_hsv_min[1] for s in specs)
    v_min = min(s.color_hsv_min[2] for s in specs)
    mask = saturated_mask_planes(*subsample2(image_bgr), s_min, v_min)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    rects = np.array([cv2.boundingRect(c) for c in contours], dtype=np.int64).reshape(-1, 4)
    size = rects[:, 2] * rects[:, 3]
    keep = np.flatnonzero(size >= 2)
    keep = keep[np.argsort(-size[keep], kind="stable")][:max_candidates]
    # sample k is pixel 2k: the blob spans pixels 2x - 1 .. 2(x + w - 1) + 1 at most
    return rects[keep] * 2 + np.array([-1, -1, 1, 1])


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
        self._ranges = [hsv_ranges(s.color_hsv_min, s.color_hsv_max) for s in self.specs]

    def detect(self, image_bgr: np.ndarray) -> list[Detection]:
        """Detections of every configured disc (at most one per vehicle)."""
        if not self.specs:
            return []
        cfg = self.config
        boxes = colour_candidates(image_bgr, self.specs, cfg.max_candidates)
        blobs = self._blobs(image_bgr, boxes)
        rng = np.random.default_rng(cfg.seed)
        # The largest blob of every colour (usually the only one) is refined and fitted with
        # the others': one set of numpy calls for all the discs (see robust_ellipses).
        firsts = [k for k, found in enumerate(blobs) if found]
        edges = self._edge_points_many(image_bgr, [blobs[k][0] for k in firsts])
        fitted = self._fit_many(edges, [self.specs[k] for k in firsts], rng)
        dets = dict(zip(firsts, fitted, strict=True))
        out = []
        for k in firsts:
            det = self._best_blob(image_bgr, blobs[k], self.specs[k], rng, dets[k])
            if det is not None:
                out.append(det)
        return out

    def _blobs(
        self, image_bgr: np.ndarray, boxes: IntArray
    ) -> list[list[tuple[float, np.ndarray]]]:
        """For each colour of :attr:`specs`, ``(area, contour)`` of its blobs inside ``boxes``
        (largest first, at most ``max_blobs_per_color``).

        Each box (plus 1 px) is converted to HSV once and thresholded per colour. A blob that
        reaches an edge of its box inside the image did not fit in it (a box from the
        subsampled mask can miss thin parts): the box grows by its own size on every side, up
        to 3 times.
        """
        found: list[list[tuple[float, np.ndarray]]] = [[] for _ in self.specs]
        h, w = image_bgr.shape[:2]
        for x, y, bw, bh in boxes.tolist():
            for _ in range(4):
                u0, v0 = max(x - 1, 0), max(y - 1, 0)
                u1, v1 = min(x + bw + 1, w), min(y + bh + 1, h)
                hsv = cv2.cvtColor(image_bgr[v0:v1, u0:u1], cv2.COLOR_BGR2HSV)
                per_colour = [
                    cv2.findContours(
                        _mask_of_ranges(hsv, ranges),
                        cv2.RETR_EXTERNAL,
                        cv2.CHAIN_APPROX_NONE,
                        offset=(u0, v0),
                    )[0]
                    for ranges in self._ranges
                ]
                if not any(_cut_by_box(c, u0, v0, u1, v1, w, h) for cs in per_colour for c in cs):
                    break
                x, y, bw, bh = x - bw, y - bh, 3 * bw, 3 * bh
            for blobs, contours in zip(found, per_colour, strict=True):
                for c in contours:
                    if len(c) >= 5:
                        area = cv2.contourArea(c)
                        if area >= self.config.min_area_px:
                            blobs.append((area, c))
        out = []
        for blobs in found:
            blobs.sort(key=lambda item: -item[0])
            # overlapping boxes can hold the same blob twice: keep it once
            seen: set[tuple[int, ...]] = set()
            unique = []
            for area, c in blobs:
                key = (*cv2.boundingRect(c), len(c))
                if key not in seen:
                    seen.add(key)
                    unique.append((area, c))
            out.append(unique[: self.config.max_blobs_per_color])
        return out

    def _best_blob(
        self,
        image_bgr: np.ndarray,
        blobs: list[tuple[float, np.ndarray]],
        spec: MarkerSpec,
        rng: np.random.Generator,
        first: Detection | None,
    ) -> Detection | None:
        """The blob of largest ``area x quality`` among ``blobs`` (largest first, the first one
        already fitted as ``first``) as a detection."""
        best: tuple[float, Detection] | None = None
        for i, (area, contour) in enumerate(blobs):
            if best is not None and area <= best[0]:
                break  # score = area x quality <= area: this blob and smaller ones cannot win
            if i == 0:
                det = first
            else:
                det = self._fit_many(
                    self._edge_points_many(image_bgr, [(area, contour)]), [spec], rng
                )[0]
            if det is None:
                continue
            score = area * det.quality
            if best is None or score > best[0]:
                best = (score, det)
        return None if best is None else best[1]

    def _edge_points_many(
        self, image_bgr: np.ndarray, blobs: Sequence[tuple[float, np.ndarray]]
    ) -> list[FloatArray]:
        """Sub-pixel edge points ``(N_k, 2)`` of each ``(area, contour)`` blob (contours as
        ``cv2.findContours`` gives them): mid-level crossings of the chroma along the contour
        normals (:mod:`onboard.vision.edges`); points without a crossing fall back to
        :func:`outward_shift`. Profiles are sampled blob by blob (each in its own chroma
        window) and their crossings found together."""
        cfg = self.config
        h, w = image_bgr.shape[:2]
        pad = math.ceil(_REACH_OUT_PX) + 2
        local, normals, origins, profiles = [], [], [], []
        groups: dict[float, list[int]] = {}
        for i, (area, contour) in enumerate(blobs):
            reach_in = min(_REACH_OUT_PX, 0.6 * math.sqrt(area / math.pi))
            x, y, bw, bh = cv2.boundingRect(contour)
            u0, v0 = max(x - pad, 0), max(y - pad, 0)
            u1, v1 = min(x + bw + pad, w), min(y + bh + pad, h)
            pts = (contour[:, 0, :] - (u0, v0)).astype(float)
            nrm = contour_normals(pts)
            offsets = profile_offsets(reach_in, _REACH_OUT_PX, _STEP_PX)
            profiles.append(
                sample_profiles(
                    chroma(image_bgr[v0:v1, u0:u1]),
                    pts.astype(np.float32),
                    nrm.astype(np.float32),
                    offsets,
                )
            )
            local.append(pts)
            normals.append(nrm)
            origins.append((u0, v0))
            groups.setdefault(reach_in, []).append(i)
        out: list[FloatArray] = [np.zeros((0, 2))] * len(blobs)
        for reach_in, members in groups.items():
            offsets = profile_offsets(reach_in, _REACH_OUT_PX, _STEP_PX)
            sizes = [local[i].shape[0] for i in members]
            shift, ok = profile_crossings(
                np.concatenate([profiles[i] for i in members]), offsets, _MIN_CHROMA_SPREAD
            )
            nrm = np.concatenate([normals[i] for i in members])
            # a point without a crossing stays where it was: shift it as outward_shift does
            inset = np.abs(nrm)
            shift = np.where(ok, shift, 0.5 * np.maximum(inset[:, 0], inset[:, 1]))
            edge = (
                np.concatenate([local[i] for i in members])
                + np.repeat(np.array([origins[i] for i in members], dtype=float), sizes, axis=0)
                + (shift + cfg.edge_offset_px)[:, None] * nrm
            )
            for i, part in zip(members, np.split(edge, np.cumsum(sizes)[:-1]), strict=True):
                out[i] = part
        return out

    def _fit_many(
        self, edge_sets: Sequence[FloatArray], specs: Sequence[MarkerSpec], rng: np.random.Generator
    ) -> list[Detection | None]:
        """The disc detection from each set of edge points (pixels) of a blob of ``specs[k]``'s
        colour: undistorted, fitted robustly (:func:`robust_ellipses`), eq. 33-34."""
        cfg = self.config
        cam = self.camera
        if not edge_sets:
            return []
        sizes = [e.shape[0] for e in edge_sets]
        xy = np.split(cam.pixels_to_normalized(np.concatenate(edge_sets)), np.cumsum(sizes)[:-1])
        fits = robust_ellipses(
            xy,
            cfg.inlier_threshold_px * cam.pixel_angle_rad,
            rng,
            direct_inlier_ratio=cfg.direct_inlier_ratio,
            p_success=cfg.p_success,
            max_iterations=cfg.max_iterations,
        )
        return [
            None if fit is None else self._detection(fit, spec)
            for fit, spec in zip(fits, specs, strict=True)
        ]

    def _detection(self, fit: RansacEllipse, spec: MarkerSpec) -> Detection | None:
        """The disc of ``spec`` whose outline has the (normalized) conic ``fit``: eq. 33-34."""
        cam = self.camera
        try:
            centers, _ = disc_poses_from_conic(fit.conic, 0.5 * spec.size_m)
            geom = ellipse_geometry(fit.conic)
        except (ValueError, np.linalg.LinAlgError):
            return None
        ratio = fit.inlier_ratio
        if ratio < self.config.min_inlier_ratio:
            return None
        # The two poses of eq. 33-34 differ by a small fraction of the range: use their mean.
        center_cam = 0.5 * (centers[0] + centers[1])
        bearing, rng_m = cam.bearing_range_body(center_cam)
        range_m = float(rng_m)
        if not (math.isfinite(range_m) and range_m > 0.0 and center_cam[2] > 0.0):
            return None
        center_uv = cam.normalized_to_pixels(center_cam[:2] / center_cam[2]).tolist()
        return Detection(
            vehicle_id=spec.id,
            kind="disc",
            bearing_body=bearing,
            range_m=range_m,
            quality=ratio,
            center_px=(center_uv[0], center_uv[1]),
            outline_px=cam.normalized_to_pixels(_ellipse_points(geom)),
        )


def _cut_by_box(contour: np.ndarray, u0: int, v0: int, u1: int, v1: int, w: int, h: int) -> bool:
    """Whether a contour (image pixels) touches an edge of the box ``[u0, u1) x [v0, v1)`` that
    is not an image edge (its blob may go on outside the box)."""
    x, y, bw, bh = cv2.boundingRect(contour)
    return (
        (x <= u0 and u0 > 0)
        or (y <= v0 and v0 > 0)
        or (x + bw >= u1 and u1 < w)
        or (y + bh >= v1 and v1 < h)
    )


_UNIT_CIRCLE = np.stack(
    [
        np.cos(np.linspace(0.0, 2.0 * np.pi, 48, endpoint=False)),
        np.sin(np.linspace(0.0, 2.0 * np.pi, 48, endpoint=False)),
    ],
    axis=1,
).reshape(-1, 1, 2)
"""48 points of the unit circle, ``cv2.transform`` layout: the drawn outline of a disc."""


def _ellipse_points(geom: EllipseGeometry) -> FloatArray:
    """48 points ``(48, 2)`` around the ellipse, from the end of its major axis."""
    c, s = math.cos(geom.major_angle_rad), math.sin(geom.major_angle_rad)
    a, b = geom.semi_major, geom.semi_minor
    cu, cv = float(geom.center[0]), float(geom.center[1])
    affine = np.array([[a * c, -b * s, cu], [a * s, b * c, cv]])
    return cv2.transform(_UNIT_CIRCLE, affine).reshape(-1, 2)
