"""A rendered virtual camera: what a vehicle's camera sees, drawn pixel by pixel.

The world is a box-shaped room (ground ``z_ned = 0``, ceiling, four walls) with seeded
procedural textures (:func:`make_background`), plus planar markers (coloured discs and ArUco /
AprilTag tags, :class:`RenderMarker`). Every pixel is ray-cast through the camera model of
:mod:`onboard.vision.camera` (intrinsics *and* distortion), so perspective and lens effects are
exactly those the pipeline inverts:

* background: each pixel's ray (camera -> body -> NED) hits the first wall of the box; the wall's
  texture is sampled bilinearly there (``cv2.remap``);
* markers, far to near: the rays of a supersampled region around the marker's projected outline
  are intersected with the marker's plane; a disc is "inside the circle" (double-sided colour),
  a tag samples the real ``cv2.aruco.generateImageMarker`` image with a one-cell white quiet zone
  (front face only; the back is plain grey). Area-averaging the supersamples gives anti-aliased
  edges and true partial-pixel coverage;
* then optional Gaussian blur (``blur_sigma_px``) and seeded Gaussian pixel noise (``noise_std``).

The camera pose is the vehicle's: ``p_ned`` and ZYX attitude ``(roll, pitch, yaw)``;
``R_ned_cam = R_ned_body R_body_cam``. Truth stays here: a renderer produces images only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property

import cv2
import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import FloatArray
from onboard.vision.camera import CameraModel, rot_rpy
from onboard.vision.tags import dictionary

NED_UP = np.array([0.0, 0.0, -1.0])
TAG_QUIET_CELLS = 1
TAG_BACK_GREY = 170


def marker_rotation(normal_ned: ArrayLike, up_ned: ArrayLike = NED_UP) -> FloatArray:
    """``R_ned_marker`` of a planar marker whose front face points along ``normal_ned``: columns
    are the marker's x (right, as seen by a viewer facing it), y (up in the plane) and z (the
    normal). ``up_ned`` must not be parallel to the normal."""
    z = np.asarray(normal_ned, dtype=float)
    z = z / np.linalg.norm(z)
    up = np.asarray(up_ned, dtype=float)
    y = up - (up @ z) * z
    ny = np.linalg.norm(y)
    if ny < 1e-9:
        raise ValueError("up direction is parallel to the marker normal")
    y /= ny
    return np.stack([np.cross(y, z), y, z], axis=1)


@dataclass(frozen=True)
class RenderMarker:
    """A planar marker in the world: centre ``p_ned``, orientation ``r_ned_marker`` (see
    :func:`marker_rotation`), ``size_m`` (disc diameter / tag black-square side).
    Discs: ``color_bgr``. Tags: ``family`` and ``tag_id``."""

    kind: str
    size_m: float
    p_ned: FloatArray
    r_ned_marker: FloatArray
    color_bgr: tuple[int, int, int] = (0, 0, 255)
    family: str = "apriltag_36h11"
    tag_id: int = 0


@dataclass(frozen=True)
class Background:
    """A textured box room: ``|x|, |y| <= half_size_m``, ``-height_m <= z <= 0`` (NED)."""

    half_size_m: float
    height_m: float
    atlas: np.ndarray = field(repr=False)
    """Grey textures of the 6 faces side by side, ``(T, 6 T)`` uint8."""
    tints: FloatArray = field(repr=False)
    """Per-face BGR tint in [0, 1], low saturation so walls never look like a disc colour."""

    @cached_property
    def atlas_bgr(self) -> np.ndarray:
        """The tinted faces, ``(T, 6 T, 3)`` uint8: one 3-channel texture lookup per pixel
        instead of a grey lookup and a per-pixel gather of the face's tint."""
        size = self.atlas.shape[0]
        faces = [
            self.atlas[:, f * size : (f + 1) * size, None] * self.tints[f].astype(np.float32)
            for f in range(6)
        ]
        return np.rint(np.concatenate(faces, axis=1)).astype(np.uint8)


