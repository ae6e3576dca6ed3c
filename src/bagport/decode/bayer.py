"""Bilinear demosaicing of Bayer mosaics (``bayer_rggb8`` and friends) into RGB.

Each colour is interpolated from its own samples with the classic bilinear kernels (what
OpenCV's ``COLOR_Bayer*2RGB`` does), written as a normalised convolution: the convolution of
the sparse samples divided by the convolution of their mask. Inside the image that
divisor is 4 everywhere; on the border it counts only the samples that exist, so edges
need no padding rule.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import numpy.typing as npt

__all__ = ["BAYER_PATTERNS", "demosaic"]

BAYER_PATTERNS = ("rggb", "bggr", "gbrg", "grbg")
"""The 2x2 tile read left to right, top to bottom (``bayer_rggb8``: R G / G B)."""

_RB_KERNEL = np.array([[1, 2, 1], [2, 4, 2], [1, 2, 1]], dtype=np.float32)
_G_KERNEL = np.array([[0, 1, 0], [1, 4, 1], [0, 1, 0]], dtype=np.float32)


def _masks(pattern: str, height: int, width: int) -> list[npt.NDArray[np.float32]]:
    """Per RGB channel, 1 where the mosaic samples that colour."""
    masks: list[npt.NDArray[np.float32]] = [np.zeros((height, width), dtype=np.float32) for _ in range(3)]
    for index, colour in enumerate(pattern):
        dy, dx = divmod(index, 2)
        masks["rgb".index(colour)][dy::2, dx::2] = 1.0
    return masks


def _convolve(image: npt.NDArray[np.float32], kernel: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
    """3x3 'same' convolution with zeros outside (the kernels are symmetric)."""
    height, width = image.shape
    padded = np.pad(image, 1)
    out = np.zeros_like(image)
    for dy in range(3):
        for dx in range(3):
            weight = kernel[dy, dx]
            if weight:
                out += weight * padded[dy : dy + height, dx : dx + width]
    return out


@lru_cache(maxsize=8)
def _weights(pattern: str, height: int, width: int) -> tuple[npt.NDArray[np.float32], ...]:
    """Per channel: its mask and the convolution of the mask (the normalisation)."""
    out = []
    for channel, mask in enumerate(_masks(pattern, height, width)):
        kernel = _G_KERNEL if channel == 1 else _RB_KERNEL
        out += [mask, _convolve(mask, kernel)]
    return tuple(out)


def demosaic(mosaic: npt.NDArray[np.uint8], pattern: str) -> npt.NDArray[np.uint8]:
    """RGB uint8 (H, W, 3) from an 8-bit Bayer mosaic (H, W) with the given 2x2 ``pattern``."""
    height, width = mosaic.shape
    weights = _weights(pattern, height, width)
    samples = mosaic.astype(np.float32)
    rgb = np.empty((height, width, 3), dtype=np.uint8)
    for channel in range(3):
        mask, norm = weights[2 * channel], weights[2 * channel + 1]
        kernel = _G_KERNEL if channel == 1 else _RB_KERNEL
        value = _convolve(samples * mask, kernel) / norm
        rgb[:, :, channel] = np.clip(np.rint(value), 0, 255).astype(np.uint8)
    return rgb
