"""What a marker detector returns, and what it looks for.

Every detector (coloured discs in :mod:`onboard.vision.discs`, fiducial tags in
:mod:`onboard.vision.tags`) turns one image into a list of :class:`Detection`: the id of the
vehicle carrying the marker, the unit bearing to the marker's centre in the observer's body
frame (FRD, from the body origin), the range in metres, a quality in ``[0, 1]`` and the kind.
:class:`MarkerSpec` describes one marker (the ``[[marker]]`` entries of a markers file, see
``docs/vision.md``). Bad frames raise :class:`messages.image.FrameError`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol

import numpy as np

from onboard.geometry import FloatArray

MarkerKind = Literal["disc", "tag"]
MARKER_KINDS: tuple[str, ...] = ("disc", "tag")


@dataclass(frozen=True)
class MarkerSpec:
    """One marker: carried by vehicle ``id``; ``size_m`` is the disc diameter or the tag side
    (outer edge of the black square). Tags: ``family`` (an OpenCV aruco dictionary name such as
    ``apriltag_36h11``) and ``tag_id`` (defaults to ``id``). Discs: the colour range
    ``color_hsv_min`` .. ``color_hsv_max`` in OpenCV's HSV (H 0-179, S and V 0-255; ``h_min >
    h_max`` wraps through red)."""

    id: int
    kind: MarkerKind
    size_m: float
    family: str = "apriltag_36h11"
    tag_id: int | None = None
    color_hsv_min: tuple[int, int, int] | None = None
    color_hsv_max: tuple[int, int, int] | None = None

    @property
    def dictionary_id(self) -> int:
        """The id inside the tag dictionary (``tag_id`` or, by default, the vehicle id)."""
        return self.id if self.tag_id is None else self.tag_id


@dataclass(frozen=True)
class Detection:
    """One marker seen in one image.

    ``bearing_body``: unit 3-vector (FRD) from the observer's body origin to the marker centre;
    ``range_m``: distance to the marker centre (NaN when the marker size is unknown);
    ``quality``: 0 (barely) .. 1 (clean fit); ``center_px``: the marker centre in the image;
    ``outline_px``: the fitted ellipse or the tag corners, for drawing.
    """

    vehicle_id: int
    kind: MarkerKind
    bearing_body: FloatArray
    range_m: float
    quality: float
    center_px: tuple[float, float]
    outline_px: FloatArray = field(repr=False)

    @property
    def position_body(self) -> FloatArray:
        """Marker centre in the body frame (m): ``range_m * bearing_body``."""
        return self.range_m * self.bearing_body

    def to_json(self) -> dict[str, Any]:
        """Plain JSON-able dict: ``id, kind, bearing_body, range_m (None if unknown), quality, center_px``."""
        return {
            "id": int(self.vehicle_id),
            "kind": self.kind,
            "bearing_body": [float(x) for x in self.bearing_body],
            "range_m": float(self.range_m) if math.isfinite(self.range_m) else None,
            "quality": float(self.quality),
            "center_px": [float(self.center_px[0]), float(self.center_px[1])],
        }


class MarkerDetector(Protocol):
    """A detector of one kind of marker: a validated BGR uint8 frame in, detections out."""

    def detect(self, image_bgr: np.ndarray) -> list[Detection]: ...


def best_per_vehicle(detections: list[Detection]) -> list[Detection]:
    """Keep the highest-quality detection of each vehicle (one identity, one bearing), sorted by id."""
    best: dict[int, Detection] = {}
    for d in detections:
        if d.vehicle_id not in best or d.quality > best[d.vehicle_id].quality:
            best[d.vehicle_id] = d
    return [best[k] for k in sorted(best)]
