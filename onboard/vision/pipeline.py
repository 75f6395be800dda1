"""One frame in, marker detections out: the camera bearing source's core (no I/O).

:class:`VisionPipeline` validates the frame (:func:`messages.image.check_frame`: a bad frame
raises :class:`messages.image.FrameError`, which a daemon counts by ``reason`` and skips), runs
the disc and tag detectors for the configured markers, and keeps one detection per vehicle.
Optionally (:meth:`VisionPipeline.bearings_level`) it levels the bearings with the autopilot's
roll and pitch (paper 002, "IMU attitude compensation").
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from messages.image import FrameError, check_frame
from messages.vocabulary import DropReason
from onboard.geometry import FloatArray
from onboard.vision.camera import CameraModel
from onboard.vision.discs import DiscDetector, DiscDetectorConfig
from onboard.vision.levelling import level_bearings
from onboard.vision.markers import Detection, MarkerSpec, best_per_vehicle
from onboard.vision.tags import TagDetector, TagDetectorConfig


class VisionPipeline:
    """Marker detection for one camera: ``process(frame) -> [Detection]`` (one per vehicle)."""

    def __init__(
        self,
        camera: CameraModel,
        markers: Sequence[MarkerSpec],
        *,
        disc_config: DiscDetectorConfig | None = None,
        tag_config: TagDetectorConfig | None = None,
        min_quality: float = 0.0,
    ) -> None:
        self.camera = camera
        self.markers = list(markers)
        self.discs = DiscDetector(camera, self.markers, disc_config)
        self.tags = TagDetector(camera, self.markers, tag_config)
        self.min_quality = min_quality

    def process(self, image: np.ndarray) -> list[Detection]:
        """Detections in a BGR (or grey: tags only) uint8 frame of the camera's size.

        Raises :class:`FrameError` (reasons ``empty``, ``dtype``, ``size``) for a bad frame.
        """
        frame = check_frame(image, self.camera.width, self.camera.height)
        if frame.ndim == 3 and frame.shape[2] == 1:
            frame = frame[:, :, 0]
        found: list[Detection] = []
        if frame.ndim == 3:
            if self.discs.specs:
                found += self.discs.detect(frame)
            if self.tags.specs:
                found += self.tags.detect(frame, cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY))
        else:
            if self.discs.specs and not self.tags.specs:
                raise FrameError(DropReason.SIZE, "colour discs need a 3-channel frame, got grey")
            found += self.tags.detect(frame, frame)
        return best_per_vehicle([d for d in found if d.quality >= self.min_quality])

    def bearings_level(
        self, detections: Sequence[Detection], roll_rad: float, pitch_rad: float
    ) -> tuple[list[int], FloatArray, FloatArray]:
        """``(vehicle ids, levelled unit bearings (K, 3), ranges (K,))`` of ``detections``:
        bearings in the heading frame (roll and pitch removed, paper 002), ranges unchanged."""
        ids = [d.vehicle_id for d in detections]
        if not detections:
            return ids, np.zeros((0, 3)), np.zeros(0)
        beta = np.stack([d.bearing_body for d in detections])
        ranges = np.array([d.range_m for d in detections], dtype=float)
        return ids, level_bearings(beta, roll_rad, pitch_rad), ranges
