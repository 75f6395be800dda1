"""Fiducial tags: OpenCV's ArUco / AprilTag dictionaries -> identity, bearing and range.

``cv2.aruco.ArucoDetector`` finds the tags of each dictionary in use, searching a dictionary
reduced to the configured codes (faster, and a tag with another id is never taken for one of
ours); anything else is ignored (no identity is guessed).

Detector tuning (:class:`TagDetectorConfig`; measured in ``benchmarks/bench_vision.py``):

* one adaptive-threshold pass with a 3-pixel window instead of OpenCV's three (3, 13, 23): the
  threshold only has to find the black square's outline, which a small window marks at any
  size; the threshold constant is ``threshold_rate x`` the standard deviation of the grey
  levels (4x subsampled), so it follows the frame's contrast (a fixed constant either lets the
  background texture through as thousands of contours, or loses low-contrast tags). This pass
  is where OpenCV spends its time: about 10x faster than the defaults on textured frames;
* bits sampled at 8 pixels per cell (OpenCV: 4): small tags (2 px per cell) decode reliably;
* ``minDistanceToBorder = 1`` (OpenCV: 3): a tag whose black square is fully in the image but
  whose quiet zone touches the image edge was rejected with OpenCV's default (the cause of most
  misses of tags fully inside the field of view);
* OpenCV's sub-pixel corner refinement is kept: without it the edge search below starts too far
  from the true edges of small tags (range errors doubled at 15-20 m).

The detected corners are then refined:
points along each side are moved to the sub-pixel mid-level crossing across the black border
(:mod:`onboard.vision.edges`), undistorted, fitted with lines, and the lines intersected
(:func:`refine_quad_normalized`; ArUco's own corners were 0.2-0.5 px inside the true ones on
rendered tags, a 3% range bias at 9 m). ``cv2.solvePnP`` with the planar-square solver
``SOLVEPNP_IPPE_SQUARE`` on those normalized corners gives the tag centre ``t`` (camera frame),
hence the body bearing and the range. Quality falls with the corner reprojection error ``e``
(pixels): ``quality = 1 / (1 + (e / 0.5 px)^2)``.

Dictionary names are the ``cv2.aruco.DICT_*`` constants in lower case without ``dict_``:
``apriltag_36h11``, ``apriltag_25h9``, ``apriltag_16h5``, ``apriltag_36h10``,
``aruco_original``, ``aruco_mip_36h12`` and ``4x4_50`` .. ``7x7_1000`` (also accepted with an
``aruco_`` prefix, e.g. ``aruco_4x4_50``).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from onboard.geometry import FloatArray
from onboard.vision.camera import CameraModel
from onboard.vision.edges import profile_crossings, profile_offsets, sample_profiles_xy
from onboard.vision.markers import Detection, MarkerSpec

_EYE3 = np.eye(3)
_NO_DIST = np.zeros(5)


@functools.cache
def _side_fractions(m: int) -> FloatArray:
    """``m`` evenly spaced positions along a tag side, 12% to 88% of the way (read-only)."""
    s = np.linspace(0.12, 0.88, m)
    s.flags.writeable = False
    return s


def tag_families() -> dict[str, int]:
    """Every dictionary name this module accepts -> its ``cv2.aruco`` constant."""
    out: dict[str, int] = {}
    for name in dir(cv2.aruco):
        if not name.startswith("DICT_"):
            continue
        short = name[len("DICT_") :].lower()
        out[short] = getattr(cv2.aruco, name)
        if short[0].isdigit():
            out["aruco_" + short] = getattr(cv2.aruco, name)
    return out


def dictionary(family: str) -> cv2.aruco.Dictionary:
    """The predefined OpenCV dictionary called ``family``; ``ValueError`` if unknown."""
    families = tag_families()
    if family.lower() not in families:
        raise ValueError(f"unknown tag family {family!r}; known: {', '.join(sorted(families))}")
    return cv2.aruco.getPredefinedDictionary(families[family.lower()])


def refine_quad_normalized(
    camera: CameraModel, gray: np.ndarray, corners_px: FloatArray, cells: int
) -> FloatArray | None:
    """Sub-pixel corners of a tag, in *normalized* (undistorted) coordinates, from its edges.

    Along each side of the detected quad, edge points are moved to the mid-level crossing of the
    darkness profile across the black border (:func:`onboard.vision.edges.profile_crossings`,
    reaching at most 0.8 cell in and out), undistorted, and fitted with a line (total least
    squares); adjacent lines intersect at the corners. ``None`` if a side has too few edge points.
    """
    corners = np.asarray(corners_px, dtype=float).reshape(4, 2)
    quad = corners.tolist()
    cu = 0.25 * sum(u for u, _ in quad)
    cv = 0.25 * sum(v for _, v in quad)
    # per side k (corner k -> k+1): start, direction, length, outward unit normal (scalars)
    sides = []
    for k in range(4):
        (ua, va), (ub, vb) = quad[k], quad[(k + 1) % 4]
        du, dv = ub - ua, vb - va
        length = math.hypot(du, dv)
        if length == 0.0:
            return None  # degenerate quad
        nu, nv = dv / length, -du / length
        if nu * (0.5 * (ua + ub) - cu) + nv * (0.5 * (va + vb) - cv) < 0.0:
            nu, nv = -nu, -nv
        sides.append((ua, va, du, dv, length, nu, nv))
    side_px = 0.25 * sum(sd[4] for sd in sides)
    cell_px = side_px / cells
    m = int(min(max(side_px, 6.0), 64.0))
    reach = min(max(0.8 * cell_px, 0.75), 3.0)
    # Only the tag's neighbourhood is converted to float (the profiles reach ``reach`` px out).
    h, w = gray.shape[:2]
    margin = math.ceil(reach) + 2
    us, vs = [u for u, _ in quad], [v for _, v in quad]
    u0 = min(max(math.floor(min(us)) - margin, 0), w - 1)
    v0 = min(max(math.floor(min(vs)) - margin, 0), h - 1)
    u1 = max(min(math.ceil(max(us)) + margin + 1, w), u0 + 1)
    v1 = max(min(math.ceil(max(vs)) + margin + 1, h), v0 + 1)
    # m points per side (rows), in the window's pixels, and each side's outward normal
    side = np.array(sides)  # (4, 7): ua, va, du, dv, length, nu, nv
    frac = _side_fractions(m)
    px = (side[:, 0:1] - u0) + frac * side[:, 2:3]
    py = (side[:, 1:2] - v0) + frac * side[:, 3:4]
    nx = np.repeat(side[:, 5:6], m, axis=1)
    ny = np.repeat(side[:, 6:7], m, axis=1)
    offsets = profile_offsets(reach, reach, 0.2)
    prof = sample_profiles_xy(
        cv2.subtract(255.0, gray[v0:v1, u0:u1], dtype=cv2.CV_32F),
        px.ravel().astype(np.float32),
        py.ravel().astype(np.float32),
        nx.ravel().astype(np.float32),
        ny.ravel().astype(np.float32),
        offsets,
    )
    shift, ok = profile_crossings(prof, offsets, 25.0)
    shift = shift.reshape(4, m)
    xy = camera.pixels_to_normalized(
        np.stack([px + (shift * nx + u0), py + (shift * ny + v0)], axis=-1)
    )
    weight = ok.reshape(4, m).astype(float)
    x, y = xy[:, :, 0], xy[:, :, 1]
    wx, wy = weight * x, weight * y
    # weighted moments of each side's points: count, sums of x, y, x^2, y^2, xy
    moments = np.stack([weight, wx, wy, wx * x, wy * y, wx * y]).sum(axis=2).T.tolist()
    if min(mom[0] for mom in moments) < 3:
        return None
    # Total least squares line of each side: normal = least-variance direction of its points,
    # i.e. perpendicular to the principal axis of their scatter (closed form in 2-D; the
    # scatter about the mean from the moments: the along-side spread dominates, so the
    # cancellation costs ~1e-14 rad of line angle).
    lines = []
    for count, sx, sy, sxx, syy, sxy in moments:
        cx, cy = sx / count, sy / count
        vxx, vyy, vxy = sxx - sx * cx, syy - sy * cy, sxy - sx * cy
        theta = 0.5 * math.atan2(2.0 * vxy, vxx - vyy)  # principal axis angle
        nx_, ny_ = -math.sin(theta), math.cos(theta)
        lines.append((nx_, ny_, -(nx_ * cx + ny_ * cy)))
    # Corner k is where side k-1 meets side k: the cross product of the two lines.
    out = []
    for k in range(4):
        (a1, b1, c1), (a2, b2, c2) = lines[k - 1], lines[k]
        z = a1 * b2 - b1 * a2
        if abs(z) < 1e-12:
            return None
        out.append(((b1 * c2 - c1 * b2) / z, (c1 * a2 - a1 * c2) / z))
    return np.array(out)


def tag_object_points(side_m: float) -> FloatArray:
    """Corners of a tag of side ``side_m`` in its own frame, in the order ``detectMarkers`` gives
    them (top-left, top-right, bottom-right, bottom-left) as ``SOLVEPNP_IPPE_SQUARE`` needs."""
    h = 0.5 * side_m
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


@dataclass(frozen=True)
class TagDetectorConfig:
    """Tuning of :class:`TagDetector` (see the module docstring for the choices)."""

    corner_refinement: int = cv2.aruco.CORNER_REFINE_SUBPIX
    min_perimeter_rate: float = 0.02
    """Smallest tag perimeter as a fraction of the image's larger side (OpenCV default 0.03)."""
    error_correction_rate: float = 0.6
    threshold_window_px: int = 3
    """Adaptive threshold window (odd, >= 3): a single pass."""
    threshold_rate: float = 0.3
    """Adaptive threshold constant = rate x grey-level standard deviation of the frame."""
    min_threshold_dn: float = 3.0
    """Lower bound of the adaptive threshold constant (grey levels)."""
    pixels_per_cell: int = 8
    """Bit sampling resolution (OpenCV's ``perspectiveRemovePixelPerCell``)."""
    min_distance_to_border_px: int = 1


