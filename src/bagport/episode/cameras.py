"""One camera of an episode while it converts: its encoder, pixel stats, fidelity and QA feed.

A camera whose first frame decodes as RGB becomes a colour video (the run's codec). One whose
frames decode as depth (``16UC1``, ``32FC1``, ``compressedDepth``) becomes a LeRobot depth video:
12-bit codes (:class:`~bagport.video.depth.DepthQuantizer`, over ``image.depth_range_m``) in a
lossless HEVC ``gray12le`` clip, marked ``is_depth_map`` with the quantiser's parameters, so
LeRobot's loader returns depth again. Its stats are of that returned depth, in metres.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from bagport.contract.plan import SourceSpec
from bagport.decode import is_depth
from bagport.episode.fidelity import EpisodeFidelity
from bagport.errors import DecodeError
from bagport.qa import ValueMonitor
from bagport.stats import ImageStatsAccumulator
from bagport.video import ClipInfo, EncoderSettings, StreamingEncoder
from bagport.video.depth import DEPTH_ENCODER, DEPTH_QMAX, DepthQuantizer

__all__ = ["CameraSink"]

_PREVIEW_SHIFT = 4
"""Depth codes >> 4 give the 8-bit picture the QA image checks look at (0 = invalid or nearest)."""


class CameraSink:
    """Feeds one camera's frames, in order, to its encoder, stats, fidelity recorder and QA."""

    def __init__(
        self,
        path: Path,
        source: SourceSpec,
        first: npt.NDArray[Any],
        fps: int,
        settings: EncoderSettings,
        fidelity: EpisodeFidelity,
        monitor: ValueMonitor,
    ) -> None:
        self.key = source.key
        self.depth = is_depth(first)
        self.quantizer: DepthQuantizer | None = None
        if self.depth:
            self.quantizer = DepthQuantizer()
            if source.depth_range_m is not None:
                low, high = source.depth_range_m
                self.quantizer = DepthQuantizer(depth_min_m=low, depth_max_m=high)
            settings = DEPTH_ENCODER
        elif source.depth_range_m is not None:
            raise DecodeError(
                f"{self.key}: image.depth_range_m is set but {source.topic} carries colour images",
                fix="remove depth_range_m from this entry (it applies to 16UC1/32FC1/compressedDepth topics).",
            )
        self.encoder = StreamingEncoder(
            path, fps=fps, width=first.shape[1], height=first.shape[0], settings=settings
        )
        self.settings = settings
        self.stats = (
            ImageStatsAccumulator(bins=DEPTH_QMAX + 1, levels=self.quantizer.levels())
            if self.quantizer is not None
            else ImageStatsAccumulator()
        )
        self._fidelity = fidelity
        self._monitor = monitor

    def write(self, frame_index: int, image: npt.NDArray[Any]) -> None:
        if is_depth(image) != self.depth:
            was, now = ("depth", "colour") if self.depth else ("colour", "depth")
            raise DecodeError(
                f"{self.key}: frame {frame_index} is a {now} image, the frames before were {was}",
                fix="map depth and colour topics to different keys; a zeros fill before a depth camera's "
                "first message comes out as colour, use fill 'hold' or 'drop_frame' there.",
            )
        if self.quantizer is None:
            pixels, preview = image, image
        else:
            pixels = self.quantizer.codes(image)
            preview = (pixels >> _PREVIEW_SHIFT).astype(np.uint8)
        self.encoder.write(pixels)
        self._fidelity.record(self.key, pixels)
        self.stats.update(pixels)
        self._monitor.add_image(frame_index, self.key, preview)

    def close(self) -> ClipInfo:
        return self.encoder.close()

    def video_info(self, clip: ClipInfo, fps: int) -> dict[str, Any]:
        """The feature's ``info`` in ``info.json``, as LeRobot 0.6 writes it."""
        info: dict[str, Any] = {
            "video.height": clip.height,
            "video.width": clip.width,
            "video.codec": clip.codec,
            "video.pix_fmt": clip.pix_fmt,
            "video.fps": fps,
            "video.channels": self.channels,
            "has_audio": False,
            **self.settings.to_info(),
            "is_depth_map": False,
        }
        if self.quantizer is not None:
            info.update(self.quantizer.to_info())
        return info

    @property
    def channels(self) -> int:
        return 1 if self.depth else 3
