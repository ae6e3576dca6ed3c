"""Synthetic camera payloads in every encoding bagport reads, with their ground truth.

Colour cameras start from :func:`~bagport.synth.pixels.render_frame` and are packed as the
encoding says (BGR byte order, grey, 16-bit grey, Bayer mosaics). Depth cameras start from
:func:`depth_frame`, an analytic depth map in metres with a hole of invalid pixels, and are
packed as ``16UC1`` millimetres, ``32FC1`` metres, or ``compressedDepth`` (12-byte header + PNG or
RVL, as compressed_depth_image_transport writes it). :func:`recorded_depth` is what a ROS subscriber
decodes from each of those (millimetre rounding, inverse-depth quantisation).
"""

from __future__ import annotations

import io
import struct

import numpy as np
import numpy.typing as npt
from PIL import Image as PILImage

__all__ = [
    "COMPRESSED_DEPTH_MAX_M",
    "compressed_depth_payload",
    "depth_frame",
    "mosaic",
    "raw_depth_bytes",
    "raw_image_bytes",
    "recorded_depth",
    "rvl_encode",
]

Rgb = npt.NDArray[np.uint8]
DepthM = npt.NDArray[np.float32]

COMPRESSED_DEPTH_MAX_M = 10.0
"""compressed_depth_image_transport's defaults: ``depth_max`` 10 m, ``depth_quantization`` 100."""
_DEPTH_QUANTIZATION = 100.0


def mosaic(rgb: Rgb, pattern: str) -> Rgb:
    """The Bayer mosaic (H, W) a sensor with 2x2 ``pattern`` (e.g. ``rggb``) records of ``rgb``."""
    out = np.zeros(rgb.shape[:2], dtype=np.uint8)
    for index, colour in enumerate(pattern):
        dy, dx = divmod(index, 2)
        out[dy::2, dx::2] = rgb[dy::2, dx::2, "rgb".index(colour)]
    return out


def _grey(rgb: Rgb) -> Rgb:
    grey: Rgb = rgb.mean(axis=2, keepdims=True).astype(np.uint8)
    return grey


def raw_image_bytes(rgb: Rgb, encoding: str) -> tuple[npt.NDArray[np.uint8], int]:
    """``sensor_msgs/Image`` ``data`` (little-endian) and ``step`` for ``rgb`` in a colour encoding."""
    name = encoding.lower()
    out: npt.NDArray[np.uint8] | npt.NDArray[np.uint16]
    if name == "rgb8":
        out = rgb
    elif name in ("bgr8", "8uc3"):
        out = rgb[:, :, ::-1]
    elif name in ("rgba8", "bgra8"):
        colour = rgb if name == "rgba8" else rgb[:, :, ::-1]
        out = np.concatenate([colour, np.full((*rgb.shape[:2], 1), 255, np.uint8)], axis=2)
    elif name in ("mono8", "8uc1"):
        out = _grey(rgb)
    elif name == "mono16":
        out = _grey(rgb).astype("<u2") * np.uint16(257)
    elif name.startswith("bayer_") and name.endswith("8"):
        out = mosaic(rgb, name[6:10])[:, :, None]
    else:
        raise ValueError(f"synthetic raw encoding {encoding!r} is not supported")
    packed = np.ascontiguousarray(out)
    return packed.view(np.uint8).ravel(), packed.shape[1] * packed.shape[2] * packed.itemsize