def threshold_constant(gray: np.ndarray, rate: float, floor_dn: float) -> float:
    """Adaptive-threshold constant of a frame: ``max(floor, rate x std)`` of its grey levels on a
    4x subsampled grid (a pixel is dark when it is this much below its window's mean)."""
    _, std = cv2.meanStdDev(gray[::4, ::4])
    return max(floor_dn, rate * float(std[0, 0]))


class TagDetector:
    """Detects the tags of ``specs`` (kind ``"tag"``) in images of ``camera``."""

    def __init__(
        self,
        camera: CameraModel,
        specs: Sequence[MarkerSpec],
        config: TagDetectorConfig | None = None,
    ) -> None:
        self.camera = camera
        self.config = config or TagDetectorConfig()
        self.specs = [s for s in specs if s.kind == "tag"]
        cfg = self.config
        if cfg.threshold_window_px < 3 or cfg.threshold_window_px % 2 == 0:
            raise ValueError(
                f"threshold_window_px must be odd and >= 3, got {cfg.threshold_window_px}"
            )
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = cfg.corner_refinement
        params.minMarkerPerimeterRate = cfg.min_perimeter_rate
        params.errorCorrectionRate = cfg.error_correction_rate
        params.adaptiveThreshWinSizeMin = cfg.threshold_window_px
        params.adaptiveThreshWinSizeMax = cfg.threshold_window_px
        params.perspectiveRemovePixelPerCell = cfg.pixels_per_cell
        params.minDistanceToBorder = cfg.min_distance_to_border_px
        self._params = params
        self._by_family: dict[str, dict[int, MarkerSpec]] = {}
        for s in self.specs:
            fam = s.family.lower()
            table = self._by_family.setdefault(fam, {})
            if s.dictionary_id in table:
                raise ValueError(f"tag {fam}:{s.dictionary_id} is configured twice")
            table[s.dictionary_id] = s
        # Each family is searched with a dictionary reduced to the configured codes: decoding
        # cost no longer grows with the family size, and a tag with another id cannot be taken
        # for one of ours (codes of a family differ in more bits than the correction allows).
        self._detectors: dict[str, cv2.aruco.ArucoDetector] = {}
        self._index: dict[str, list[MarkerSpec]] = {}
        for fam, table in self._by_family.items():
            full = dictionary(fam)
            ordered = [table[k] for k in sorted(table)]
            for s in ordered:
                if not 0 <= s.dictionary_id < full.bytesList.shape[0]:
                    raise ValueError(f"tag id {s.dictionary_id} is not in {fam}")
            codes = full.bytesList[[s.dictionary_id for s in ordered]]
            reduced = cv2.aruco.Dictionary(codes, full.markerSize, full.maxCorrectionBits)
            self._detectors[fam] = cv2.aruco.ArucoDetector(reduced, params)
            self._index[fam] = ordered
        self._k = camera.k_matrix
        self._dist = camera.dist_coeffs
        self._cells = {fam: int(dictionary(fam).markerSize) + 2 for fam in self._by_family}

    def detect(self, image_bgr: np.ndarray, gray: np.ndarray | None = None) -> list[Detection]:
        """Detections of configured tags; unconfigured ids are ignored."""
        if not self._detectors:
            return []
        if gray is None:
            gray = image_bgr if image_bgr.ndim == 2 else cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY)
        self._params.adaptiveThreshConstant = threshold_constant(
            gray, self.config.threshold_rate, self.config.min_threshold_dn
        )
        out = []
        for fam, det in self._detectors.items():
            det.setDetectorParameters(self._params)
            corners, ids, _ = det.detectMarkers(gray)
            if ids is None:
                continue
            for c, index in zip(corners, ids.ravel(), strict=True):
                spec = self._index[fam][int(index)]
                if spec is not None:
                    d = self._pose(gray, c.reshape(4, 2).astype(float), spec, self._cells[fam])
                    if d is not None:
                        out.append(d)
        return out

    def _pose(
        self, gray: np.ndarray, corners_px: FloatArray, spec: MarkerSpec, cells: int
    ) -> Detection | None:
        cam = self.camera
        obj = tag_object_points(spec.size_m)
        xy = refine_quad_normalized(cam, gray, corners_px, cells)
        if xy is None:
            xy = cam.pixels_to_normalized(corners_px)
        ok, rvec, tvec = cv2.solvePnP(obj, xy, _EYE3, _NO_DIST, flags=cv2.SOLVEPNP_IPPE_SQUARE)
        t = tvec.ravel()
        if not ok or not np.all(np.isfinite(t)) or t[2] <= 0.0:
            return None
        proj, _ = cv2.projectPoints(obj, rvec, tvec, _EYE3, _NO_DIST)
        residual = proj.reshape(4, 2) - xy
        err_px = math.sqrt(float(np.vdot(residual, residual)) / 4.0)
        err_px /= cam.pixel_angle_rad
        bearing, rng_m = cam.bearing_range_body(t)
        center = cam.normalized_to_pixels(t[:2] / t[2]).tolist()
        return Detection(
            vehicle_id=spec.id,
            kind="tag",
            bearing_body=bearing,
            range_m=float(rng_m),
            quality=1.0 / (1.0 + (err_px / 0.5) ** 2),
            center_px=(center[0], center[1]),
            outline_px=cam.normalized_to_pixels(xy),
        )
