"""Bearings from the vehicle's own camera images: the camera pipeline behind :class:`BearingSource`.

:class:`CameraImageSource` takes frames of a camera rig (``camera_id`` = index into its
:class:`~onboard.vision.pipeline.VisionPipeline` s, one per camera, each with its mounting),
either as :class:`messages.image.Image` payloads over Zenoh (``bf/<fleet>/<id>/camera/image``,
:meth:`CameraImageSource.subscribe`) or as arrays from a local OpenCV device
(:class:`DeviceCapture`). A worker thread decodes and processes them; the Zenoh callback only
stores the newest payload of each camera (a frame still waiting when a newer one of the same
camera arrives is replaced and counted as skipped: the source keeps up by dropping frames,
never by queueing them).

For each frame the worker

1. decodes it (a bad frame, payload or image, is counted in the daemon's ``DropCounter`` under
   ``camera_<reason>`` and skipped, never raised);
2. runs the pipeline: detections with ``vehicle_id``, a unit ``bearing_body`` (FRD) and quality;
   detections whose outline touches the image border (a marker cut by the frame, whose fit is not
   trusted) are left out; identities outside the fleet, or the vehicle's own, are counted
   (``camera_unknown_target``) and dropped;
3. levels the bearings with the autopilot's roll and pitch *at the frame's stamp* (paper 002,
   "IMU attitude compensation"): the agent core wants heading-frame bearings
   ``R_z(psi)^T (p_j - p_i) / d``, as the simulator's virtual camera gives. The attitude comes
   from :class:`AttitudeHistory`, filled every ``attitude_period_s`` (5 ms: faster than the
   100 Hz ATTITUDE stream the daemon asks for, so no sample is missed) from an ``attitude()``
   callable in the frame's clock; with no attitude within ``max_attitude_gap_s`` of the stamp the
   frame is dropped (``camera_no_attitude``): unlevelled bearings would be wrong by the tilt;
4. gathers the frames of all cameras with the same stamp into one measurement set (a vehicle
   seen by two cameras keeps its best-quality detection): the set is complete when every camera
   has reported, or when a newer stamp arrives first.

:meth:`poll` returns the newest complete set not returned before, as
:class:`~messages.agent.BearingMeasurement` s stamped with the frame time, and
:meth:`frame_ranges` the ranges of that set's detections (discs from their apparent size,
paper 002 eq. 33-34; tags from their pose) as :class:`~messages.agent.RangeMeasurement` s with
the same stamp (paper 002 eq. 22's measured distances). A range that is not finite
(``camera_nonfinite``) or outside :data:`messages.limits.RANGE_MIN_M` ..
:data:`~messages.limits.RANGE_MAX_M` (``camera_out_of_range``) is counted and dropped, its
bearing kept. With ``ranges=False`` (the fleet file's ``[camera] ranges``) no range is given.
"""

from __future__ import annotations

import bisect
import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from messages.agent import BearingMeasurement, RangeMeasurement
from messages.codec import MessageError, decode
from messages.image import Image, image_from_payload, image_key
from messages.limits import plausible_range, stamp_ahead
from messages.vocabulary import DropReason, DropScope
from onboard.daemon.peers import DropCounter, PeerLink
from onboard.vision.markers import Detection
from onboard.vision.pipeline import VisionPipeline

log = logging.getLogger(__name__)

BORDER_MARGIN_PX = 1.0
"""A detection whose outline comes closer than this to the image edge is not trusted."""


@dataclass(frozen=True)
class AttitudeSample:
    """Roll and pitch (rad, FRD/NED ZYX) at time ``t_s`` of the frames' clock."""

    t_s: float
    roll_rad: float
    pitch_rad: float