def make_background(
    seed: int, half_size_m: float = 30.0, height_m: float = 20.0, texture_px: int = 1024
) -> Background:
    """Seeded room: multi-octave value noise plus random rectangles (corners for ORB)."""
    rng = np.random.default_rng(seed)
    faces = []
    for _ in range(6):
        tex = np.zeros((texture_px, texture_px), dtype=np.float32)
        for cells, amp in ((4, 50.0), (16, 35.0), (64, 25.0), (256, 15.0)):
            small = rng.uniform(-1.0, 1.0, (cells, cells)).astype(np.float32)
            tex += amp * cv2.resize(small, (texture_px, texture_px), interpolation=cv2.INTER_CUBIC)
        for _ in range(60):
            x0, y0 = rng.integers(0, texture_px, 2)
            w, h = rng.integers(texture_px // 64, texture_px // 8, 2)
            tex[y0 : y0 + h, x0 : x0 + w] += float(rng.uniform(-60.0, 60.0))
        faces.append(np.clip(128.0 + tex, 10, 245).astype(np.uint8))
    tints = 1.0 - 0.18 * rng.uniform(0.0, 1.0, (6, 3))
    return Background(half_size_m, height_m, np.concatenate(faces, axis=1), tints)


class Renderer:
    """Renders views of one camera model; precomputes the camera's pixel rays once."""

    def __init__(
        self, camera: CameraModel, background: Background | None = None, supersample: int = 4
    ) -> None:
        self.camera = camera
        self.background = background if background is not None else make_background(0)
        self.supersample = int(supersample)
        rays = camera.pixels_to_normalized(camera.pixel_grid())
        self._rays_cam = np.concatenate([rays, np.ones((*rays.shape[:2], 1))], axis=-1).astype(
            np.float32
        )
        self._x_cam = np.ascontiguousarray(self._rays_cam[..., 0])
        self._y_cam = np.ascontiguousarray(self._rays_cam[..., 1])
        """Normalized image coordinates of every pixel (the ray is ``(x, y, 1)`` in the camera
        frame), as contiguous planes: the background is computed one NED axis at a time."""

    def camera_pose(
        self, p_ned: ArrayLike, roll_rad: float, pitch_rad: float, yaw_rad: float
    ) -> tuple[FloatArray, FloatArray]:
        """``(R_ned_cam, camera centre in NED)`` of a vehicle pose."""
        r_ned_body = rot_rpy(roll_rad, pitch_rad, yaw_rad)
        c_ned = np.asarray(p_ned, dtype=float) + r_ned_body @ self.camera.t_body_cam
        return r_ned_body @ self.camera.r_body_cam, c_ned

    def render(
        self,
        p_ned: ArrayLike,
        roll_rad: float,
        pitch_rad: float,
        yaw_rad: float,
        markers: Sequence[RenderMarker] = (),
        *,
        blur_sigma_px: float = 0.0,
        noise_std: float = 0.0,
        seed: int | None = None,
    ) -> np.ndarray:
        """BGR uint8 image ``(height, width, 3)`` of the scene from the given vehicle pose."""
        r_ned_cam, c_ned = self.camera_pose(p_ned, roll_rad, pitch_rad, yaw_rad)
        img = self._background(r_ned_cam, c_ned)
        dist = [float(np.linalg.norm(m.p_ned - c_ned)) for m in markers]
        for k in np.argsort(dist)[::-1]:
            self._draw_marker(img, markers[int(k)], r_ned_cam, c_ned)
        if blur_sigma_px > 0.0:
            img = cv2.GaussianBlur(img, (0, 0), blur_sigma_px)
        if noise_std > 0.0:
            img += _pixel_noise(img.shape, noise_std, seed)
        np.rint(img, out=img)
        np.clip(img, 0.0, 255.0, out=img)
        return img.astype(np.uint8)

    # --- background -------------------------------------------------------------------------

    def _background(self, r_ned_cam: FloatArray, c_ned: FloatArray) -> np.ndarray:
        """BGR float32 image of the room: each pixel's ray leaves ``c_ned`` and hits the first
        wall of the box (the smallest positive ray parameter over the three axes; ties go to the
        lower axis), whose tinted texture is sampled there. Computed on ``(H, W)`` planes, one
        NED axis at a time (no ``(H, W, 3)`` temporaries: they dominated the frame time)."""
        bg = self.background
        r = r_ned_cam.astype(np.float32)
        lo = np.array([-bg.half_size_m, -bg.half_size_m, -bg.height_m], dtype=np.float32)
        hi = np.array([bg.half_size_m, bg.half_size_m, 0.0], dtype=np.float32)
        span = np.array([2 * bg.half_size_m, 2 * bg.half_size_m, bg.height_m], dtype=np.float32)
        c = np.clip(c_ned, lo + 1e-3, hi - 1e-3).astype(np.float32)
        # NED ray directions, one plane per axis: d_a = R[a, 0] x + R[a, 1] y + R[a, 2]
        d = [self._x_cam * r[a, 0] + self._y_cam * r[a, 1] + r[a, 2] for a in range(3)]
        # from inside the box the ray leaves through one bound of each axis, at the positive one
        # of (lo - c) / d and (hi - c) / d (1 / d = +-inf for d = +-0 makes it +inf either way)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = []
            for a in range(3):
                inv = np.float32(1.0) / d[a]
                t.append(np.maximum((hi[a] - c[a]) * inv, (lo[a] - c[a]) * inv))
        # the first wall hit: the smallest of the three (ties go to the lower axis)
        t_hit = np.minimum(np.minimum(t[0], t[1]), t[2])
        axis = np.where(t[0] == t_hit, 0, np.where(t[1] == t_hit, 1, 2))
        # where the ray hits, as fractions of the room along each axis
        frac = [(c[a] + t_hit * d[a] - lo[a]) / span[a] for a in range(3)]
        d_hit = np.where(axis == 0, d[0], np.where(axis == 1, d[1], d[2]))
        face = 2 * axis + (d_hit > 0)
        fu = np.where(axis == 0, frac[1], frac[0])  # in-plane texture coordinates of each face
        fv = np.where(axis == 2, frac[1], frac[2])
        size = bg.atlas.shape[0]
        map_x = (face * size + np.clip(fu, 0.0, 1.0) * (size - 1)).astype(np.float32)
        map_y = (np.clip(fv, 0.0, 1.0) * (size - 1)).astype(np.float32)
        return cv2.remap(bg.atlas_bgr, map_x, map_y, cv2.INTER_LINEAR).astype(np.float32)

    # --- markers ----------------------------------------------------------------------------

    def _draw_marker(
        self, img: np.ndarray, m: RenderMarker, r_ned_cam: FloatArray, c_ned: FloatArray
    ) -> None:
        cam = self.camera
        half = 0.5 * m.size_m
        if m.kind == "tag":
            half *= 1.0 + 2.0 * TAG_QUIET_CELLS / tag_cells(m.family)
            outline = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=float) * half
        else:
            th = np.linspace(0.0, 2.0 * np.pi, 32, endpoint=False)
            outline = half / math.cos(np.pi / 32) * np.stack([np.cos(th), np.sin(th)], axis=1)
        pts_ned = m.p_ned + outline @ m.r_ned_marker[:, :2].T
        pts_cam = (pts_ned - c_ned) @ r_ned_cam
        if np.any(pts_cam[:, 2] < 0.05):
            return  # crosses or lies behind the image plane: not drawn
        uv, _ = cam.project_cam(pts_cam)
        u0 = max(math.floor(uv[:, 0].min()) - 2, 0)
        v0 = max(math.floor(uv[:, 1].min()) - 2, 0)
        u1 = min(math.ceil(uv[:, 0].max()) + 3, cam.width)
        v1 = min(math.ceil(uv[:, 1].max()) + 3, cam.height)
        if u1 <= u0 or v1 <= v0:
            return
        ss = self.supersample
        sub = (np.arange(ss) + 0.5) / ss - 0.5
        us = (np.arange(u0, u1)[:, None] + sub[None, :]).ravel()
        vs = (np.arange(v0, v1)[:, None] + sub[None, :]).ravel()
        grid = np.stack(np.meshgrid(us, vs), axis=-1)  # (h*ss, w*ss, 2)
        xy = cam.pixels_to_normalized(grid)
        rays = np.concatenate([xy, np.ones((*xy.shape[:2], 1))], axis=-1) @ r_ned_cam.T
        normal = m.r_ned_marker[:, 2]
        denom = rays @ normal
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((m.p_ned - c_ned) @ normal) / denom
        local = (c_ned + t[..., None] * rays - m.p_ned) @ m.r_ned_marker[:, :2]
        valid = np.isfinite(t) & (t > 0)
        front = float((c_ned - m.p_ned) @ normal) > 0.0
        if m.kind == "tag":
            colour, inside = self._tag_shade(m, local, half, front)
        else:
            inside = np.sum(local**2, axis=-1) <= (0.5 * m.size_m) ** 2
            colour = np.broadcast_to(np.array(m.color_bgr, dtype=np.float32), (*inside.shape, 3))
        alpha = (inside & valid).astype(np.float32)
        h, w = v1 - v0, u1 - u0
        cov = cv2.resize(alpha, (w, h), interpolation=cv2.INTER_AREA)
        col = cv2.resize(
            (colour * alpha[..., None]).astype(np.float32), (w, h), interpolation=cv2.INTER_AREA
        )
        roi = img[v0:v1, u0:u1]
        roi *= 1.0 - cov[..., None]
        roi += col

    def _tag_shade(
        self, m: RenderMarker, local: FloatArray, half: float, front: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        inside = np.all(np.abs(local) <= half, axis=-1)
        if not front:
            grey = np.full((*inside.shape, 3), TAG_BACK_GREY, dtype=np.float32)
            return grey, inside
        tex = _tag_texture(m.family, m.tag_id)
        n = tex.shape[0]
        col = ((local[..., 0] + half) / (2 * half) * n - 0.5).astype(np.float32)
        row = ((half - local[..., 1]) / (2 * half) * n - 0.5).astype(np.float32)
        grey = cv2.remap(tex, col, row, cv2.INTER_NEAREST, borderValue=255).astype(np.float32)
        return np.repeat(grey[..., None], 3, axis=-1), inside


def _pixel_noise(shape: tuple[int, ...], std: float, seed: int | None) -> np.ndarray:
    """Gaussian noise ``(H, W, 3)`` float32 of standard deviation ``std``, the same for the same
    ``seed``. OpenCV's generator, seeded per call (its state is per thread, so the image
    publisher's render thread does not share it): 3-4x faster than numpy's, which took a
    quarter of a 320x240 frame."""
    if seed is None:
        seed = int(np.random.SeedSequence().generate_state(1)[0])
    state = int(np.random.SeedSequence(seed).generate_state(1)[0]) & 0x7FFFFFFF
    out = np.empty(shape, dtype=np.float32)
    cv2.setRNGSeed(state)
    cv2.randn(out, (0.0,) * shape[-1], (float(std),) * shape[-1])
    return out


def tag_cells(family: str) -> int:
    """Cells across the black square: data bits + the 1-cell black border on each side."""
    return int(dictionary(family).markerSize) + 2


def _tag_texture(family: str, tag_id: int, px_per_cell: int = 16) -> np.ndarray:
    """The marker image with its white quiet zone, ``px_per_cell`` pixels per cell."""
    cells = tag_cells(family)
    core = cv2.aruco.generateImageMarker(dictionary(family), tag_id, cells * px_per_cell, 1)
    q = TAG_QUIET_CELLS * px_per_cell
    return cv2.copyMakeBorder(core, q, q, q, q, cv2.BORDER_CONSTANT, value=255)


def place_in_view(
    renderer: Renderer,
    pose: tuple[ArrayLike, float, float, float],
    uv: ArrayLike,
    distance_m: float,
    tilt_rad: float = 0.0,
    tilt_azimuth_rad: float = 0.0,
) -> tuple[FloatArray, FloatArray]:
    """Centre ``p_ned`` and orientation of a marker seen at pixel ``uv``, ``distance_m`` from the
    camera centre, its normal turned ``tilt_rad`` away from facing the camera (about an axis at
    ``tilt_azimuth_rad`` in the marker plane). For studies and tests."""
    r_ned_cam, c_ned = renderer.camera_pose(*pose)
    ray = r_ned_cam @ renderer.camera.pixels_to_rays_cam(np.asarray(uv, dtype=float))
    p = c_ned + distance_m * ray
    facing = marker_rotation(-ray)
    axis_local = np.array([math.cos(tilt_azimuth_rad), math.sin(tilt_azimuth_rad), 0.0])
    axis = facing @ axis_local
    c, s = math.cos(tilt_rad), math.sin(tilt_rad)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    tilt = np.eye(3) + s * k + (1 - c) * (k @ k)
    return p, tilt @ facing
