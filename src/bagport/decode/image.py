"""Decode sensor_msgs Image / CompressedImage into RGB uint8 (H, W, 3) or depth (H, W) metres.

Colour and grey encodings come out RGB uint8: ``rgb8``, ``bgr8``, ``rgba8``, ``bgra8``, ``8UC3``
(OpenCV's BGR order), ``mono8``, ``8UC1``, ``mono16`` (scaled to 8 bits: ``round(v / 257)``) and
``bayer_rggb8|bggr8|gbrg8|grbg8`` (bilinear demosaic; the ``...16`` variants are scaled to 8 bits
first), and packed 4:2:2 ``yuv422`` (UYVY) and ``yuv422_yuy2`` (YUYV; also ``uyvy``, ``yuyv``: BT.601
limited range, converted by swscale). Depth encodings come out float32 metres with NaN for invalid
(:mod:`bagport.decode.depth`): ``16UC1`` (millimetres), ``32FC1`` (metres), and
``compressedDepth`` CompressedImages. CompressedImage ``jpeg`` and ``png`` come out RGB (a
16-bit PNG whose format names ``16UC1`` is depth in millimetres).
"""

from __future__ import annotations

import io
from enum import Enum
from typing import Any

import av
import numpy as np
import numpy.typing as npt
import simplejpeg
from PIL import Image as PILImage
from PIL import UnidentifiedImageError

from bagport.decode.bayer import BAYER_PATTERNS, demosaic
from bagport.decode.depth import DEPTH_ENCODINGS, decode_compressed_depth, depth_from_pixels
from bagport.errors import DecodeError
from bagport.msgtypes import RosType

__all__ = ["ImageKind", "RawEncoding", "decode_image", "image_channels", "is_depth"]

Rgb = npt.NDArray[np.uint8]


class RawEncoding:
    """Raw encodings bagport reads (sensor_msgs/image_encodings.h names, lower case)."""

    RGB8 = "rgb8"
    BGR8 = "bgr8"
    RGBA8 = "rgba8"
    BGRA8 = "bgra8"
    MONO8 = "mono8"
    MONO16 = "mono16"
    TYPE_8UC1 = "8uc1"
    TYPE_8UC3 = "8uc3"
    TYPE_16UC1 = "16uc1"
    TYPE_32FC1 = "32fc1"


_YUV422_UYVY = {"yuv422": True, "uyvy": True, "yuv422_yuy2": False, "yuyv": False}
"""Packed 4:2:2 encodings, whether their bytes run U Y V Y (image_encodings: ``yuv422`` is UYVY, as USB
cameras send it; ``yuv422_yuy2`` is YUYV; ROS 2 also names them ``uyvy`` and ``yuyv``)."""
_BAYER8 = {f"bayer_{p}8": p for p in BAYER_PATTERNS}
_BAYER16 = {f"bayer_{p}16": p for p in BAYER_PATTERNS}
_LAYOUT: dict[str, tuple[str, int]] = {
    RawEncoding.RGB8: ("u1", 3),
    RawEncoding.BGR8: ("u1", 3),
    RawEncoding.TYPE_8UC3: ("u1", 3),
    RawEncoding.RGBA8: ("u1", 4),
    RawEncoding.BGRA8: ("u1", 4),
    RawEncoding.MONO8: ("u1", 1),
    RawEncoding.TYPE_8UC1: ("u1", 1),
    RawEncoding.MONO16: ("u2", 1),
    RawEncoding.TYPE_16UC1: ("u2", 1),
    RawEncoding.TYPE_32FC1: ("f4", 1),
    **dict.fromkeys(_BAYER8, ("u1", 1)),
    **dict.fromkeys(_BAYER16, ("u2", 1)),
    **dict.fromkeys(_YUV422_UYVY, ("u1", 2)),
}
_JPEG_MAGIC = b"\xff\xd8"
_PNG_MAGIC = b"\x89PNG"


