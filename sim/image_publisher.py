"""The rendered camera of every simulated vehicle, published as images over Zenoh.

Each vehicle carries a *camera rig* (one or more :class:`~onboard.vision.camera.CameraModel` s,
``camera_id`` = index, each with its own mounting; e.g. one forward camera, or a ring of four
looking forward, right, back and left) and the markers of a markers file (the file the agents
read, ``docs/vision.md``), one per vehicle id:

* ``kind = "disc"``: a **coloured ball** of diameter ``size_m`` centred on the body origin. A
  ball looks the same from every direction, and its silhouette is exactly a disc facing the
  camera (:func:`ball_silhouette`), which is what the renderer draws: the pipeline's disc model
  (paper 002 eq. 32-34) then gives the bearing to the body origin *exactly* and a range short by
  ``r^2 / (2 d)`` (3 mm for a 0.6 m ball at 4 m). Colour: the centre of the HSV range.
* ``kind = "tag"``: four copies of the tag on the vertical sides of a box around the body origin
  (:func:`tag_box`), facing out. The pipeline reports the bearing to the centre of the face it
  sees, off the body origin by up to ``half_box * sin(45 deg)`` sideways.

A vehicle never sees its own markers; markers hide each other (the renderer draws far to near);
the camera sees only what its frustum and pixel size allow (nothing else limits range).

:class:`ImagePublisher` is a tick hook for :class:`sim.server.SimServer`: at ``rate_hz`` of
simulation time it snapshots every vehicle's true pose (truth stays in the simulator: only
images leave it) and hands the snapshot to a worker thread that renders, JPEG-encodes and
publishes one :class:`messages.image.Image` per vehicle and camera on
``bf/<fleet>/<id>/camera/image``, stamped with the snapshot time (the exposure time). The
simulator's loop never waits for a render (its MAVLink streams keep their timing); when the
worker is still busy at the next frame time, that frame is skipped and counted, like a camera
that drops frames. Rendering costs tens of milliseconds per frame and camera on this machine
(``docs/vision.md``, "Flying on camera bearings"), so with several vehicles run the simulator
slower than real time (``--speedup < 1``): the daemons follow the simulation clock.
"""

from __future__ import annotations

import logging
import math
import statistics
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from messages.codec import MessageError, encode
from messages.image import Encoding, image_key, image_payload
from onboard.geometry import FloatArray
from onboard.vision.camera import CameraModel
from onboard.vision.markers import MarkerSpec
from sim.render import (
    TAG_QUIET_CELLS,
    Background,
    Renderer,
    RenderMarker,
    make_background,
    marker_rotation,
    tag_cells,
)
from sim.world import World, tilt_from_specific_force

log = logging.getLogger(__name__)

RENDER_VALUE = 230
"""HSV value (brightness) of the rendered balls: bright, but with headroom for pixel noise."""


@dataclass(frozen=True)
class RenderConfig:
    """How often and how the rig renders (rate in simulation time)."""

    rate_hz: float = 10.0
    blur_sigma_px: float = 0.5
    noise_std: float = 1.0
    """Gaussian pixel noise (grey levels), seeded per frame, vehicle and camera."""
    encoding: Encoding = "jpeg"
    jpeg_quality: int = 90
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.rate_hz > 0.0:
            raise ValueError(f"render rate must be > 0, got {self.rate_hz}")
        if not (self.blur_sigma_px >= 0.0 and self.noise_std >= 0.0):
            raise ValueError("blur and noise must be >= 0")
        if not 1 <= self.jpeg_quality <= 100:
            raise ValueError(f"jpeg quality must be in 1..100, got {self.jpeg_quality}")


@dataclass(frozen=True)
class Poses:
    """True poses of every vehicle at one instant (vehicle index first)."""

    t_s: float
    p_ned: FloatArray
    roll_rad: FloatArray
    pitch_rad: FloatArray
    yaw_rad: FloatArray


def true_poses(t_s: float, world: World, wind_ned: Sequence[float] = (0.0, 0.0, 0.0)) -> Poses:
    """Snapshot of the world: positions, yaw, and the roll and pitch the vehicles fly with
    (the thrust tilt of :func:`sim.world.tilt_from_specific_force`, without sensor noise)."""
    roll, pitch = tilt_from_specific_force(
        world.a_ned, world.v_ned, world.yaw_rad, np.asarray(wind_ned), world.config.drag_per_s
    )
    return Poses(t_s, world.p_ned.copy(), roll.copy(), pitch.copy(), world.yaw_rad.copy())