def depth_frame(height: int, width: int, index: int) -> DepthM:
    """Depth in metres for frame ``index``: a left-to-right ramp from 0.3 m to 6 m plus a step
    that moves with the frame (10 mm per frame, modulo 50), and a hole of invalid pixels (NaN)
    in the top-left corner."""
    ramp = np.linspace(0.3, 6.0, width, dtype=np.float32)
    depth = np.repeat(ramp[None, :], height, axis=0) + np.float32(0.01 * (index % 50))
    depth[: height // 4, : width // 4] = np.nan
    return depth.astype(np.float32)


def _mm(depth: DepthM) -> npt.NDArray[np.uint16]:
    return np.where(np.isfinite(depth), np.rint(depth * 1000), 0).astype(np.uint16)


def _inverse_depth(depth: DepthM) -> tuple[npt.NDArray[np.uint16], float, float]:
    """The transport's 32FC1 coding: ``q = A / d + B`` truncated, 0 for invalid or too far."""
    quant_a = np.float32(_DEPTH_QUANTIZATION * (_DEPTH_QUANTIZATION + 1.0))
    quant_b = np.float32(1.0 - quant_a / np.float32(COMPRESSED_DEPTH_MAX_M))
    valid = np.isfinite(depth) & (depth > 0) & (depth < COMPRESSED_DEPTH_MAX_M)
    safe = np.where(valid, depth, np.float32(1.0))
    stored = np.where(valid, quant_a / safe + quant_b, 0).astype(np.uint16)
    return stored, float(quant_a), float(quant_b)


def raw_depth_bytes(depth: DepthM, encoding: str) -> tuple[npt.NDArray[np.uint8], int]:
    """``data`` and ``step`` of a raw ``16UC1`` (millimetres, 0 = invalid) or ``32FC1`` (metres) image."""
    if encoding.lower() == "16uc1":
        pixels: npt.NDArray[np.uint16] | npt.NDArray[np.float32] = _mm(depth).astype("<u2")
    elif encoding.lower() == "32fc1":
        pixels = depth.astype("<f4")
    else:
        raise ValueError(f"synthetic depth encoding {encoding!r} is not supported")
    packed = np.ascontiguousarray(pixels)
    return packed.view(np.uint8).ravel(), packed.shape[1] * packed.itemsize


def compressed_depth_payload(depth: DepthM, encoding: str, codec: str = "png") -> tuple[bytes, str]:
    """``CompressedImage`` ``data`` and ``format`` as compressed_depth_image_transport writes them
    (``codec`` ``png``, or ``rvl``: ``uint32 width, height`` then the RVL-coded values)."""
    if encoding.lower() == "16uc1":
        stored, quant_a, quant_b = _mm(depth), 0.0, 0.0
    else:
        stored, quant_a, quant_b = _inverse_depth(depth)
    header = struct.pack("<iff", 0, quant_a, quant_b)
    if codec == "rvl":
        size = struct.pack("<II", stored.shape[1], stored.shape[0])
        return header + size + rvl_encode(stored), f"{encoding}; compressedDepth rvl"
    buf = io.BytesIO()
    PILImage.fromarray(stored).save(buf, format="PNG")
    return header + buf.getvalue(), f"{encoding}; compressedDepth png"


_NIBBLE_SHIFTS = np.arange(28, -1, -4, dtype=np.uint32)


def _vle(value: int, nibbles: list[int]) -> None:
    while True:
        nibble = value & 0x7
        value >>= 3
        nibbles.append(nibble | (0x8 if value else 0))
        if not value:
            return


def rvl_encode(values: npt.NDArray[np.uint16]) -> bytes:
    """RVL coding of 16-bit ``values`` (row-major), as compressed_depth_image_transport's rvl_codec.cpp
    writes it (see :mod:`bagport.decode.rvl` for the format)."""
    flat = np.asarray(values, dtype=np.uint16).ravel().astype(np.int64)
    nibbles: list[int] = []
    previous, index, size = 0, 0, flat.size
    while index < size:
        start = index
        while index < size and flat[index] == 0:
            index += 1
        _vle(index - start, nibbles)
        start = index
        while index < size and flat[index] != 0:
            index += 1
        _vle(index - start, nibbles)
        for current in flat[start:index].tolist():
            delta = current - previous  # int arithmetic on unsigned shorts, as rvl_codec.cpp does
            _vle((delta << 1) ^ (delta >> 31), nibbles)
            previous = current
    nibbles += [0] * (-len(nibbles) % 8)
    packed = np.asarray(nibbles, dtype=np.uint32).reshape(-1, 8) << _NIBBLE_SHIFTS[None, :]
    words: npt.NDArray[np.uint32] = np.bitwise_or.reduce(packed, axis=1).astype("<u4")
    return words.tobytes()


def recorded_depth(depth: DepthM, encoding: str, compressed: bool) -> DepthM:
    """The depth (metres, NaN = invalid) a ROS subscriber gets back from what the bag holds."""
    if encoding.lower() == "16uc1":
        mm = _mm(depth)
        return np.where(mm > 0, mm.astype(np.float32) / np.float32(1000), np.nan).astype(np.float32)
    if not compressed:
        return depth.copy()
    stored, quant_a, quant_b = _inverse_depth(depth)
    with np.errstate(divide="ignore"):
        out = np.float32(quant_a) / (stored.astype(np.float32) - np.float32(quant_b))
    return np.where(stored > 0, out, np.nan).astype(np.float32)