class ImageKind(Enum):
    """What a camera's frames are: RGB uint8 (H, W, 3), or depth float32 metres (H, W).

    Decided once per camera (from its first message, :meth:`of`) and carried from there on.
    """

    COLOUR = "colour"
    DEPTH = "depth"

    @classmethod
    def of(cls, image: npt.NDArray[Any]) -> ImageKind:
        """The kind of a decoded frame (:func:`decode_image`'s output)."""
        return cls.DEPTH if image.ndim == 2 else cls.COLOUR

    @property
    def channels(self) -> int:
        """Channels of the feature a camera of this kind becomes: 1 for depth, 3 for RGB."""
        return 1 if self is ImageKind.DEPTH else 3


def is_depth(image: npt.NDArray[Any]) -> bool:
    """Whether a decoded frame is a depth map (float32 metres, one channel) rather than RGB."""
    return ImageKind.of(image) is ImageKind.DEPTH


def image_channels(image: npt.NDArray[Any]) -> int:
    """Channels of the feature a decoded frame becomes: 1 for depth, 3 for RGB."""
    return ImageKind.of(image).channels


def _to_8bit(grey16: npt.NDArray[np.uint16]) -> npt.NDArray[np.uint8]:
    """Full 16-bit range onto 0..255 (``round(v / 257)``: 65535 -> 255)."""
    return ((grey16.astype(np.uint32) + 128) // 257).astype(np.uint8)


def _pixels(msg: Any, encoding: str) -> npt.NDArray[Any]:
    """(H, W, C) view of the message's pixels in their own type (byte order applied)."""
    kind, channels = _LAYOUT[encoding]
    dtype = np.dtype(kind).newbyteorder(">" if int(getattr(msg, "is_bigendian", 0)) else "<")
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.frombuffer(msg.data, dtype=np.uint8) if not isinstance(msg.data, np.ndarray) else msg.data
    row_bytes = width * channels * dtype.itemsize
    if step < row_bytes or data.size < height * step:
        raise DecodeError(
            f"image data has {data.size} bytes, expected {height}x{step} for {width}x{height} {encoding}",
            fix="the message is truncated or its step/encoding fields are wrong.",
        )
    rows = data[: height * step].reshape(height, step)[:, :row_bytes]
    values = rows.view(dtype) if dtype.itemsize > 1 else rows
    return values.reshape(height, width, channels)


def _yuv422_to_rgb(pixels: npt.NDArray[np.uint8], *, uyvy: bool, encoding: str) -> Rgb:
    """Packed 4:2:2 YUV (two bytes a pixel, a U and V pair per two pixels) to RGB with swscale, as FFmpeg
    converts such camera frames (BT.601, limited range: what USB cameras send)."""
    height, width = pixels.shape[:2]
    if width % 2:
        raise DecodeError(
            f"a {encoding} image has {width} pixels a row, but its U/V samples pair the pixels: the width must be even",
            fix="the message's width or encoding field is wrong; record the camera again, or as rgb8.",
        )
    # (H, W, 2) bytes; U Y V Y -> Y U Y V: each byte pair swapped
    packed: npt.NDArray[np.uint8] = np.ascontiguousarray(pixels[:, :, ::-1] if uyvy else pixels)
    if height % 2:  # PyAV takes yuyv422 frames of even height only: the last row twice, dropped after
        packed = np.concatenate([packed, packed[-1:]])
    frame = av.VideoFrame.from_ndarray(packed, format="yuyv422")
    return np.asarray(frame.to_ndarray(format="rgb24")[:height], dtype=np.uint8)


def _decode_raw(msg: Any) -> npt.NDArray[Any]:
    encoding = str(msg.encoding).lower()
    if encoding not in _LAYOUT:
        raise DecodeError(
            f"raw image encoding {msg.encoding!r} is not supported (supported: {sorted(_LAYOUT)})",
            fix="convert the topic, or map it with a custom decoder.",
        )
    if int(msg.height) == 0 or int(msg.width) == 0:
        raise DecodeError(
            f"the image is empty ({int(msg.width)}x{int(msg.height)} {msg.encoding}): a camera driver publishes such "
            "messages before its first frame or after a glitch",
            fix="convert from after it with a manifest window (start_ns/start_s), or leave the topic out of the "
            "contract; bagport does not make a frame of it (it would be black).",
        )
    pixels = _pixels(msg, encoding)
    if encoding in DEPTH_ENCODINGS:
        return depth_from_pixels(pixels[:, :, 0], encoding)
    if encoding in (RawEncoding.RGB8,):
        return pixels
    if encoding in (RawEncoding.BGR8, RawEncoding.TYPE_8UC3):
        return pixels[:, :, ::-1]
    if encoding == RawEncoding.RGBA8:
        return pixels[:, :, :3]
    if encoding == RawEncoding.BGRA8:
        return pixels[:, :, 2::-1]
    if encoding in _BAYER8:
        return demosaic(np.ascontiguousarray(pixels[:, :, 0]), _BAYER8[encoding])
    if encoding in _BAYER16:
        return demosaic(_to_8bit(pixels[:, :, 0]), _BAYER16[encoding])
    if encoding in _YUV422_UYVY:
        return _yuv422_to_rgb(pixels, uyvy=_YUV422_UYVY[encoding], encoding=encoding)
    grey = _to_8bit(pixels) if pixels.dtype.itemsize == 2 else pixels
    return np.repeat(grey, 3, axis=2)


def _decode_png(payload: bytes, fmt: str) -> npt.NDArray[Any]:
    with PILImage.open(io.BytesIO(payload)) as img:
        if img.mode.startswith("I"):  # 16-bit grey
            grey16 = np.asarray(img).astype(np.uint16)
            if fmt.split(";", 1)[0].strip() == RawEncoding.TYPE_16UC1:
                return depth_from_pixels(grey16, RawEncoding.TYPE_16UC1)
            return np.repeat(_to_8bit(grey16)[:, :, None], 3, axis=2)
        return np.asarray(img.convert("RGB"), dtype=np.uint8)


_VIDEO_CODECS = ("h264", "h265", "hevc", "av1", "vp8", "vp9")
_VIDEO_IN_IMAGE_FIX = (
    "its format names a video codec: a video stream's packets depend on each other, so bagport reads them from "
    "video message types (foxglove_msgs/CompressedVideo, ffmpeg_image_transport_msgs/FFMPEGPacket; see "
    "'Video streams' in docs/contracts.md), not from sensor_msgs/CompressedImage."
)


def _decode_compressed(msg: Any) -> npt.NDArray[Any]:
    payload = msg.data.tobytes() if isinstance(msg.data, np.ndarray) else bytes(msg.data)
    fmt = str(msg.format).lower()
    if "compresseddepth" in fmt:
        return decode_compressed_depth(payload, str(msg.format))
    is_jpeg = payload[:2] == _JPEG_MAGIC or (("jpeg" in fmt or "jpg" in fmt) and payload[:4] != _PNG_MAGIC)
    try:
        if is_jpeg:
            return np.asarray(simplejpeg.decode_jpeg(payload, colorspace="RGB"), dtype=np.uint8)
        return _decode_png(payload, fmt)
    except UnidentifiedImageError:
        raise DecodeError(
            f"compressed image (format {msg.format!r}, {len(payload)} bytes) is neither JPEG nor PNG",
            fix=_VIDEO_IN_IMAGE_FIX
            if any(codec in fmt for codec in _VIDEO_CODECS)
            else "the message payload is "
            "corrupt, or in a format bagport does not read as an image (it reads JPEG and PNG).",
        ) from None
    except (ValueError, OSError) as err:
        raise DecodeError(
            f"compressed image (format {msg.format!r}, {len(payload)} bytes) cannot be decoded: {err}",
            fix="the message payload is corrupt or not JPEG/PNG.",
        ) from err


def decode_image(msg: Any, msgtype: str) -> npt.NDArray[Any]:
    """RGB uint8 (H, W, 3), or float32 (H, W) depth in metres with NaN for invalid pixels.

    BGR encodings come out as RGB; the result may be a view of ``msg``.
    """
    if msgtype == RosType.IMAGE:
        return _decode_raw(msg)
    if msgtype == RosType.COMPRESSED_IMAGE:
        return _decode_compressed(msg)
    raise DecodeError(f"{msgtype} is not an image type")
