"""RVL, the lossless 16-bit depth codec of compressed_depth_image_transport (``compressedDepth rvl``).

RVL (A. D. Wilson, "Fast Lossless Depth Image Compression", 2017) codes the pixels in row-major
order as alternating runs: a count of zeros, a count of non-zeros, then each non-zero pixel as the
zig-zag coded difference from the previous non-zero pixel. Every number is variable-length coded in
3-bit nibbles (low bits first; bit 3 set: more follow), and the nibbles are packed eight to a 32-bit
little-endian word, the first nibble in the word's top bits.

The encoder lives with the synthetic depth cameras (:func:`bagport.synth.images.rvl_encode`).
Decoding is vectorised (nibbles, numbers and the running sum with numpy); only the run structure is
walked in Python, once per run.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from bagport.errors import DecodeError

__all__ = ["rvl_decode"]

U16 = npt.NDArray[np.uint16]
_NIBBLE_SHIFTS = np.arange(28, -1, -4, dtype=np.uint32)


def _numbers(data: bytes) -> npt.NDArray[np.int64]:
    """Every variable-length coded number in ``data``, in order."""
    usable = len(data) - len(data) % 4
    words = np.frombuffer(data[:usable], dtype="<u4")
    nibbles: npt.NDArray[np.int64] = (
        ((words[:, None] >> _NIBBLE_SHIFTS[None, :]) & 0xF).reshape(-1).astype(np.int64)
    )
    last = np.flatnonzero((nibbles & 0x8) == 0)  # the last nibble of each number
    if last.size == 0:
        return np.zeros(0, dtype=np.int64)
    nibbles = nibbles[: last[-1] + 1]
    starts = np.concatenate(([0], last[:-1] + 1))
    number = np.repeat(np.arange(last.size), last - starts + 1)
    position = np.arange(nibbles.size) - starts[number]
    values = np.zeros(last.size, dtype=np.int64)
    np.add.at(values, number, (nibbles & 0x7) << (3 * position))
    return values


def rvl_decode(data: bytes, pixels: int) -> U16:
    """The ``pixels`` 16-bit values RVL-coded in ``data`` (row-major)."""
    numbers = _numbers(data)
    out = np.zeros(pixels, dtype=np.uint16)
    deltas: list[npt.NDArray[np.int64]] = []
    places: list[npt.NDArray[np.int64]] = []
    at = done = 0
    while done < pixels:
        if at + 2 > numbers.size:
            raise DecodeError(
                f"RVL data ends after {done} of {pixels} pixels",
                fix="the compressedDepth payload is truncated or its width/height are wrong.",
            )
        zeros, nonzeros = int(numbers[at]), int(numbers[at + 1])
        done += zeros
        if done + nonzeros > pixels or at + 2 + nonzeros > numbers.size:
            raise DecodeError(
                f"RVL data codes more pixels than the {pixels} of the image, or ends inside a run",
                fix="the compressedDepth payload is corrupt or its width/height are wrong.",
            )
        deltas.append(numbers[at + 2 : at + 2 + nonzeros])
        places.append(np.arange(done, done + nonzeros, dtype=np.int64))
        done += nonzeros
        at += 2 + nonzeros
    if deltas:
        coded = np.concatenate(deltas)
        signed = (coded >> 1) ^ -(coded & 1)  # zig-zag
        out[np.concatenate(places)] = (np.cumsum(signed) & 0xFFFF).astype(np.uint16)
    return out
