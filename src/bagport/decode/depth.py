"""Depth images in metres: raw ``16UC1`` (millimetres) / ``32FC1`` (metres), and
``compressedDepth`` CompressedImages (compressed_depth_image_transport).

Every depth decoder returns float32 (H, W) metres with NaN where the sensor gave no depth:
``0`` in ``16UC1``; NaN, +/-inf, zero or negative in ``32FC1`` (REP 118).

``compressedDepth`` payloads are a 12-byte ``ConfigHeader {int32 format; float32
depthParam[2]}`` then a 16-bit PNG: for ``16UC1`` the PNG holds the millimetres as they are;
for ``32FC1`` it holds quantised inverse depth ``q = A / d + B`` (``A, B = depthParam``), which
decodes as ``d = A / (q - B)``, ``q = 0`` meaning no depth. The ``rvl`` variant (format
``16UC1; compressedDepth rvl``) has, after the same 12-byte header, ``uint32 width, height`` and the
RVL-coded 16-bit values (:mod:`bagport.decode.rvl`) instead of the PNG; they mean the same.
"""

from __future__ import annotations

import io
import struct

import numpy as np
import numpy.typing as npt
from PIL import Image as PILImage

from bagport.decode.rvl import rvl_decode
from bagport.errors import DecodeError

__all__ = ["DEPTH_ENCODINGS", "DepthM", "decode_compressed_depth", "depth_from_pixels"]

DepthM = npt.NDArray[np.float32]
DEPTH_ENCODINGS = ("16uc1", "32fc1")
_MM_PER_M = np.float32(1000.0)
_HEADER_BYTES = 12
_PNG_MAGIC = b"\x89PNG"
_RVL_SIZE = struct.Struct("<II")


def depth_from_pixels(pixels: npt.NDArray[np.uint16] | npt.NDArray[np.float32], encoding: str) -> DepthM:
    """Metres with NaN for invalid, from ``16UC1`` millimetres or ``32FC1`` metres."""
    if encoding == "16uc1":
        depth = pixels.astype(np.float32) / _MM_PER_M
        depth[pixels == 0] = np.nan
        return depth
    depth = np.array(pixels, dtype=np.float32)
    depth[~(np.isfinite(depth) & (depth > 0))] = np.nan
    return depth


def _png_u16(payload: bytes, fmt: str) -> npt.NDArray[np.uint16]:
    try:
        with PILImage.open(io.BytesIO(payload)) as img:
            pixels = np.asarray(img)
    except (ValueError, OSError) as err:
        raise DecodeError(
            f"compressedDepth image (format {fmt!r}) has an unreadable PNG: {err}",
            fix="the message payload is corrupt.",
        ) from err
    if pixels.ndim != 2:
        raise DecodeError(
            f"compressedDepth image (format {fmt!r}) holds a {pixels.shape} PNG, expected one 16-bit channel",
            fix="the topic is not a compressed_depth_image_transport stream; map it as an image instead.",
        )
    return pixels.astype(np.uint16)


def _rvl_u16(payload: bytes, fmt: str) -> npt.NDArray[np.uint16]:
    if len(payload) < _HEADER_BYTES + _RVL_SIZE.size:
        raise DecodeError(
            f"compressedDepth image (format {fmt!r}, {len(payload)} bytes) is too short for its header",
            fix="the message payload is corrupt.",
        )
    width, height = _RVL_SIZE.unpack_from(payload, _HEADER_BYTES)
    data = payload[_HEADER_BYTES + _RVL_SIZE.size :]
    if width * height > 64 * max(len(data), 1):  # RVL never codes a pixel in less than 1/64 byte
        raise DecodeError(
            f"compressedDepth RVL image claims {width}x{height} pixels in {len(data)} bytes",
            fix="the message payload is corrupt.",
        )
    return rvl_decode(data, width * height).reshape(height, width)


def decode_compressed_depth(payload: bytes, fmt: str) -> DepthM:
    """A ``compressedDepth`` payload (``format`` like ``16UC1; compressedDepth png`` or ``... rvl``) as metres."""
    encoding = fmt.split(";", 1)[0].strip().lower()
    if encoding not in DEPTH_ENCODINGS:
        raise DecodeError(
            f"compressedDepth image of encoding {encoding!r} (format {fmt!r}); expected 16UC1 or 32FC1",
            fix="the format string is not compressed_depth_image_transport's; map the topic another way.",
        )
    rvl = "rvl" in fmt.lower()
    if not rvl and (
        len(payload) <= _HEADER_BYTES or payload[_HEADER_BYTES : _HEADER_BYTES + 4] != _PNG_MAGIC
    ):
        raise DecodeError(
            f"compressedDepth image (format {fmt!r}, {len(payload)} bytes) does not start with a 12-byte "
            "header followed by a PNG",
            fix="the message payload is corrupt or from an unknown depth transport.",
        )
    stored = _rvl_u16(payload, fmt) if rvl else _png_u16(payload[_HEADER_BYTES:], fmt)
    quant_a, quant_b = struct.unpack_from("<ff", payload, 4)
    if encoding == "16uc1":
        return depth_from_pixels(stored, encoding)
    invalid = stored == 0
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.float32(quant_a) / (stored.astype(np.float32) - np.float32(quant_b))
    depth[invalid] = np.nan
    return depth_from_pixels(depth, "32fc1")
