"""Per-episode statistics with LeRobot's keys and shapes.

Vectors: per dimension, exact quantiles over the episode's frames.  Images: per
channel in [0, 1] with shape (3, 1, 1), from a 256-bin histogram per channel
(exact for uint8 pixels), accumulated frame by frame so memory stays flat.  Depth maps:
shape (1, 1, 1) in metres (LeRobot does not divide depth by 255), from a histogram of the
4096 depth codes, so the stats are those of the depth LeRobot's loader returns.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, cast

import numpy as np
import numpy.typing as npt
from PIL import Image as PILImage

__all__ = ["QUANTILES", "STAT_KEYS", "FeatureStats", "ImageStatsAccumulator", "column_stats", "vector_stats"]

QUANTILES: dict[str, float] = {"q01": 0.01, "q10": 0.10, "q50": 0.50, "q90": 0.90, "q99": 0.99}
STAT_KEYS = ("min", "max", "mean", "std", "count", *QUANTILES)

FeatureStats = dict[str, npt.NDArray[Any]]

_RGB = 3
_BYTE_VALUES = 256


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
    # one call sorts once for every quantile (the same values as one call per quantile)
    for key, row in zip(QUANTILES, np.quantile(data, list(QUANTILES.values()), axis=0), strict=True):
        stats[key] = row
    return stats


def column_stats(columns: Sequence[npt.NDArray[Any]]) -> list[FeatureStats]:
    """:func:`vector_stats` of each of several columns of one length, in one call: the same values, bit for
    bit (each column is contiguous, so numpy sums it pairwise as it does a column alone), at a fifth of
    the cost for an episode's five index columns (numpy's cost per call is most of it)."""
    data = np.empty((len(columns[0]), len(columns)), dtype=np.float64, order="F")
    for i, column in enumerate(columns):
        data[:, i] = column
    stats = vector_stats(data)
    return [
        {key: row.copy() if key == "count" else row[i : i + 1] for key, row in stats.items()}
        for i in range(len(columns))
    ]


class ImageStatsAccumulator:
    """Streams frames into per-channel histograms; ``count`` = frames seen.

    Colour: RGB uint8 (H, W, 3), 256 bins. Depth: 12-bit codes (H, W) with ``bins=4096`` and
    ``levels`` = the depth each code decodes to (:meth:`bagport.video.depth.DepthQuantizer.levels`).

    Colour frames (each subsampled to at most ``max_side`` pixels a side) are counted
    :data:`RGB_BATCH_FRAMES` at a time: PIL counts a batch's three channels in one pass and its
    counts become one array, where frame by frame the conversion of PIL's 768 counts cost more than
    the counting (W3: 57 against 20 us a 96x128 frame). Memory stays flat: one batch of samples.
    """

    RGB_BATCH_FRAMES = 32
    """Colour samples counted together (a batch of W3's 96x128 frames: 1.2 MB)."""

    def __init__(
        self, max_side: int = 150, *, bins: int = 256, levels: npt.NDArray[np.float64] | None = None
    ) -> None:
        self._max_side = max_side
        self._bins = bins
        self.levels = levels
        self._hist: npt.NDArray[np.int64] | None = None
        self._frames = 0
        self._batch: npt.NDArray[np.uint8] | None = None  # room for a batch of samples (frames, h, w, 3)
        self._batched = 0  # samples in it not counted yet

    def update(self, image: npt.NDArray[np.uint8] | npt.NDArray[np.uint16]) -> None:
        step = max(1, max(image.shape[0], image.shape[1]) // self._max_side)
        sample = image[::step, ::step]
        if sample.ndim == 2:
            sample = sample[:, :, None]
        if self._hist is None:
            self._hist = np.zeros((sample.shape[2], self._bins), dtype=np.int64)
        if sample.dtype == np.uint8 and sample.shape[2] == _RGB and self._bins == _BYTE_VALUES:
            self._add_rgb(cast("npt.NDArray[np.uint8]", sample))  # its dtype was just checked
        else:
            for channel in range(sample.shape[2]):
                self._hist[channel] += np.bincount(sample[:, :, channel].ravel(), minlength=self._bins)
        self._frames += 1

    def _add_rgb(self, sample: npt.NDArray[np.uint8]) -> None:
        if self._batch is None or self._batch.shape[1:] != sample.shape:
            self._count_batch()  # another frame size: what is held is counted first
            self._batch = np.empty((self.RGB_BATCH_FRAMES, *sample.shape), np.uint8)
        self._batch[self._batched] = sample
        self._batched += 1
        if self._batched == self.RGB_BATCH_FRAMES:
            self._count_batch()

    def _count_batch(self) -> None:
        """Count the held RGB samples into the histogram: PIL, the three channels in one pass."""
        if self._batch is None or not self._batched or self._hist is None:
            return
        held = self._batch[: self._batched]
        stacked = held.reshape(-1, *held.shape[2:])  # the samples one under another: one image
        counts = PILImage.fromarray(stacked).histogram()
        self._hist += np.asarray(counts, dtype=np.int64).reshape(_RGB, _BYTE_VALUES)
        self._batched = 0

    @property
    def frames(self) -> int:
        return self._frames

    def result(self) -> FeatureStats:
        return histogram_stats(self.histogram(), self._frames, self.levels)

    def histogram(self) -> npt.NDArray[np.int64]:
        self._count_batch()
        return self._hist.copy() if self._hist is not None else np.zeros((3, self._bins), dtype=np.int64)


def histogram_stats(
    hist: npt.NDArray[np.int64], frames: int, levels: npt.NDArray[np.float64] | None = None
) -> FeatureStats:
    """Per-channel stats, shape (channels, 1, 1), from pixel histograms (channels x bins).

    ``levels[b]`` is the value bin ``b`` stands for; by default ``b / 255`` (colour in [0, 1]).
    """
    if levels is None:
        levels = np.arange(hist.shape[1], dtype=np.float64) / 255.0
    channels, last = hist.shape[0], hist.shape[1] - 1
    totals = hist.sum(axis=1).astype(np.float64)
    safe = np.maximum(totals, 1.0)
    mean = (hist * levels).sum(axis=1) / safe
    var = (hist * levels**2).sum(axis=1) / safe - mean**2
    nonzero = hist > 0
    minimum = np.array([levels[np.argmax(row)] if row.any() else 0.0 for row in nonzero])
    maximum = np.array([levels[last - np.argmax(row[::-1])] if row.any() else 0.0 for row in nonzero])
    cumulative = np.cumsum(hist, axis=1)

    def shaped(vec: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        return vec.reshape(channels, 1, 1)

    stats: FeatureStats = {
        "min": shaped(minimum),
        "max": shaped(maximum),
        "mean": shaped(mean),
        "std": shaped(np.sqrt(np.maximum(var, 0.0))),
        "count": np.array([frames], dtype=np.int64),
    }
    for key, q in QUANTILES.items():
        idx = np.array([np.searchsorted(cumulative[c], q * totals[c], side="left") for c in range(channels)])
        stats[key] = shaped(levels[np.minimum(idx, last)])
    return stats