def hsv_range_bgr(hsv_min: Sequence[int], hsv_max: Sequence[int]) -> tuple[int, int, int]:
    """A fully saturated BGR colour at the centre hue of an OpenCV HSV range (H 0-179;
    ``h_min > h_max`` wraps through red)."""
    h_lo, h_hi = int(hsv_min[0]), int(hsv_max[0])
    if h_lo > h_hi:
        h_hi += 180
    h = ((h_lo + h_hi) // 2) % 180
    bgr = cv2.cvtColor(np.array([[[h, 255, RENDER_VALUE]]], dtype=np.uint8), cv2.COLOR_HSV2BGR)
    b, g, r = (int(x) for x in bgr[0, 0])
    return b, g, r


def ball_silhouette(
    p_ned: FloatArray, diameter_m: float, c_ned: FloatArray
) -> tuple[FloatArray, FloatArray, float] | None:
    """The disc a camera at ``c_ned`` sees of a ball (centre ``p_ned``): the circle where the
    viewing cone touches the ball, at ``d - r^2/d`` from the camera with radius
    ``r sqrt(1 - r^2/d^2)``, facing the camera. Returns ``(centre, R_ned_marker, diameter)``,
    or ``None`` when the camera is inside the ball."""
    r = 0.5 * diameter_m
    offset = np.asarray(p_ned, dtype=float) - c_ned
    d = float(np.linalg.norm(offset))
    if d <= r * (1.0 + 1e-6):
        return None
    u = offset / d
    centre = c_ned + (d - r * r / d) * u
    up = np.array([0.0, 0.0, -1.0]) if abs(u[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    return centre, marker_rotation(-u, up), 2.0 * r * math.sqrt(1.0 - (r / d) ** 2)


def tag_box_half_m(spec: MarkerSpec, cells: int) -> float:
    """Half side of the box whose vertical faces carry the tag with its white quiet zone."""
    return 0.5 * spec.size_m * (1.0 + 2.0 * TAG_QUIET_CELLS / cells)


def tag_box(
    spec: MarkerSpec, p_ned: FloatArray, yaw_rad: float, half_m: float
) -> list[RenderMarker]:
    """The tag of ``spec`` on the four vertical faces of a box of half side ``half_m`` around
    ``p_ned``, turned with the vehicle's yaw, each facing out."""
    out = []
    for k in range(4):
        a = yaw_rad + 0.5 * math.pi * k
        normal = np.array([math.cos(a), math.sin(a), 0.0])
        out.append(
            RenderMarker(
                "tag",
                spec.size_m,
                np.asarray(p_ned, dtype=float) + half_m * normal,
                marker_rotation(normal),
                family=spec.family,
                tag_id=spec.dictionary_id,
            )
        )
    return out


class ImagePublisher:
    """Tick hook: renders every vehicle's camera rig at ``config.rate_hz`` (module docstring).

    ``ids[i]`` is vehicle ``i``'s agent id (default ``i``): the marker with that id rides on it,
    and its images go to ``image_key(fleet, ids[i])``. Call :meth:`close` to stop the worker.
    """

    def __init__(
        self,
        cameras: Sequence[CameraModel],
        markers: Sequence[MarkerSpec],
        config: RenderConfig,
        fleet: str,
        put: Callable[[str, bytes], None],
        ids: Sequence[int] | None = None,
        background: Background | None = None,
        wind_ned: Sequence[float] = (0.0, 0.0, 0.0),
    ) -> None:
        if not cameras:
            raise ValueError("a camera rig needs at least one camera")
        self.config = config
        self.fleet = fleet
        self.put = put
        self.ids = list(ids) if ids is not None else None
        self.wind_ned = tuple(wind_ned)
        room = background if background is not None else make_background(config.seed)
        self.renderers = [Renderer(cam, room) for cam in cameras]
        self.markers = {m.id: m for m in markers}
        self._cells = {m.id: tag_cells(m.family) for m in markers if m.kind == "tag"}
        self.next_t_s = 0.0
        self.frame_index = 0
        self.stats = RenderStats()
        self._pending: Poses | None = None
        self._cond = threading.Condition()
        self._busy = False
        self._stop = False
        self._worker: threading.Thread | None = None

    # --- pure part: one frame --------------------------------------------------------------
    def scene(
        self, poses: Poses, observer: int, ids: Sequence[int], c_ned: FloatArray
    ) -> list[RenderMarker]:
        """Markers of every vehicle but ``observer``, as seen from a camera centre ``c_ned``."""
        out: list[RenderMarker] = []
        for j, vid in enumerate(ids):
            spec = self.markers.get(vid)
            if j == observer or spec is None:
                continue
            if spec.kind == "disc":
                ball = ball_silhouette(poses.p_ned[j], spec.size_m, c_ned)
                if ball is not None:
                    centre, rot, diameter = ball
                    assert spec.color_hsv_min is not None and spec.color_hsv_max is not None
                    colour = hsv_range_bgr(spec.color_hsv_min, spec.color_hsv_max)
                    out.append(RenderMarker("disc", diameter, centre, rot, color_bgr=colour))
            else:
                half = tag_box_half_m(spec, self._cells[vid])
                out += tag_box(spec, poses.p_ned[j], float(poses.yaw_rad[j]), half)
        return out

    def render(self, poses: Poses, vehicle: int, camera_id: int, frame_index: int) -> np.ndarray:
        """The image of camera ``camera_id`` on vehicle ``vehicle`` (index) at ``poses``."""
        ids = self.ids if self.ids is not None else list(range(len(poses.p_ned)))
        renderer = self.renderers[camera_id]
        pose = (
            poses.p_ned[vehicle],
            float(poses.roll_rad[vehicle]),
            float(poses.pitch_rad[vehicle]),
            float(poses.yaw_rad[vehicle]),
        )
        _, c_ned = renderer.camera_pose(*pose)
        cfg = self.config
        seed = int(
            np.random.SeedSequence([cfg.seed, frame_index, vehicle, camera_id]).generate_state(1)[0]
        )
        return renderer.render(
            *pose,
            self.scene(poses, vehicle, ids, c_ned),
            blur_sigma_px=cfg.blur_sigma_px,
            noise_std=cfg.noise_std,
            seed=seed,
        )

    def frames(self, poses: Poses, frame_index: int) -> Iterator[tuple[str, bytes]]:
        """Every encoded :class:`~messages.image.Image` of one frame time, ``(key, bytes)``,
        each yielded as soon as it is rendered (so the first vehicles need not wait for the
        last)."""
        ids = self.ids if self.ids is not None else list(range(len(poses.p_ned)))
        for i, vid in enumerate(ids):
            for k in range(len(self.renderers)):
                t0 = time.perf_counter()
                img = self.render(poses, i, k, frame_index)
                self.stats.add_render(time.perf_counter() - t0)
                try:
                    msg = image_payload(
                        img,
                        sender=vid,
                        camera_id=k,
                        seq=frame_index,
                        stamp_s=poses.t_s,
                        encoding=self.config.encoding,
                        jpeg_quality=self.config.jpeg_quality,
                    )
                except MessageError as exc:  # oversize: lower the quality or the size
                    self.stats.failed += 1
                    log.warning("image of vehicle %d camera %d not sent: %s", vid, k, exc)
                    continue
                yield image_key(self.fleet, vid), encode(msg)

    # --- hook and worker ---------------------------------------------------------------------
    def __call__(self, t_s: float, world: World) -> None:
        if t_s + 1e-9 < self.next_t_s:
            return
        self.next_t_s = max(self.next_t_s + 1.0 / self.config.rate_hz, t_s)
        if self._worker is None:
            self.start()
        with self._cond:
            if self._busy or self._pending is not None:
                self.stats.skipped += 1
                return
            self._pending = true_poses(t_s, world, self.wind_ned)
            self._cond.notify_all()

    def start(self) -> None:
        """Start the render worker (the first tick does it by itself)."""
        if self._worker is None:
            self._worker = threading.Thread(target=self._run, name="render", daemon=True)
            self._worker.start()

    def _run(self) -> None:
        while True:
            with self._cond:
                while self._pending is None and not self._stop:
                    self._cond.wait()
                if self._stop:
                    return
                poses, self._pending, self._busy = self._pending, None, True
            assert poses is not None
            try:
                for k, data in self.frames(poses, self.frame_index):
                    self.put(k, data)
                    self.stats.published += 1
            except Exception:  # a failing render must not stop the simulator
                self.stats.failed += 1
                log.exception("render failed at t=%.2f", poses.t_s)
            self.frame_index += 1
            with self._cond:
                self._busy = False
                self._cond.notify_all()

    def wait_idle(self, timeout_s: float = 30.0) -> bool:
        """Wait until the worker has published every frame handed to it (tests, scripts)."""
        with self._cond:
            return self._cond.wait_for(lambda: not self._busy and self._pending is None, timeout_s)

    def close(self) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        if self._worker is not None:
            self._worker.join(timeout=10.0)

    def status(self) -> str:
        return self.stats.line()


@dataclass
class RenderStats:
    """Counters of the render worker and recent render times (s)."""

    published: int = 0
    skipped: int = 0
    failed: int = 0
    recent_s: deque[float] = field(default_factory=lambda: deque(maxlen=200))

    def add_render(self, dt_s: float) -> None:
        self.recent_s.append(dt_s)

    @property
    def median_render_ms(self) -> float:
        return 1e3 * statistics.median(self.recent_s) if self.recent_s else math.nan

    def line(self) -> str:
        return (
            f"images {self.published} skipped-frames {self.skipped} failed {self.failed} "
            f"render {self.median_render_ms:.0f} ms"
        )
