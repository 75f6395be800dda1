"""The centralized ``SE(3)`` EKF's inputs from a tilted multicopter's own sensors.

Paper 001's filter (:mod:`onboard.estimation.se3_ekf`, eq. 34-35) takes, per agent, body-frame
bearings and body-frame linear and angular velocities. A multicopter of this project measures
its bearings in its camera frame, i.e. in its *tilted* body frame (FRD, roll and pitch
included), and its autopilot reports its attitude (MAVLink ATTITUDE: roll, pitch, yaw and body
rates ``p, q, r``; or ATTITUDE_QUATERNION: ``q = (w, x, y, z)``, body FRD to NED) and its velocity
(LOCAL_POSITION_NED in NED, or a body-frame velocity). This module turns those into the filter's
inputs. Pure functions on numpy arrays, plus :class:`AttitudeBuffer` (no I/O, no clock) that
interpolates the attitude at a camera frame's capture time.

**The choice: level the bearings and run the filter on heading frames** (docs/equations.md,
"Centralized EKF on SE(3)^N", item "Tilted multicopters"). With the ZYX attitude
``R_ned_body = R_z(psi) R_y(theta) R_x(phi)``, a vehicle's heading frame is ``R_z(psi)`` (its
body frame with roll and pitch removed), and

* bearings: ``beta_level = T beta_body``, ``T = R_y(theta) R_x(phi)``
  (:func:`onboard.vision.levelling.level_bearings`; a camera-frame bearing first goes through
  the camera's extrinsic rotation ``R_body_cam``);
* velocity: ``v_heading = T v_body`` (or ``R_z(psi)^T v_ned``);
* angular velocity: the heading frame turns about the vertical at the Euler yaw rate
  ``psidot = (q sin(phi) + r cos(phi)) / cos(theta)`` (the ZYX kinematics), so the filter's
  ``w = (0, 0, psidot)``.

The ``SE(3)`` model is *exact* for heading frames (``R_z(psi + dt psidot) = R_z(psi)
exp(dt hat(psidot e3))``, ``pdot = R_z(psi) v_heading``): the same filter, state and equations,
fed the levelled inputs (the path of :mod:`groundstation.gcs.ekf_loop`). Why this and not the
filter natively on tilted body frames with the gyro's full ``(p, q, r)``:

1. It uses the attitude where it is good. The autopilot's roll and pitch are observed against
   gravity (no drift, a fraction of a degree); run natively, the filter would instead estimate
   every vehicle's tilt relative to the reference from bearings alone (1 degree each) and carry
   it between frames by integrating gyro rates through the fast tilt dynamics. The yaw, which
   the autopilots do not share (each in its own, drifting frame), is not used, only its rate.
2. It is what the team already sends: the daemons level their camera bearings before sending
   them (``onboard/daemon/camera_source.py``, :class:`messages.peer.BearingShare`) and their
   odometry is in the heading frame (:class:`messages.peer.MotionShare`: ``v_body``, yaw rate),
   so one loop serves the daemons' messages and a vehicle's own raw sensors, and the estimate
   lives in the frame of the flight stack's ``R^3 x S^1`` controllers and estimates.
3. Its cost: the attitude's error enters the levelled bearings and velocities;
   :func:`levelled_bearing_sigma_rad` and :func:`heading_motion_sigmas` carry it into the
   filter's noise through the Jacobians :func:`level_jacobian` and
   :func:`heading_motion_jacobian`.

The native alternative is measured beside it in :func:`sim.se3_runner.run_tilted_team`
(``path="native"``, ``python benchmarks/ekf_tilted.py``; 4 vehicles tilting up to 15 degrees,
seeds 0-4): the same scale (0.2-0.6%), relative rotations 0.39-0.65 degrees against 0.15-0.33
for the levelled inputs with a 0.3-degree attitude (docs/equations.md).

Shapes: bearings ``(..., 3)``; angles in rad; ``w_body_rad_s = (p, q, r)``.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import FloatArray, hat, rot_z, so3_exp, so3_log
from onboard.vision.levelling import tilt_matrix

QUATERNION_NORM_TOLERANCE = 1e-3
"""A quaternion whose norm is further than this from 1 is bad input (counted, skipped); within
it, it is normalized (MAVLink sends float32)."""
MAX_TILT_RAD = math.radians(80.0)
"""Roll or pitch beyond this is bad input: the Euler yaw rate divides by ``cos(pitch)``, and no
multicopter of this project flies there."""
ROTATION_TOLERANCE = 1e-3
"""Largest entry of ``R^T R - I`` an attitude matrix may have."""

_E1 = np.array([1.0, 0.0, 0.0])
_E2 = np.array([0.0, 1.0, 0.0])


class BadAttitude(ValueError):
    """An attitude sample the filter cannot use; ``word`` names the counter it increments."""

    def __init__(self, word: str, message: str) -> None:
        super().__init__(message)
        self.word = word


# ---------------------------------------------------------------------------------------------
# Attitude representations (MAVLink ATTITUDE, ATTITUDE_QUATERNION)
# ---------------------------------------------------------------------------------------------


def _check_tilt(roll_rad: float, pitch_rad: float) -> None:
    if abs(pitch_rad) > MAX_TILT_RAD or abs(roll_rad) > MAX_TILT_RAD:
        raise BadAttitude(
            "attitude_out_of_range",
            f"roll {math.degrees(roll_rad):.1f} deg or pitch {math.degrees(pitch_rad):.1f} deg "
            f"beyond {math.degrees(MAX_TILT_RAD):.0f} deg",
        )


def rotation_from_euler(roll_rad: float, pitch_rad: float, yaw_rad: float) -> FloatArray:
    """``R_ned_body = R_z(yaw) R_y(pitch) R_x(roll)`` ``(3, 3)`` from MAVLink ATTITUDE's angles.

    Raises :class:`BadAttitude` (``nonfinite_attitude``, ``attitude_out_of_range``).
    """
    if not all(math.isfinite(float(x)) for x in (roll_rad, pitch_rad, yaw_rad)):
        raise BadAttitude("nonfinite_attitude", "roll, pitch or yaw is not finite")
    _check_tilt(float(roll_rad), float(pitch_rad))
    return rot_z(float(yaw_rad)) @ tilt_matrix(float(roll_rad), float(pitch_rad))


def rotation_from_quaternion(
    q_wxyz: ArrayLike, tolerance: float = QUATERNION_NORM_TOLERANCE
) -> FloatArray:
    """``R_ned_body`` ``(3, 3)`` of ATTITUDE_QUATERNION's ``q = (w, x, y, z)`` (Hamilton, body
    FRD to NED; its ``repr_offset_q`` is not applied). Normalized if within ``tolerance`` of
    unit norm; raises :class:`BadAttitude` (``nonfinite_attitude``, ``non_unit_quaternion``,
    ``attitude_out_of_range``)."""
    q = np.asarray(q_wxyz, dtype=float)
    if q.shape != (4,) or not np.all(np.isfinite(q)):
        raise BadAttitude("nonfinite_attitude", f"quaternion must be 4 finite numbers, got {q}")
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > tolerance:
        raise BadAttitude("non_unit_quaternion", f"quaternion norm {norm:.6f} is not 1")
    w, x, y, z = q / norm
    rot = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    _check_tilt(*tilt_of(rot))
    return rot


def euler_from_rotation(rot_ned_body: ArrayLike) -> tuple[float, float, float]:
    """``(roll, pitch, yaw)`` (rad) of ``R = R_z(yaw) R_y(pitch) R_x(roll)``, ``(3, 3)``."""
    r = np.asarray(rot_ned_body, dtype=float)
    roll = math.atan2(r[2, 1], r[2, 2])
    pitch = -math.asin(max(-1.0, min(1.0, float(r[2, 0]))))
    yaw = math.atan2(r[1, 0], r[0, 0])
    return roll, pitch, yaw


def tilt_of(rot_ned_body: ArrayLike) -> tuple[float, float]:
    """``(roll, pitch)`` (rad) of an attitude: what levelling needs (the yaw is not used)."""
    roll, pitch, _ = euler_from_rotation(rot_ned_body)
    return roll, pitch


# ---------------------------------------------------------------------------------------------
# Levelled inputs and their Jacobians
# ---------------------------------------------------------------------------------------------


def level(
    beta: ArrayLike, roll_rad: float, pitch_rad: float, rot_body_cam: ArrayLike | None = None
) -> FloatArray:
    """Heading-frame bearings ``T R_body_cam beta`` ``(..., 3)`` of tilted-body bearings
    (``rot_body_cam=None``) or camera-frame bearings (``R_body_cam`` the camera's extrinsic
    rotation, e.g. :data:`onboard.vision.camera.BODY_FROM_CAM_FORWARD`)."""
    b = np.asarray(beta, dtype=float)
    if rot_body_cam is not None:
        b = np.einsum("ij,...j->...i", np.asarray(rot_body_cam, dtype=float), b)
    return np.einsum("ij,...j->...i", tilt_matrix(roll_rad, pitch_rad), b)


def level_jacobian(beta_body: ArrayLike, roll_rad: float, pitch_rad: float) -> FloatArray:
    """``d beta_level / d (beta_body, roll, pitch)`` ``(3, 5)`` of :func:`level`.

    ``T = R_y(theta) R_x(phi)``: ``d/d beta = T``, ``d/d phi = hat(R_y(theta) e1) beta_level``,
    ``d/d theta = hat(e2) beta_level`` (``d R_x / d phi = R_x hat(e1)``, ``d R_y / d theta =
    hat(e2) R_y``); checked against finite differences in tests/onboard/test_se3_inputs.py.
    """
    t = tilt_matrix(roll_rad, pitch_rad)
    bl = t @ np.asarray(beta_body, dtype=float)
    a1 = tilt_matrix(0.0, pitch_rad) @ _E1
    return np.column_stack([t, hat(a1) @ bl, hat(_E2) @ bl])


def euler_yaw_rate(w_body_rad_s: ArrayLike, roll_rad: float, pitch_rad: float) -> float:
    """The heading frame's rate ``psidot = (q sin(phi) + r cos(phi)) / cos(theta)`` (rad/s) from
    body rates ``(p, q, r)`` (ZYX kinematics; MAVLink's ``yawspeed`` is ``r``, not ``psidot``)."""
    _, q, r = np.asarray(w_body_rad_s, dtype=float)
    return float((q * math.sin(roll_rad) + r * math.cos(roll_rad)) / math.cos(pitch_rad))


def heading_motion(
    v_body_m_s: ArrayLike, w_body_rad_s: ArrayLike, roll_rad: float, pitch_rad: float
) -> tuple[FloatArray, float]:
    """``(v_heading (3,), psidot)``: the levelled filter's inputs from tilted-body velocity and
    rates: ``v_heading = T v_body``, ``w = (0, 0, psidot)`` (module doc)."""
    v = tilt_matrix(roll_rad, pitch_rad) @ np.asarray(v_body_m_s, dtype=float)
    return v, euler_yaw_rate(w_body_rad_s, roll_rad, pitch_rad)


def heading_motion_jacobian(
    v_body_m_s: ArrayLike, w_body_rad_s: ArrayLike, roll_rad: float, pitch_rad: float
) -> FloatArray:
    """``d (v_heading, psidot) / d (v_body, w_body, roll, pitch)`` ``(4, 8)``.

    ``d v_h / d v_b = T``, ``d v_h / d phi = hat(R_y(theta) e1) v_h``, ``d v_h / d theta =
    hat(e2) v_h``; ``d psidot / d w = (0, sin phi, cos phi) / cos theta``, ``d psidot / d phi =
    (q cos phi - r sin phi) / cos theta``, ``d psidot / d theta = psidot tan theta``.
    """
    v_h, rate = heading_motion(v_body_m_s, w_body_rad_s, roll_rad, pitch_rad)
    _, q, r = np.asarray(w_body_rad_s, dtype=float)
    cr, sr, cp = math.cos(roll_rad), math.sin(roll_rad), math.cos(pitch_rad)
    a1 = tilt_matrix(0.0, pitch_rad) @ _E1
    jac = np.zeros((4, 8))
    jac[:3, :3] = tilt_matrix(roll_rad, pitch_rad)
    jac[:3, 6] = hat(a1) @ v_h
    jac[:3, 7] = hat(_E2) @ v_h
    jac[3, 3:6] = (0.0, sr / cp, cr / cp)
    jac[3, 6] = (q * cr - r * sr) / cp
    jac[3, 7] = rate * math.tan(pitch_rad)
    return jac


def levelled_bearing_sigma_rad(
    beta_body: ArrayLike, roll_rad: float, pitch_rad: float, sigma_rad: float, tilt_sigma_rad: float
) -> float:
    """Isotropic angular standard deviation (rad) of the levelled bearings of one frame: the
    bearing's own ``sigma_rad`` and the attitude's ``tilt_sigma_rad`` (roll and pitch, each)
    through :func:`level_jacobian`'s tilt columns (tangent to the bearing), the largest over
    the frame: ``sqrt(sigma^2 + tilt_sigma^2 max_e lambda_max(J_e^T J_e))``. The tilt error is
    common to a frame's bearings; the filter treats it as independent (a small overstatement of
    the information, bounded by the inflation)."""
    bl = level(np.asarray(beta_body, dtype=float).reshape(-1, 3), roll_rad, pitch_rad)
    c1 = np.cross(tilt_matrix(0.0, pitch_rad) @ _E1, bl)  # the tilt columns, per bearing
    c2 = np.cross(_E2, bl)
    a, b, c = np.sum(c1 * c1, axis=1), np.sum(c2 * c2, axis=1), np.sum(c1 * c2, axis=1)
    lam = 0.5 * (a + b) + np.sqrt(0.25 * (a - b) ** 2 + c * c)  # lambda_max of [[a, c], [c, b]]
    worst = float(np.max(lam)) if len(lam) else 0.0
    return float(math.sqrt(sigma_rad**2 + tilt_sigma_rad**2 * worst))


def heading_motion_sigmas(
    v_body_m_s: ArrayLike,
    w_body_rad_s: ArrayLike,
    roll_rad: float,
    pitch_rad: float,
    velocity_sigma_m_s: float,
    rate_sigma_rad_s: float,
    tilt_sigma_rad: float,
) -> tuple[float, float]:
    """Isotropic standard deviations ``(v_heading m/s, psidot rad/s)`` of :func:`heading_motion`
    from isotropic body-velocity, body-rate and tilt noise, through
    :func:`heading_motion_jacobian` (largest eigenvalue for the velocity block)."""
    j = heading_motion_jacobian(v_body_m_s, w_body_rad_s, roll_rad, pitch_rad)
    cov = (
        j
        @ np.diag([velocity_sigma_m_s**2] * 3 + [rate_sigma_rad_s**2] * 3 + [tilt_sigma_rad**2] * 2)
        @ j.T
    )
    return float(math.sqrt(np.linalg.eigvalsh(cov[:3, :3])[-1])), float(math.sqrt(cov[3, 3]))


# ---------------------------------------------------------------------------------------------
# Attitude at a frame's capture time
# ---------------------------------------------------------------------------------------------


@dataclass
class AttitudeBuffer:
    """The last ``horizon_s`` of one vehicle's attitude samples; :meth:`at` interpolates on
    ``SO(3)`` (``R_0 exp(s log(R_0^T R_1))``) between the two around ``t_s`` when they are at most
    ``2 max_gap_s`` apart, otherwise takes the nearest within ``max_gap_s``, otherwise ``None``
    (as the daemon's levelling, ``onboard/daemon/camera_source.py``)."""

    horizon_s: float = 3.0
    max_gap_s: float = 0.25
    t_s: list[float] = field(default_factory=list)
    rot: list[FloatArray] = field(default_factory=list)

    def add(self, t_s: float, rot_ned_body: ArrayLike) -> None:
        """Append a sample; raises :class:`BadAttitude` (``nonfinite_attitude``, ``not_a_rotation``,
        ``stale_attitude``: not newer than the last one)."""
        r = np.asarray(rot_ned_body, dtype=float)
        if not math.isfinite(t_s) or r.shape != (3, 3) or not np.all(np.isfinite(r)):
            raise BadAttitude("nonfinite_attitude", "attitude stamp or rotation not finite")
        if np.max(np.abs(r.T @ r - np.eye(3))) > ROTATION_TOLERANCE or np.linalg.det(r) < 0.0:
            raise BadAttitude("not_a_rotation", "attitude matrix is not a rotation")
        if self.t_s and t_s <= self.t_s[-1]:
            raise BadAttitude("stale_attitude", f"attitude at {t_s} not after {self.t_s[-1]}")
        self.t_s.append(float(t_s))
        self.rot.append(r.copy())
        cut = bisect.bisect_left(self.t_s, t_s - self.horizon_s)
        if cut:
            del self.t_s[:cut], self.rot[:cut]

    def at(self, t_s: float) -> FloatArray | None:
        """``R_ned_body`` ``(3, 3)`` at ``t_s`` (class doc), or ``None``."""
        if not self.t_s or not math.isfinite(t_s):
            return None
        k = bisect.bisect_left(self.t_s, t_s)
        if k < len(self.t_s) and self.t_s[k] == t_s:
            return self.rot[k].copy()
        if 0 < k < len(self.t_s):
            t0, t1 = self.t_s[k - 1], self.t_s[k]
            if t1 - t0 <= 2.0 * self.max_gap_s:
                s = (t_s - t0) / (t1 - t0)
                r0 = self.rot[k - 1]
                return r0 @ so3_exp(s * so3_log(r0.T @ self.rot[k]))
        near = min(
            (j for j in (k - 1, k) if 0 <= j < len(self.t_s)), key=lambda j: abs(self.t_s[j] - t_s)
        )
        if abs(self.t_s[near] - t_s) <= self.max_gap_s:
            return self.rot[near].copy()
        return None


__all__ = [
    "AttitudeBuffer",
    "BadAttitude",
    "euler_from_rotation",
    "euler_yaw_rate",
    "heading_motion",
    "heading_motion_jacobian",
    "heading_motion_sigmas",
    "level",
    "level_jacobian",
    "levelled_bearing_sigma_rad",
    "rotation_from_euler",
    "rotation_from_quaternion",
    "tilt_of",
]
