"""Image payloads: encoding round trip, size limit, and FrameError for bad frames."""

from __future__ import annotations

import numpy as np
import pytest

from messages.codec import MAX_PAYLOAD_BYTES, MessageError, decode, encode
from messages.image import (
    FrameError,
    Image,
    check_frame,
    decode_frame,
    encode_frame,
    image_from_payload,
    image_key,
    image_payload,
)


def _frame(seed: int = 0, h: int = 480, w: int = 640) -> np.ndarray:
    """Seeded 32x32-pixel colour blocks (piecewise flat, as JPEG likes)."""
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 255, (h // 32, w // 32, 3), dtype=np.uint8)
    return np.kron(small, np.ones((32, 32, 1), dtype=np.uint8))


@pytest.mark.parametrize("encoding", ["png", "jpeg"])
def test_round_trip_through_codec(encoding: str) -> None:
    img = _frame()
    msg = image_payload(img, sender=3, camera_id=1, seq=7, stamp_s=1.5, encoding=encoding)
    data = encode(msg)
    assert len(data) < MAX_PAYLOAD_BYTES
    back = decode(data, Image)
    assert (back.width, back.height, back.camera_id, back.seq) == (640, 480, 1, 7)
    out = image_from_payload(back)
    if encoding == "png":
        np.testing.assert_array_equal(out, img)
    else:
        assert np.abs(out.astype(int) - img).mean() < 6.0
    assert image_key("alpha", 3) == "bf/alpha/3/camera/image"


def test_noise_frame_too_large_for_png_is_refused() -> None:
    noise = np.random.default_rng(1).integers(0, 255, (720, 1280, 3), dtype=np.uint8)
    with pytest.raises(FrameError) as exc:
        image_payload(noise, sender=1, encoding="png")
    assert exc.value.reason == "oversize"


def test_bad_frames() -> None:
    cases = [
        (lambda: decode_frame(b""), "empty"),
        (lambda: decode_frame(b"\x89PNG not really"), "encoding"),
        (lambda: check_frame(np.zeros((4, 4), np.int16)), "dtype"),
        (lambda: check_frame(np.zeros((4, 4, 2), np.uint8)), "size"),
    ]
    for fun, reason in cases:
        with pytest.raises(FrameError) as exc:
            fun()
        assert exc.value.reason == reason and isinstance(exc.value, MessageError)
    msg = image_payload(_frame(), sender=1, encoding="png")
    wrong = Image(sender=1, width=320, height=240, encoding="png", data=msg.data)
    with pytest.raises(FrameError) as exc:
        image_from_payload(wrong)
    assert exc.value.reason == "size"


def _jpeg_sampling(data: bytes) -> list[int]:
    """``H << 4 | V`` of each component in the JPEG's baseline frame header (SOF0)."""
    k = data.index(b"\xff\xc0")
    n = data[k + 9]
    return [data[k + 11 + 3 * c] for c in range(n)]


def test_jpeg_keeps_full_resolution_colour_unless_asked() -> None:
    """Colour markers are found from chroma: the simulator's frames are 4:4:4, not the
    encoder's default 4:2:0 (which halves chroma resolution both ways)."""
    img = _frame(seed=2)
    assert _jpeg_sampling(encode_frame(img)) == [0x11, 0x11, 0x11]
    assert _jpeg_sampling(encode_frame(img, full_chroma=False)) == [0x22, 0x11, 0x11]
    # a one-pixel red/green checkerboard survives only with full chroma
    board = np.zeros((64, 64, 3), dtype=np.uint8)
    board[::2, ::2] = board[1::2, 1::2] = (0, 0, 230)
    board[1::2, ::2] = board[::2, 1::2] = (0, 230, 0)
    err = {
        full: np.abs(decode_frame(encode_frame(board, full_chroma=full)).astype(int) - board).mean()
        for full in (True, False)
    }
    assert err[True] < 0.25 * err[False], err
