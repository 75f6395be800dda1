"""The camera model: pinhole intrinsics and lens distortion in OpenCV conventions, mounted on the body.

Pixels ``(u, v)``: ``u`` to the right, ``v`` down, the centre of the top-left pixel at ``(0, 0)``.
The camera frame is OpenCV's: ``z`` forward along the optical axis, ``x`` right, ``y`` down.
A point ``X_cam = (X, Y, Z)`` projects as (paper 002 eq. 24, ``mu p = K Pi P``, plus OpenCV's
five-coefficient distortion ``dist = (k1, k2, p1, p2, k3)``)::

    x = X/Z, y = Y/Z, r2 = x^2 + y^2, radial = 1 + k1 r2 + k2 r2^2 + k3 r2^3
    x_d = x radial + 2 p1 x y + p2 (r2 + 2 x^2)
    y_d = y radial + p1 (r2 + 2 y^2) + 2 p2 x y
    u = fx x_d + cx,  v = fy y_d + cy

``(x, y)`` are *normalized* image coordinates (the paper's ``K = I`` coordinates). Undistortion
inverts the distortion by the same fixed-point iteration as ``cv2.undistortPoints``.

Mounting: with the default extrinsics the optical axis is body ``x`` and the camera frame maps to
body FRD as ``body = (z_cam, x_cam, y_cam)`` (forward, right, down). ``mount_rpy_deg`` rotates the
camera from that default by roll, pitch, yaw about the body axes (``R = R_z R_y R_x``; a camera
pitched 20 degrees down has pitch -20), and ``t_body_cam_m`` is the camera centre in the body frame.
Bearings are returned from the body origin: ``beta_body = normalize(R_body_cam X_cam + t_body_cam)``.

Pure numpy; every function is vectorized over leading axes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import FloatArray

BODY_FROM_CAM_FORWARD = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
"""``R_body_cam`` of a camera looking along body x: ``body = (z_cam, x_cam, y_cam)``."""

UNDISTORT_ITERATIONS = 100
UNDISTORT_TOLERANCE = 1e-12


def rot_rpy(roll_rad: float, pitch_rad: float, yaw_rad: float) -> FloatArray:
    """``R_z(yaw) R_y(pitch) R_x(roll)``: the aerospace (ZYX) attitude convention used by MAVLink."""
    cr, sr = math.cos(roll_rad), math.sin(roll_rad)
    cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    r_x = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    r_y = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    r_z = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return r_z @ r_y @ r_x


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics (pixels), distortion ``(k1, k2, p1, p2, k3)`` and body-frame extrinsics."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)
    mount_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    t_body_cam_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    r_body_cam: FloatArray = field(init=False, repr=False, compare=False)
    _principal: FloatArray = field(init=False, repr=False, compare=False)
    _focal: FloatArray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0) or not all(
            math.isfinite(v) for v in (self.fx, self.fy, self.cx, self.cy, *self.dist)
        ):
            raise ValueError("focal lengths must be positive and all intrinsics finite")
        if len(self.dist) != 5:
            raise ValueError(
                f"dist must have 5 coefficients (k1 k2 p1 p2 k3), got {len(self.dist)}"
            )
        roll, pitch, yaw = (math.radians(a) for a in self.mount_rpy_deg)
        object.__setattr__(self, "r_body_cam", rot_rpy(roll, pitch, yaw) @ BODY_FROM_CAM_FORWARD)
        # (cx, cy) and (fx, fy) as arrays: pixel <-> normalized in two broadcast operations
        object.__setattr__(self, "_principal", np.array([self.cx, self.cy]))
        object.__setattr__(self, "_focal", np.array([self.fx, self.fy]))

    @classmethod
    def from_fov(cls, width: int = 640, height: int = 480, hfov_deg: float = 90.0) -> CameraModel:
        """Distortion-free camera with square pixels, principal point at the image centre."""
        f = 0.5 * width / math.tan(math.radians(hfov_deg) / 2.0)
        return cls(width, height, f, f, 0.5 * width, 0.5 * height)

    @property
    def k_matrix(self) -> FloatArray:
        """Calibration matrix ``K`` of paper 002 eq. 24."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> FloatArray:
        return np.asarray(self.dist, dtype=float)

    @property
    def t_body_cam(self) -> FloatArray:
        return np.asarray(self.t_body_cam_m, dtype=float)

    @property
    def hfov_deg(self) -> float:
        """Horizontal field of view: angle between the rays through the left and right edges."""
        return _angle_deg(self, [[-0.5, self.cy], [self.width - 0.5, self.cy]])

    @property
    def vfov_deg(self) -> float:
        return _angle_deg(self, [[self.cx, -0.5], [self.cx, self.height - 0.5]])

    @property
    def pixel_angle_rad(self) -> float:
        """Angle subtended by one pixel at the principal point (``1 / f``)."""
        return 1.0 / math.sqrt(self.fx * self.fy)

    # --- normalized coordinates <-> pixels -------------------------------------------------

    def distort(self, xy_norm: ArrayLike) -> FloatArray:
        """Apply lens distortion to normalized coordinates ``(..., 2)``."""
        xy = np.asarray(xy_norm, dtype=float)
        if not any(self.dist):  # a pinhole (the rendered cameras): the formula is the identity
            return xy.copy()
        k1, k2, p1, p2, k3 = self.dist
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return np.stack([xd, yd], axis=-1)

    def undistort(self, xy_dist: ArrayLike) -> FloatArray:
        """Invert :meth:`distort` by fixed-point iteration (as ``cv2.undistortPoints``), until the
        step is below 1e-12 or after 100 iterations."""
        xd = np.asarray(xy_dist, dtype=float)
        if not any(self.dist):
            return xd.copy()
        k1, k2, p1, p2, k3 = self.dist
        x, y = xd[..., 0].copy(), xd[..., 1].copy()
        for _ in range(UNDISTORT_ITERATIONS):
            r2 = x * x + y * y
            inv_radial = 1.0 / (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)))
            dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
            dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
            x_new = (xd[..., 0] - dx) * inv_radial
            y_new = (xd[..., 1] - dy) * inv_radial
            step = max(
                float(np.max(np.abs(x_new - x), initial=0.0)),
                float(np.max(np.abs(y_new - y), initial=0.0)),
            )
            x, y = x_new, y_new
            if step < UNDISTORT_TOLERANCE:
                break
        return np.stack([x, y], axis=-1)

    def pixels_to_normalized(self, uv: ArrayLike) -> FloatArray:
        """Pixels ``(..., 2)`` -> undistorted normalized coordinates ``(..., 2)`` (``K^-1`` + undistort)."""
        xd = (np.asarray(uv, dtype=float) - self._principal) / self._focal
        return self.undistort(xd) if any(self.dist) else xd

    def normalized_to_pixels(self, xy_norm: ArrayLike) -> FloatArray:
        """Undistorted normalized coordinates -> pixels (distort + ``K``)."""
        xd = self.distort(xy_norm) if any(self.dist) else np.asarray(xy_norm, dtype=float)
        return xd * self._focal + self._principal

    # --- rays ---------------------------------------------------------------------------------

    def pixels_to_rays_cam(self, uv: ArrayLike) -> FloatArray:
        """Unit rays in the camera frame through pixels ``(..., 2)`` -> ``(..., 3)``."""
        xy = self.pixels_to_normalized(uv)
        ray = np.concatenate([xy, np.ones((*xy.shape[:-1], 1))], axis=-1)
        return ray / np.linalg.norm(ray, axis=-1, keepdims=True)

    def pixels_to_rays_body(self, uv: ArrayLike) -> FloatArray:
        """Unit rays in the body frame (FRD) through pixels, from the camera centre."""
        return self.pixels_to_rays_cam(uv) @ self.r_body_cam.T

    def cam_to_body(self, x_cam: ArrayLike) -> FloatArray:
        """Points in the camera frame -> points in the body frame (``R_body_cam X + t_body_cam``)."""
        return np.asarray(x_cam, dtype=float) @ self.r_body_cam.T + self.t_body_cam

    def body_to_cam(self, x_body: ArrayLike) -> FloatArray:
        return (np.asarray(x_body, dtype=float) - self.t_body_cam) @ self.r_body_cam

    def bearing_range_body(self, x_cam: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Unit bearing (body FRD, from the body origin) and range (m) of camera-frame points."""
        x = np.asarray(x_cam, dtype=float)
        if x.shape == (3,):  # one point (a detection): scalar arithmetic, fewer numpy calls
            xc = x.tolist()
            xb = [
                sum(r * v for r, v in zip(row, xc, strict=True)) + t
                for row, t in zip(self.r_body_cam.tolist(), self.t_body_cam_m, strict=True)
            ]
            rng = math.sqrt(xb[0] * xb[0] + xb[1] * xb[1] + xb[2] * xb[2])
            if rng == 0.0:
                return np.full(3, np.nan), np.float64(0.0)
            return np.array([v / rng for v in xb]), np.float64(rng)
        x_body = self.cam_to_body(x)
        rng = np.linalg.norm(x_body, axis=-1)
        return x_body / rng[..., None], rng

    def project_cam(self, x_cam: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Pixels of camera-frame points ``(..., 3)`` and a mask of points in front of the camera.

        Points behind the camera (``Z <= 0``) get NaN pixels.
        """
        x = np.asarray(x_cam, dtype=float)
        z = x[..., 2]
        front = z > 1e-9
        z_safe = np.where(front, z, 1.0)
        xy = x[..., :2] / z_safe[..., None]
        uv = self.normalized_to_pixels(xy)
        uv[~front] = np.nan
        return uv, front

    def project_body(self, x_body: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Pixels of body-frame points and the in-front mask (see :meth:`project_cam`)."""
        return self.project_cam(self.body_to_cam(x_body))

    def in_image(self, uv: ArrayLike, margin_px: float = 0.0) -> FloatArray:
        """Mask of pixels at least ``margin_px`` inside the image border (NaN -> False)."""
        uv = np.asarray(uv, dtype=float)
        lo = margin_px - 0.5
        with np.errstate(invalid="ignore"):
            return (
                (uv[..., 0] >= lo)
                & (uv[..., 0] <= self.width - 0.5 - margin_px)
                & (uv[..., 1] >= lo)
                & (uv[..., 1] <= self.height - 0.5 - margin_px)
            )

    def pixel_grid(self) -> FloatArray:
        """Pixel centres ``(H, W, 2)`` as ``(u, v)``."""
        v, u = np.mgrid[0 : self.height, 0 : self.width].astype(float)
        return np.stack([u, v], axis=-1)


def _angle_deg(camera: CameraModel, uv: ArrayLike) -> float:
    rays = camera.pixels_to_rays_cam(uv)
    return math.degrees(math.acos(float(np.clip(rays[0] @ rays[1], -1.0, 1.0))))
