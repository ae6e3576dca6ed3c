"""Resizing camera frames: area averaging when shrinking, bilinear when enlarging.

Colour frames go through PIL (``BOX`` is exact area averaging for any scale factor). Depth
maps are resized from their valid pixels only: each output pixel is the mean of the valid
depth under it (weighted by area), and is invalid (NaN) when less than half of its area was
valid, so a hole never bleeds zeros into the depth around it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
from PIL import Image as PILImage

__all__ = ["resize_depth", "resize_image", "resize_rgb"]

_MIN_VALID_SHARE = 0.5


def _filter(shape: tuple[int, ...], height: int, width: int) -> PILImage.Resampling:
    shrinking = height <= shape[0] and width <= shape[1]
    return PILImage.Resampling.BOX if shrinking else PILImage.Resampling.BILINEAR


def resize_rgb(rgb: npt.NDArray[np.uint8], height: int, width: int) -> npt.NDArray[np.uint8]:
    """RGB uint8 to ``height x width``: area average when shrinking, bilinear otherwise."""
    if rgb.shape[0] == height and rgb.shape[1] == width:
        return rgb
    img = PILImage.fromarray(np.ascontiguousarray(rgb))
    return np.asarray(img.resize((width, height), _filter(rgb.shape, height, width)))


def _resize_float(plane: npt.NDArray[np.float32], height: int, width: int) -> npt.NDArray[np.float32]:
    img = PILImage.fromarray(np.ascontiguousarray(plane, dtype=np.float32))
    return np.asarray(img.resize((width, height), _filter(plane.shape, height, width)), dtype=np.float32)


def resize_depth(depth_m: npt.NDArray[np.float32], height: int, width: int) -> npt.NDArray[np.float32]:
    """Depth (metres, NaN = invalid) to ``height x width``, averaging valid depth only."""
    if depth_m.shape[0] == height and depth_m.shape[1] == width:
        return depth_m
    valid = np.isfinite(depth_m)
    total = _resize_float(np.where(valid, depth_m, np.float32(0)), height, width)
    share = _resize_float(valid.astype(np.float32), height, width)
    out = np.full((height, width), np.nan, dtype=np.float32)
    keep = share >= _MIN_VALID_SHARE
    out[keep] = total[keep] / share[keep]
    return out


def resize_image(image: npt.NDArray[Any], height: int, width: int) -> npt.NDArray[Any]:
    """A decoded frame (RGB uint8, or depth float32 metres) to ``height x width``."""
    if image.ndim == 2:
        return resize_depth(image, height, width)
    return resize_rgb(image, height, width)
