"""Per-episode statistics with LeRobot's keys and shapes.

Vectors: per dimension, exact quantiles over the episode's frames.  Images: per
channel in [0, 1] with shape (3, 1, 1), from a 256-bin histogram per channel
(exact for uint8 pixels), accumulated frame by frame so memory stays flat.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["QUANTILES", "STAT_KEYS", "FeatureStats", "ImageStatsAccumulator", "vector_stats"]

QUANTILES: dict[str, float] = {"q01": 0.01, "q10": 0.10, "q50": 0.50, "q90": 0.90, "q99": 0.99}
STAT_KEYS = ("min", "max", "mean", "std", "count", *QUANTILES)

FeatureStats = dict[str, npt.NDArray[Any]]


def vector_stats(values: npt.NDArray[Any]) -> FeatureStats:
    """Stats over axis 0 of a (frames, dims) array."""
    data = np.asarray(values, dtype=np.float64)
    if data.ndim == 1:
        data = data[:, None]
    stats: FeatureStats = {
        "min": data.min(axis=0),
        "max": data.max(axis=0),
        "mean": data.mean(axis=0),
        "std": data.std(axis=0),
        "count": np.array([data.shape[0]], dtype=np.int64),
    }
    for key, q in QUANTILES.items():
        stats[key] = np.quantile(data, q, axis=0)
    return stats


class ImageStatsAccumulator:
    """Streams RGB uint8 frames into per-channel histograms; ``count`` = frames seen."""

    def __init__(self, max_side: int = 150) -> None:
        self._max_side = max_side
        self._hist = np.zeros((3, 256), dtype=np.int64)
        self._frames = 0

    def update(self, rgb: npt.NDArray[np.uint8]) -> None:
        step = max(1, max(rgb.shape[0], rgb.shape[1]) // self._max_side)
        sample = rgb[::step, ::step]
        for channel in range(3):
            self._hist[channel] += np.bincount(sample[:, :, channel].ravel(), minlength=256)
        self._frames += 1

    @property
    def frames(self) -> int:
        return self._frames

    def result(self) -> FeatureStats:
        return histogram_stats(self._hist, self._frames)

    def histogram(self) -> npt.NDArray[np.int64]:
        return self._hist.copy()


def histogram_stats(hist: npt.NDArray[np.int64], frames: int) -> FeatureStats:
    """Stats in [0, 1] from per-channel 256-bin pixel histograms."""
    levels = np.arange(256, dtype=np.float64) / 255.0
    totals = hist.sum(axis=1).astype(np.float64)
    safe = np.maximum(totals, 1.0)
    mean = (hist * levels).sum(axis=1) / safe
    var = (hist * levels**2).sum(axis=1) / safe - mean**2
    nonzero = hist > 0
    minimum = np.array([levels[np.argmax(row)] if row.any() else 0.0 for row in nonzero])
    maximum = np.array([levels[255 - np.argmax(row[::-1])] if row.any() else 0.0 for row in nonzero])
    cumulative = np.cumsum(hist, axis=1)

    def shaped(vec: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        return vec.reshape(3, 1, 1)

    stats: FeatureStats = {
        "min": shaped(minimum),
        "max": shaped(maximum),
        "mean": shaped(mean),
        "std": shaped(np.sqrt(np.maximum(var, 0.0))),
        "count": np.array([frames], dtype=np.int64),
    }
    for key, q in QUANTILES.items():
        idx = np.array([np.searchsorted(cumulative[c], q * totals[c], side="left") for c in range(3)])
        stats[key] = shaped(levels[np.minimum(idx, 255)])
    return stats
