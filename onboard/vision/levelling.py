"""IMU attitude compensation (paper 002, "IMU attitude compensation").

The autopilot's roll and pitch are reliable (gravity is observed), its yaw is not. Bearings
measured in the tilted body frame (FRD) are therefore rotated into the *heading* (levelled)
frame: the frame that has the body's yaw but a vertical third axis, which is the body frame of
the project's R^3 x S^1 agent model (docs/equations.md, "Conventions"). With the ZYX attitude of
MAVLink, ``R_ned_body = R_z(yaw) R_y(pitch) R_x(roll)`` and ``R_ned_heading = R_z(yaw)``, so

    beta_level = R_y(pitch) R_x(roll) beta_body.

Pure numpy, vectorized: ``roll``/``pitch`` broadcast against the leading axes of the bearings.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from onboard.geometry import FloatArray


def tilt_matrix(roll_rad: ArrayLike, pitch_rad: ArrayLike) -> FloatArray:
    """``R_y(pitch) R_x(roll)``: body -> heading frame; shape ``(..., 3, 3)``."""
    roll, pitch = np.broadcast_arrays(
        np.asarray(roll_rad, dtype=float), np.asarray(pitch_rad, dtype=float)
    )
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    out = np.empty((*roll.shape, 3, 3))
    out[..., 0, 0] = cp
    out[..., 0, 1] = sp * sr
    out[..., 0, 2] = sp * cr
    out[..., 1, 0] = 0.0
    out[..., 1, 1] = cr
    out[..., 1, 2] = -sr
    out[..., 2, 0] = -sp
    out[..., 2, 1] = cp * sr
    out[..., 2, 2] = cp * cr
    return out


def level_bearings(beta_body: ArrayLike, roll_rad: ArrayLike, pitch_rad: ArrayLike) -> FloatArray:
    """Body-frame vectors ``(..., 3)`` -> heading frame: ``R_y(pitch) R_x(roll) beta``."""
    return np.einsum("...ij,...j->...i", tilt_matrix(roll_rad, pitch_rad), beta_body)


def unlevel_bearings(
    beta_level: ArrayLike, roll_rad: ArrayLike, pitch_rad: ArrayLike
) -> FloatArray:
    """Inverse of :func:`level_bearings`: heading frame -> tilted body frame."""
    return np.einsum("...ji,...j->...i", tilt_matrix(roll_rad, pitch_rad), beta_level)
