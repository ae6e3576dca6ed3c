"""Synthetic camera frames whose pixels carry their true colour and their sequence number.

Top half: three vertical bars, pure red, green and blue in true RGB order (a BGR/RGB
swap shows as red and blue trading places).  Bottom half: the frame's sequence number
(10 bits, modulo 1024) as 2 rows x 5 large black/white blocks, robust to lossy video.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = [
    "CODE_BITS",
    "bar_means",
    "decode_frame_index",
    "expected_bar_colours",
    "render_frame",
    "textured_frame",
]

CODE_BITS = 10
_COLS = 5
_ROWS = 2
Rgb = npt.NDArray[np.uint8]


def expected_bar_colours() -> npt.NDArray[np.float64]:
    """(3 bars, RGB) of the top half, left to right."""
    return np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255]], dtype=np.float64)


def _bar_slices(height: int, width: int) -> list[tuple[slice, slice]]:
    third = width // 3
    top = height // 2
    inset_y, inset_x = max(1, top // 4), max(1, third // 4)
    return [
        (slice(inset_y, top - inset_y), slice(i * third + inset_x, (i + 1) * third - inset_x))
        for i in range(3)
    ]


def _block_slices(height: int, width: int) -> list[tuple[slice, slice]]:
    top = height // 2
    block_h = (height - top) // _ROWS
    block_w = width // _COLS
    blocks = []
    for bit in range(CODE_BITS):
        row, col = divmod(bit, _COLS)
        y0, x0 = top + row * block_h, col * block_w
        blocks.append((slice(y0, y0 + block_h), slice(x0, x0 + block_w)))
    return blocks


def render_frame(
    height: int, width: int, index: int, rng: np.random.Generator | None = None, noise: float = 0.0
) -> Rgb:
    """RGB uint8 (height, width, 3) for frame ``index``."""
    frame = np.zeros((height, width, 3), dtype=np.uint8)
    third = width // 3
    top = height // 2
    for bar, colour in enumerate(expected_bar_colours().astype(np.uint8)):
        end = (bar + 1) * third if bar < 2 else width
        frame[:top, bar * third : end] = colour
    if noise > 0 and rng is not None:
        noisy = frame[:top].astype(np.float32) + rng.normal(0, noise, frame[:top].shape).astype(np.float32)
        frame[:top] = np.clip(noisy, 0, 255).astype(np.uint8)
    code = index % (1 << CODE_BITS)
    for bit, (ys, xs) in enumerate(_block_slices(height, width)):
        if code >> bit & 1:
            frame[ys, xs] = 255
    return frame


def textured_frame(index: int, height: int, width: int) -> Rgb:
    """A camera-like frame: gradients, texture, a blob moving with ``index`` and sensor noise (seeded
    by ``index``). Lossy codecs lose detail on it the way they do on real images."""
    rng = np.random.default_rng(index)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    base = np.stack(
        [xx / width * 200 + 20, yy / height * 180 + 30, (xx + yy) / (width + height) * 150 + 50], axis=2
    )
    base += (25 * np.sin(xx / 3.0 + index * 0.3) * np.cos(yy / 5.0))[:, :, None]
    cy, cx = height / 2 + height / 3 * np.sin(index / 9), width / 2 + width / 3 * np.cos(index / 7)
    blob = np.exp(-(((yy - cy) / (height / 8)) ** 2 + ((xx - cx) / (width / 8)) ** 2))
    base += 80 * blob[:, :, None] * np.array([1.0, -0.5, 0.3])
    base += rng.normal(0, 6, base.shape)
    return np.clip(base, 0, 255).astype(np.uint8)


def decode_frame_index(rgb: Rgb) -> int:
    """The sequence number (mod 1024) written by :func:`render_frame`."""
    height, width = rgb.shape[:2]
    code = 0
    for bit, (ys, xs) in enumerate(_block_slices(height, width)):
        h, w = ys.stop - ys.start, xs.stop - xs.start
        inner = rgb[ys.start + h // 4 : ys.stop - h // 4, xs.start + w // 4 : xs.stop - w // 4]
        if inner.mean() > 128:
            code |= 1 << bit
    return code


def bar_means(rgb: Rgb) -> npt.NDArray[np.float64]:
    """Measured (3 bars, RGB) means over the bar interiors."""
    height, width = rgb.shape[:2]
    return np.array([rgb[ys, xs].reshape(-1, 3).mean(axis=0) for ys, xs in _bar_slices(height, width)])