class AttitudeHistory:
    """The last ``horizon_s`` of attitude samples; :meth:`at` interpolates between them."""

    def __init__(self, horizon_s: float = 3.0, max_gap_s: float = 0.25) -> None:
        self.horizon_s = horizon_s
        self.max_gap_s = max_gap_s
        self._t: list[float] = []
        self._rp: list[tuple[float, float]] = []

    def add(self, s: AttitudeSample) -> None:
        if not all(math.isfinite(x) for x in (s.t_s, s.roll_rad, s.pitch_rad)):
            return
        if self._t and s.t_s <= self._t[-1]:
            if s.t_s == self._t[-1]:
                self._rp[-1] = (s.roll_rad, s.pitch_rad)
            return  # repeated or out of order: keep the history monotonic
        self._t.append(s.t_s)
        self._rp.append((s.roll_rad, s.pitch_rad))
        cut = bisect.bisect_left(self._t, s.t_s - self.horizon_s)
        if cut:
            del self._t[:cut], self._rp[:cut]

    def at(self, t_s: float) -> tuple[float, float] | None:
        """``(roll, pitch)`` at ``t_s``: linear between the samples around it, the nearest one
        within ``max_gap_s`` outside them, else ``None``."""
        if not self._t:
            return None
        k = bisect.bisect_left(self._t, t_s)
        if 0 < k < len(self._t):
            t0, t1 = self._t[k - 1], self._t[k]
            if t1 - t0 <= 2.0 * self.max_gap_s:
                w = (t_s - t0) / (t1 - t0)
                (r0, p0), (r1, p1) = self._rp[k - 1], self._rp[k]
                return r0 + w * (r1 - r0), p0 + w * (p1 - p0)
        nearest = min(
            (j for j in (k - 1, k) if 0 <= j < len(self._t)), key=lambda j: abs(self._t[j] - t_s)
        )
        if abs(self._t[nearest] - t_s) <= self.max_gap_s:
            return self._rp[nearest]
        return None


def inside_image(
    d: Detection, width: int, height: int, margin_px: float = BORDER_MARGIN_PX
) -> bool:
    """Does the detection's outline stay ``margin_px`` away from the image edges?"""
    pts = np.asarray(d.outline_px, dtype=float).reshape(-1, 2)
    if len(pts) == 0:
        return True
    lo = margin_px - 0.5
    return bool(
        np.all(pts[:, 0] >= lo)
        and np.all(pts[:, 0] <= width - 0.5 - margin_px)
        and np.all(pts[:, 1] >= lo)
        and np.all(pts[:, 1] <= height - 0.5 - margin_px)
    )


@dataclass
class SourceStats:
    """What the source did (not bad input, so not in the ``DropCounter``)."""

    frames: int = 0
    skipped: int = 0
    """Frames replaced by a newer one of the same camera before they were processed."""
    late: int = 0
    """Frames older than a set already completed."""
    incomplete: int = 0
    """Sets completed without every camera (a newer stamp came first)."""
    cut: int = 0
    """Detections left out because the marker touches the image border."""
    detections: int = 0
    ranges: int = 0
    """Ranges passed on (at most one per bearing)."""
    process_s: list[float] = field(default_factory=list)


@dataclass
class _Frame:
    camera_id: int
    stamp_s: float
    image: np.ndarray | None = None
    payload: Image | None = None


