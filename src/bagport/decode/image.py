"""Decode sensor_msgs Image / CompressedImage into RGB uint8 arrays (HxWx3)."""

from __future__ import annotations

import io
from typing import Any

import numpy as np
import numpy.typing as npt
import simplejpeg
from PIL import Image as PILImage

from bagport.errors import DecodeError
from bagport.msgtypes import RosType

__all__ = ["RawEncoding", "decode_image", "resize_rgb"]

Rgb = npt.NDArray[np.uint8]


class RawEncoding:
    """Raw encodings bagport reads (sensor_msgs/image_encodings.h names)."""

    RGB8 = "rgb8"
    BGR8 = "bgr8"
    RGBA8 = "rgba8"
    BGRA8 = "bgra8"
    MONO8 = "mono8"


_CHANNELS = {
    RawEncoding.RGB8: 3,
    RawEncoding.BGR8: 3,
    RawEncoding.RGBA8: 4,
    RawEncoding.BGRA8: 4,
    RawEncoding.MONO8: 1,
}
_JPEG_MAGIC = b"\xff\xd8"
_PNG_MAGIC = b"\x89PNG"


def _decode_raw(msg: Any) -> Rgb:
    encoding = str(msg.encoding).lower()
    channels = _CHANNELS.get(encoding)
    if channels is None:
        raise DecodeError(
            f"raw image encoding {msg.encoding!r} is not supported (supported: {sorted(_CHANNELS)})",
            fix="convert the topic, or map it with a custom decoder.",
        )
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.frombuffer(msg.data, dtype=np.uint8) if not isinstance(msg.data, np.ndarray) else msg.data
    if step < width * channels or data.size < height * step:
        raise DecodeError(
            f"image data has {data.size} bytes, expected {height}x{step} for {width}x{height} {encoding}",
            fix="the message is truncated or its step/encoding fields are wrong.",
        )
    rows = data[: height * step].reshape(height, step)[:, : width * channels]
    pixels = rows.reshape(height, width, channels)
    if encoding == RawEncoding.RGB8:
        return pixels
    if encoding == RawEncoding.BGR8:
        return pixels[:, :, ::-1]
    if encoding == RawEncoding.RGBA8:
        return pixels[:, :, :3]
    if encoding == RawEncoding.BGRA8:
        return pixels[:, :, 2::-1]
    return np.repeat(pixels, 3, axis=2)


def _decode_compressed(msg: Any) -> Rgb:
    payload = msg.data.tobytes() if isinstance(msg.data, np.ndarray) else bytes(msg.data)
    fmt = str(msg.format).lower()
    if "compresseddepth" in fmt:
        raise DecodeError(
            f"compressed depth images ({msg.format!r}) are not supported yet",
            fix="remove this topic from the contract for now.",
        )
    is_jpeg = payload[:2] == _JPEG_MAGIC or (("jpeg" in fmt or "jpg" in fmt) and payload[:4] != _PNG_MAGIC)
    try:
        if is_jpeg:
            return np.asarray(simplejpeg.decode_jpeg(payload, colorspace="RGB"), dtype=np.uint8)
        with PILImage.open(io.BytesIO(payload)) as img:
            return np.asarray(img.convert("RGB"), dtype=np.uint8)
    except (ValueError, OSError) as err:
        raise DecodeError(
            f"compressed image (format {msg.format!r}, {len(payload)} bytes) cannot be decoded: {err}",
            fix="the message payload is corrupt or not JPEG/PNG.",
        ) from err


def decode_image(msg: Any, msgtype: str) -> Rgb:
    """RGB uint8 (H, W, 3); BGR encodings come out as RGB.  May be a view of ``msg``."""
    if msgtype == RosType.IMAGE:
        return _decode_raw(msg)
    if msgtype == RosType.COMPRESSED_IMAGE:
        return _decode_compressed(msg)
    raise DecodeError(f"{msgtype} is not an image type")


def resize_rgb(rgb: Rgb, height: int, width: int) -> Rgb:
    """Bilinear resize (area-averaging when shrinking, via PIL's reducing filter)."""
    if rgb.shape[0] == height and rgb.shape[1] == width:
        return rgb
    img = PILImage.fromarray(np.ascontiguousarray(rgb))
    return np.asarray(img.resize((width, height), PILImage.Resampling.BILINEAR, reducing_gap=2.0))
