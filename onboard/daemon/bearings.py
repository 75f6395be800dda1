"""Bearing sources: where a daemon's body-frame bearings come from.

One interface, :class:`BearingSource`: ``poll()`` returns the bearings of a camera frame not seen
before, or ``None``; a source that also measures distances is a :class:`RangeSource`
(``frame_ranges()``: the ranges of the frame ``poll()`` returned last, same stamp).
:class:`SimCameraSource` takes the simulator's virtual camera
(``bf/<fleet>/<id>/camera/bearings``); the camera pipeline (``onboard.vision``) plugs in behind
the same interface.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

from messages.agent import BearingMeasurement, RangeMeasurement
from messages.codec import MessageError, decode
from messages.limits import stamp_ahead
from messages.sim import CameraBearings, camera_key
from messages.vocabulary import DropReason, DropScope
from onboard.daemon.peers import DropCounter, PeerLink


class BearingSource(Protocol):
    def poll(self) -> tuple[BearingMeasurement, ...] | None:
        """Bearings of the newest frame not returned before, or ``None``."""
        ...

    def age_s(self, now_s: float) -> float:
        """Time since the newest frame was captured (inf before the first)."""
        ...


@runtime_checkable
class RangeSource(Protocol):
    """A :class:`BearingSource` whose frames also carry ranges (the camera pipeline's discs)."""

    def frame_ranges(self) -> tuple[RangeMeasurement, ...]:
        """The ranges of the frame the last ``poll()`` returned (``()`` if none)."""
        ...


class SimCameraSource:
    """The simulator's virtual camera over Zenoh; stamps are simulation time, so use it with the
    daemon's ``clock = "sim"``. Targets outside the fleet are counted and dropped, and so is a
    frame stamped further ahead of ``clock`` (the daemon's) than
    :data:`messages.limits.STAMP_FUTURE_MAX_S` (``camera_future_stamp``): kept as the newest,
    it would hide every real frame after it."""

    def __init__(
        self, link: PeerLink, drops: DropCounter, clock: Callable[[], float | None] | None = None
    ) -> None:
        self.id = link.id
        self.known = link.known
        self.drops = drops
        self.clock = clock
        self._lock = threading.Lock()
        self._frame: tuple[BearingMeasurement, ...] | None = None
        self._new = False
        self._stamp = -math.inf
        link.subscribe(camera_key(link.fleet, link.id), self._on_sample)

    def _on_sample(self, sample: Any) -> None:
        try:
            msg = decode(sample.payload.to_bytes(), CameraBearings)
        except MessageError as exc:
            self.drops.drop(exc.reason, exc.detail, DropScope.CAMERA)
            return
        if msg.sender != self.id or len(msg.targets) != len(msg.beta_body):
            self.drops.drop(DropReason.MALFORMED, f"frame from {msg.sender}", DropScope.CAMERA)
            return
        now_s = self.clock() if self.clock is not None else None
        if stamp_ahead(msg.stamp_s, now_s):
            self.drops.drop(
                DropReason.FUTURE_STAMP, f"frame stamped {msg.stamp_s} at {now_s}", DropScope.CAMERA
            )
            return
        frame = []
        for target, beta in zip(msg.targets, msg.beta_body, strict=True):
            norm = math.sqrt(sum(b * b for b in beta))
            if target not in self.known or target == self.id:
                self.drops.drop(DropReason.UNKNOWN_TARGET, f"target {target}", DropScope.CAMERA)
            elif abs(norm - 1.0) > 1e-3:
                self.drops.drop(DropReason.NOT_UNIT, f"|beta| = {norm}", DropScope.CAMERA)
            else:
                frame.append(BearingMeasurement(target=target, beta_body=beta, stamp_s=msg.stamp_s))
        with self._lock:
            # an older frame is a late duplicate, unless the newest is itself in the future
            # (our clock was reset: a restarted simulator)
            if msg.stamp_s <= self._stamp and not stamp_ahead(self._stamp, now_s):
                return
            self._frame, self._new, self._stamp = tuple(frame), True, msg.stamp_s

    def poll(self) -> tuple[BearingMeasurement, ...] | None:
        with self._lock:
            if not self._new:
                return None
            self._new = False
            return self._frame

    def age_s(self, now_s: float) -> float:
        """Never negative: a frame up to :data:`messages.limits.STAMP_FUTURE_MAX_S` ahead is fresh (age 0)."""
        with self._lock:
            return max(now_s - self._stamp, 0.0)