class CameraImageSource:
    """Bearings from a camera rig (module docstring). ``known`` are the fleet's agent ids."""

    def __init__(
        self,
        agent_id: int,
        pipelines: Sequence[VisionPipeline],
        known: Sequence[int] | frozenset[int],
        drops: DropCounter,
        attitude: Callable[[], AttitudeSample | None] | None,
        *,
        attitude_period_s: float = 0.005,
        max_attitude_gap_s: float = 0.25,
        start: bool = True,
        clock: Callable[[], float | None] | None = None,
        ranges: bool = True,
    ) -> None:
        if not pipelines:
            raise ValueError("a camera source needs at least one camera pipeline")
        self.id = agent_id
        self.pipelines = list(pipelines)
        self.known = frozenset(known)
        self.drops = drops
        self.attitude = attitude
        self.attitude_period_s = attitude_period_s
        self.clock = clock
        """The daemon's clock: an image stamped further ahead of it than
        :data:`messages.limits.STAMP_FUTURE_MAX_S` is dropped (``camera_future_stamp``)."""
        self.ranges = ranges
        """Pass the detections' ranges on (:meth:`frame_ranges`)."""
        self.history = AttitudeHistory(max_gap_s=max_attitude_gap_s)
        self.stats = SourceStats()
        self._cond = threading.Condition()
        self._inbox: dict[int, _Frame] = {}
        self._set_stamp = -math.inf
        self._set: dict[int, Detection] = {}
        self._set_cameras: set[int] = set()
        self._done_stamp = -math.inf
        self._out: tuple[BearingMeasurement, ...] | None = None
        self._out_ranges: tuple[RangeMeasurement, ...] = ()
        self._polled_ranges: tuple[RangeMeasurement, ...] = ()
        self._new = False
        self._out_stamp = -math.inf
        self._stop = False
        self._worker: threading.Thread | None = None
        if start:
            self._worker = threading.Thread(
                target=self._run, name=f"camera-{agent_id}", daemon=True
            )
            self._worker.start()

    # --- input ----------------------------------------------------------------------------------
    def subscribe(self, link: PeerLink) -> CameraImageSource:
        """Take this vehicle's images from Zenoh (``image_key(fleet, id)``)."""
        link.subscribe(
            image_key(link.fleet, self.id), lambda s: self.on_payload(s.payload.to_bytes())
        )
        return self

    def on_payload(self, data: bytes) -> None:
        """One Zenoh sample: validate the payload (cheap) and queue it for the worker."""
        try:
            msg = decode(data, Image)
        except MessageError as exc:
            self.drops.drop(exc.reason, exc.detail, DropScope.CAMERA)
            return
        if msg.sender != self.id:
            self.drops.drop(
                DropReason.SENDER,
                f"image from {msg.sender} on agent {self.id}'s key",
                DropScope.CAMERA,
            )
            return
        if not 0 <= msg.camera_id < len(self.pipelines):
            self.drops.drop(
                DropReason.ID,
                f"camera {msg.camera_id}: the rig has {len(self.pipelines)}",
                DropScope.CAMERA,
            )
            return
        if self.clock is not None and stamp_ahead(msg.stamp_s, self.clock()):
            self.drops.drop(
                DropReason.FUTURE_STAMP, f"image stamped {msg.stamp_s}", DropScope.CAMERA
            )
            return
        self._queue(_Frame(msg.camera_id, msg.stamp_s, payload=msg))

    def on_frame(self, camera_id: int, stamp_s: float, image: Any) -> None:
        """One frame from a local device (an array, or ``None`` for a failed read)."""
        if not 0 <= camera_id < len(self.pipelines):
            self.drops.drop(
                DropReason.ID,
                f"camera {camera_id}: the rig has {len(self.pipelines)}",
                DropScope.CAMERA,
            )
            return
        if not math.isfinite(stamp_s):
            self.drops.drop(DropReason.NONFINITE, f"stamp {stamp_s}", DropScope.CAMERA)
            return
        self._queue(_Frame(camera_id, stamp_s, image=image))

    def _queue(self, frame: _Frame) -> None:
        with self._cond:
            if frame.camera_id in self._inbox:
                self.stats.skipped += 1
            self._inbox[frame.camera_id] = frame
            self._cond.notify()

    # --- worker -----------------------------------------------------------------------------
    def _run(self) -> None:
        next_sample = 0.0
        while True:
            with self._cond:
                if not self._inbox and not self._stop:
                    self._cond.wait(max(0.0, next_sample - time.monotonic()))
                if self._stop:
                    return
            if time.monotonic() >= next_sample:
                next_sample = time.monotonic() + self.attitude_period_s
                self.sample_attitude()
            self.step()

    def step(self) -> int:
        """Process every queued frame, oldest stamp first; returns how many (the worker's body,
        callable directly when the source was built with ``start=False``)."""
        with self._cond:
            frames = sorted(self._inbox.values(), key=lambda f: (f.stamp_s, f.camera_id))
            self._inbox.clear()
        for frame in frames:
            self.sample_attitude()
            self.process(frame)
        return len(frames)

    def sample_attitude(self) -> None:
        """Record the autopilot's current attitude (if any) in the history."""
        if self.attitude is None:
            return
        try:
            s = self.attitude()
        except Exception as exc:  # the link is not our business: never let it stop the camera
            self.drops.drop(DropReason.ATTITUDE_ERROR, repr(exc), DropScope.CAMERA)
            return
        if s is not None:
            self.history.add(s)

    def process(self, frame: _Frame) -> None:
        """Decode, detect, level and gather one frame (the worker calls it; tests too)."""
        if frame.stamp_s <= self._done_stamp:
            self.stats.late += 1
            return
        pipe = self.pipelines[frame.camera_id]
        t0 = time.perf_counter()
        try:
            image = frame.image if frame.payload is None else image_from_payload(frame.payload)
            detections = pipe.process(image)
        except MessageError as exc:  # FrameError: empty, size, dtype, encoding, oversize
            self.drops.drop(exc.reason, exc.detail, DropScope.CAMERA)
            return
        self.stats.frames += 1
        self.stats.process_s.append(time.perf_counter() - t0)
        del self.stats.process_s[:-200]
        kept = []
        for d in detections:
            if d.vehicle_id not in self.known or d.vehicle_id == self.id:
                self.drops.drop(
                    DropReason.UNKNOWN_TARGET, f"marker of vehicle {d.vehicle_id}", DropScope.CAMERA
                )
            elif not np.all(np.isfinite(d.bearing_body)):
                self.drops.drop(
                    DropReason.NONFINITE, f"bearing to {d.vehicle_id}", DropScope.CAMERA
                )
            elif not inside_image(d, pipe.camera.width, pipe.camera.height):
                self.stats.cut += 1
            else:
                kept.append(d)
        self._gather(frame.camera_id, frame.stamp_s, kept)

    def _gather(self, camera_id: int, stamp_s: float, detections: list[Detection]) -> None:
        if stamp_s > self._set_stamp:
            if self._set_cameras:
                self.stats.incomplete += 1
                self._emit()
            self._set_stamp, self._set, self._set_cameras = stamp_s, {}, set()
        self._set_cameras.add(camera_id)
        for d in detections:
            old = self._set.get(d.vehicle_id)
            if old is None or d.quality > old.quality:
                self._set[d.vehicle_id] = d
        if len(self._set_cameras) == len(self.pipelines):
            self._emit()

    def _emit(self) -> None:
        stamp = self._set_stamp
        self._done_stamp = stamp
        self._set_cameras = set()
        dets = [self._set[k] for k in sorted(self._set)]
        self._set = {}
        rp = self.history.at(stamp)
        if rp is None:
            self.drops.drop(
                DropReason.NO_ATTITUDE,
                f"no autopilot attitude near t={stamp:.3f}",
                DropScope.CAMERA,
            )
            return
        ids, beta, rng = self.pipelines[0].bearings_level(dets, rp[0], rp[1])
        out = tuple(
            BearingMeasurement(
                target=int(j), beta_body=(float(b[0]), float(b[1]), float(b[2])), stamp_s=stamp
            )
            for j, b in zip(ids, beta, strict=True)
        )
        ranges = self._ranges(ids, rng.tolist(), stamp) if self.ranges else ()
        self.stats.detections += len(out)
        self.stats.ranges += len(ranges)
        with self._cond:
            self._out, self._new, self._out_stamp = out, True, stamp
            self._out_ranges = ranges

    def _ranges(
        self, ids: list[int], range_m: list[float], stamp_s: float
    ) -> tuple[RangeMeasurement, ...]:
        """The plausible ranges of one set (module docstring); the others counted."""
        out = []
        for j, r in zip(ids, range_m, strict=True):
            if not math.isfinite(r):
                self.drops.drop(DropReason.NONFINITE, f"range to {j}: {r}", DropScope.CAMERA)
            elif not plausible_range(r):
                self.drops.drop(DropReason.OUT_OF_RANGE, f"range to {j}: {r} m", DropScope.CAMERA)
            else:
                out.append(RangeMeasurement(target=int(j), range_m=float(r), stamp_s=stamp_s))
        return tuple(out)

    # --- BearingSource --------------------------------------------------------------------------
    def poll(self) -> tuple[BearingMeasurement, ...] | None:
        with self._cond:
            if not self._new:
                return None
            self._new = False
            self._polled_ranges = self._out_ranges
            return self._out

    def frame_ranges(self) -> tuple[RangeMeasurement, ...]:
        """The ranges of the set the last :meth:`poll` returned (``()`` before the first)."""
        with self._cond:
            return self._polled_ranges

    def age_s(self, now_s: float) -> float:
        with self._cond:
            return max(now_s - self._out_stamp, 0.0)

    def close(self) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify()
        if self._worker is not None:
            self._worker.join(timeout=5.0)


