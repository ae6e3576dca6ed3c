"""Depth maps as LeRobot 0.6 depth video: 12-bit log-quantised codes, lossless HEVC ``gray12le``.

LeRobot's ``DepthEncoderConfig`` (``lerobot/configs/video.py``) writes a depth camera as a
one-channel ``gray12le`` HEVC clip (x265 ``lossless=1``) of codes ``0..4095``, and its loader
turns a code back into depth with the parameters recorded in the feature's ``info``
(``video.depth_min``, ``video.depth_max``, ``video.shift``, ``video.use_log``; metres). This module
does the same with the same formulas (``lerobot/datasets/depth_utils.py``), in metres::

    code  = clip(rint(4095 * (log(d + shift) - log(min + shift)) / (log(max + shift) - log(min + shift))), 0, 4095)
    depth = clip(exp(code * step + log(min + shift)) - shift, min, max)

Invalid depth (NaN, +/-inf, zero or negative: "no return" in REP 118) has no code of its own
in LeRobot's format: bagport writes code 0, which LeRobot reads back as ``depth_min``. Depth
beyond ``depth_max`` is written as 4095 (read back as ``depth_max``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from bagport.video.settings import EncoderSettings

__all__ = [
    "DEPTH_ENCODER",
    "DEPTH_QMAX",
    "DepthQuantizer",
    "histogram_levels",
    "is_depth_info",
]

DEPTH_QMAX = 4095
"""Highest 12-bit code (LeRobot's ``DEPTH_QMAX``)."""
DEPTH_PIX_FMT = "gray12le"
DEPTH_UNIT = "m"
"""The unit of the depth bagport feeds the quantiser (LeRobot's ``depth_unit``: it rescales on read)."""

DEPTH_ENCODER = EncoderSettings(
    codec="hevc",
    pix_fmt=DEPTH_PIX_FMT,
    g=2,
    crf=30,
    preset="ultrafast",
    extra_options={"x265-params": "lossless=1"},
)
"""LeRobot 0.6's ``DepthEncoderConfig`` defaults (HEVC/x265 lossless, 12-bit grey, g=2) except the
x265 preset: ``ultrafast`` instead of x265's default ``medium``. Lossless either way (the same
codes decode); on 640x480 depth ``medium`` took 424 ms a frame and ``ultrafast`` 57 ms, for files
7% larger. The preset is recorded in ``info`` (``video.preset``) as LeRobot records it."""


@dataclass(frozen=True, slots=True)
class DepthQuantizer:
    """LeRobot's depth quantiser; defaults are LeRobot's (``DEFAULT_DEPTH_*``)."""

    depth_min_m: float = 0.01
    depth_max_m: float = 10.0
    shift_m: float = 3.5
    use_log: bool = True

    def __post_init__(self) -> None:
        if not 0 <= self.depth_min_m < self.depth_max_m:
            raise ValueError(f"depth range [{self.depth_min_m}, {self.depth_max_m}] m is empty")
        if self.use_log and self.depth_min_m + self.shift_m <= 0:
            raise ValueError("depth_min + shift must be positive for log quantisation")

    def _bounds(self) -> tuple[float, float]:
        if self.use_log:
            return math.log(self.depth_min_m + self.shift_m), math.log(self.depth_max_m + self.shift_m)
        return self.depth_min_m, self.depth_max_m

    def codes(self, depth_m: npt.NDArray[np.float32]) -> npt.NDArray[np.uint16]:
        """12-bit codes of a depth map in metres; invalid depth (not finite, <= 0) is code 0.

        Float32 arithmetic as LeRobot's ``quantize_depth`` does, so the codes are the same.
        """
        depth = np.asarray(depth_m, dtype=np.float32)
        valid = np.isfinite(depth) & (depth > 0)
        safe = np.where(valid, depth, np.float32(self.depth_min_m))
        low, high = self._bounds()
        norm: npt.NDArray[Any]
        if self.use_log:
            norm = (np.log(safe + np.float32(self.shift_m)) - low) / (high - low)
        else:
            norm = (safe - np.float32(low)) / (np.float32(high) - np.float32(low))
        codes = np.rint(norm * DEPTH_QMAX).clip(0, DEPTH_QMAX).astype(np.uint16)
        codes[~valid] = 0
        return codes

    def levels(self) -> npt.NDArray[np.float64]:
        """The depth in metres LeRobot's loader returns for each code ``0..4095`` (float32 maths)."""
        low, high = self._bounds()
        scale, offset = (high - low) / DEPTH_QMAX, low
        buf = np.arange(DEPTH_QMAX + 1, dtype=np.float32) * np.float32(scale) + np.float32(offset)
        if self.use_log:
            buf = np.exp(buf) - np.float32(self.shift_m)
        levels: npt.NDArray[np.float64] = np.clip(buf, self.depth_min_m, self.depth_max_m).astype(np.float64)
        return levels

    def step_m(self, depth_m: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """The size of one code at ``depth_m`` (twice the worst rounding error there)."""
        low, high = self._bounds()
        per_code = (high - low) / DEPTH_QMAX
        depth = np.asarray(depth_m, dtype=np.float64)
        return per_code * (depth + self.shift_m) if self.use_log else np.full_like(depth, per_code)

    def to_info(self) -> dict[str, Any]:
        """The feature ``info`` keys LeRobot reads to dequantise (and to mark the feature as depth)."""
        return {
            "video.depth_min": self.depth_min_m,
            "video.depth_max": self.depth_max_m,
            "video.shift": self.shift_m,
            "video.use_log": self.use_log,
            "is_depth_map": True,
            "depth_unit": DEPTH_UNIT,
        }

    @classmethod
    def from_info(cls, info: Mapping[str, Any]) -> DepthQuantizer:
        defaults = cls()
        return cls(
            depth_min_m=float(info.get("video.depth_min", defaults.depth_min_m)),
            depth_max_m=float(info.get("video.depth_max", defaults.depth_max_m)),
            shift_m=float(info.get("video.shift", defaults.shift_m)),
            use_log=bool(info.get("video.use_log", defaults.use_log)),
        )


def is_depth_info(info: Mapping[str, Any] | None) -> bool:
    """Whether a feature's ``info`` marks a depth map (LeRobot's ``depth_keys`` rule)."""
    return bool(info and (info.get("is_depth_map") or info.get("video.is_depth_map")))


def histogram_levels(info: Mapping[str, Any] | None) -> npt.NDArray[np.float64] | None:
    """What each histogram bin of a video feature stands for: depth in metres for depth maps,
    ``None`` (levels / 255) for colour video."""
    return DepthQuantizer.from_info(info or {}).levels() if is_depth_info(info) else None
