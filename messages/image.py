"""Camera images as payloads, and the one error type for a frame that cannot be used.

:class:`Image` carries one compressed frame of camera ``camera_id`` on vehicle ``sender``:

* ``encoding`` — ``"jpeg"`` (default, lossy, full-resolution colour (4:4:4), about 30-120 kB
  at 640x480) or ``"png"`` (lossless, larger), the bytes written by ``cv2.imencode``;
* ``data`` — those bytes, a 3-channel BGR 8-bit image (OpenCV's order) or 1-channel grey;
* ``width``, ``height`` — the decoded size in pixels, checked on decode;
* ``stamp_s`` (from :class:`~messages.codec.Payload`) — the exposure time.

A whole encoded payload must stay under ``messages.codec.MAX_PAYLOAD_BYTES`` (1 MiB);
:func:`image_payload` refuses larger frames (lower the JPEG quality or the resolution).
Key: ``bf/<fleet>/<id>/camera/image`` (:func:`image_key`).

:class:`FrameError` (a :class:`~messages.codec.MessageError`) is raised for every unusable
frame, whether it arrives as a payload or as an array from a local camera: ``reason`` is one of
``empty``, ``size``, ``dtype``, ``encoding``, ``oversize``, so a daemon counts and skips it.
OpenCV is imported inside the functions (``messages`` stays light to import).
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np

from messages.codec import MAX_PAYLOAD_BYTES, MessageError, Payload
from messages.keys import key
from messages.vocabulary import DropReason

IMAGE_TOPIC = "camera/image"
Encoding = Literal["jpeg", "png"]
_EXTENSION = {"jpeg": ".jpg", "png": ".png"}
_HEADER_ALLOWANCE = 256
"""Bytes kept free in ``MAX_PAYLOAD_BYTES`` for the MessagePack fields around ``data``."""


class FrameError(MessageError):
    """A frame that cannot be processed; ``reason`` in ``empty, size, dtype, encoding, oversize``."""


class Image(Payload, tag="image", kw_only=True):
    """One encoded camera frame (see the module docstring for the encoding)."""

    camera_id: int = 0
    width: int
    height: int
    encoding: Encoding = "jpeg"
    data: bytes


def image_key(fleet: str, agent_id: int) -> str:
    return key(fleet, agent_id, IMAGE_TOPIC)


def check_frame(image: Any, width: int | None = None, height: int | None = None) -> np.ndarray:
    """Validate a decoded frame: a non-empty uint8 ``(H, W)`` or ``(H, W, 3)`` array of the
    expected size (when given). Returns it as an ndarray; raises :class:`FrameError`."""
    if image is None:
        raise FrameError(DropReason.EMPTY, "no image")
    arr = np.asarray(image)
    if arr.size == 0:
        raise FrameError(DropReason.EMPTY, f"image of shape {arr.shape}")
    if arr.dtype != np.uint8:
        raise FrameError(DropReason.DTYPE, f"expected uint8 pixels, got {arr.dtype}")
    if arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[2] not in (1, 3)):
        raise FrameError(DropReason.SIZE, f"expected HxW or HxWx3, got shape {arr.shape}")
    if (width is not None and arr.shape[1] != width) or (
        height is not None and arr.shape[0] != height
    ):
        raise FrameError(
            DropReason.SIZE, f"expected {width}x{height}, got {arr.shape[1]}x{arr.shape[0]}"
        )
    return arr


def encode_frame(
    image: np.ndarray,
    encoding: Encoding = "jpeg",
    jpeg_quality: int = 90,
    *,
    full_chroma: bool = True,
) -> bytes:
    """Compress a frame with ``cv2.imencode``; raises :class:`FrameError`.

    JPEG keeps full-resolution colour (4:4:4) unless ``full_chroma`` is false (4:2:0, the
    encoder's default and most cameras' video streams). Colour markers are found from chroma:
    at 4:2:0 each colour sample spans 2x2 pixels, which moved the bearings of the simulator's
    9-pixel balls by 0.045 degree (median) against 0.012 degree at 4:4:4 (docs/vision.md).
    """
    import cv2

    arr = check_frame(image)
    if encoding not in _EXTENSION:
        raise FrameError(DropReason.ENCODING, f"unknown encoding {encoding!r}")
    params: list[int] = []
    if encoding == "jpeg":
        params = [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)]
        if full_chroma:
            params += [cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444]
    ok, buf = cv2.imencode(_EXTENSION[encoding], arr, params)
    if not ok:
        raise FrameError(DropReason.ENCODING, f"cv2.imencode failed for {encoding}")
    return buf.tobytes()


def decode_frame(
    data: bytes | bytearray | memoryview, width: int | None = None, height: int | None = None
) -> np.ndarray:
    """Decompress JPEG/PNG bytes to a BGR (or grey) uint8 array; raises :class:`FrameError`."""
    import cv2

    if len(data) == 0:
        raise FrameError(DropReason.EMPTY, "no image bytes")
    img = cv2.imdecode(np.frombuffer(bytes(data), dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise FrameError(
            DropReason.ENCODING, f"{len(data)} bytes are not a decodable JPEG/PNG image"
        )
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, :3]
    if img.dtype != np.uint8:
        raise FrameError(DropReason.DTYPE, f"decoded image has {img.dtype} pixels, expected uint8")
    return check_frame(img, width, height)


def image_payload(
    image: np.ndarray,
    *,
    sender: int,
    camera_id: int = 0,
    seq: int = 0,
    stamp_s: float = 0.0,
    encoding: Encoding = "jpeg",
    jpeg_quality: int = 90,
) -> Image:
    """Build an :class:`Image` from a frame; raises :class:`FrameError` (``oversize``) if the
    encoded frame would not fit in ``MAX_PAYLOAD_BYTES``."""
    arr = check_frame(image)
    data = encode_frame(arr, encoding, jpeg_quality)
    if len(data) > MAX_PAYLOAD_BYTES - _HEADER_ALLOWANCE:
        raise FrameError(
            DropReason.OVERSIZE, f"{encoding} frame of {len(data)} bytes exceeds the limit"
        )
    return Image(
        sender=sender,
        seq=seq,
        stamp_s=stamp_s,
        camera_id=camera_id,
        width=int(arr.shape[1]),
        height=int(arr.shape[0]),
        encoding=encoding,
        data=data,
    )


def image_from_payload(msg: Image) -> np.ndarray:
    """Decode the frame of an :class:`Image` and check its declared size."""
    return decode_frame(msg.data, msg.width, msg.height)