class DeviceCapture:
    """A local camera through ``cv2.VideoCapture`` (a device index such as ``"0"``, a file or a
    stream URL) feeding camera 0 of a :class:`CameraImageSource`, frames stamped with ``clock``
    at capture. A failed read is counted (``camera_device_read``) and retried after ``retry_s``;
    the end of a file stops the capture."""

    def __init__(
        self,
        device: str,
        source: CameraImageSource,
        clock: Callable[[], float | None],
        retry_s: float = 0.5,
    ) -> None:
        import cv2

        self.source = source
        self.clock = clock
        self.retry_s = retry_s
        self.cap = cv2.VideoCapture(int(device) if device.isdigit() else device)
        self.is_file = not device.isdigit() and "://" not in device
        if not self.cap.isOpened():
            raise OSError(f"cannot open camera device {device!r}")
        self._stop = threading.Event()
        self.frames = 0
        self._thread = threading.Thread(target=self._run, name="capture", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            ok, frame = self.cap.read()
            stamp = self.clock()
            if not ok:
                if self.is_file:
                    return
                self.source.drops.drop(
                    DropReason.DEVICE_READ, "VideoCapture.read failed", DropScope.CAMERA
                )
                self._stop.wait(self.retry_s)
                continue
            if stamp is None:
                continue
            self.frames += 1
            self.source.on_frame(0, stamp, frame)

    def wait(self, timeout_s: float | None = None) -> None:
        """Wait for the capture to end (files)."""
        self._thread.join(timeout_s)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.cap.release()
