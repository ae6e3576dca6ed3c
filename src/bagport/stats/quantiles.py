"""Dataset-wide quantiles of vector features, within one histogram bin of the exact value.

Per-episode quantiles cannot be merged exactly (LeRobot averages them, weighted by frame count,
which can be far off when episodes differ). Once the dataset's min and max of each dimension are
known (merged exactly from the episode stats), one streaming pass over the frames fills a
histogram of :data:`QUANTILE_BINS` equal bins per dimension between them. The exact quantile
(inverted CDF: the smallest value with at least ``q * count`` values at or below it) lies in the
bin where the cumulative count reaches ``q * count``; the value reported is interpolated inside
that bin (as LeRobot's ``RunningQuantileStats`` does), so it is off by at most one bin width,
``(max - min) / QUANTILE_BINS``. Memory: ``dims x QUANTILE_BINS`` counters, whatever the length.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from bagport.stats.numeric import QUANTILES

__all__ = ["QUANTILE_BINS", "QuantileHistogram"]

QUANTILE_BINS = 5000
"""Bins per dimension (LeRobot's ``RunningQuantileStats`` uses as many)."""


class QuantileHistogram:
    """Counts the values of one (frames, dims) feature in fixed bins between known bounds."""

    def __init__(self, minimum: npt.ArrayLike, maximum: npt.ArrayLike, bins: int = QUANTILE_BINS) -> None:
        self._min = np.asarray(minimum, dtype=np.float64).reshape(-1)
        self._max = np.asarray(maximum, dtype=np.float64).reshape(-1)
        self._bins = bins
        self._counts = np.zeros((self._min.size, bins), dtype=np.int64)

    def bin_width(self) -> npt.NDArray[np.float64]:
        """The most a reported quantile can be off, per dimension."""
        return (self._max - self._min) / self._bins

    def update(self, values: npt.NDArray[Any]) -> None:
        data = np.asarray(values, dtype=np.float64).reshape(len(values), -1)
        for dim in range(self._min.size):
            lo, hi = self._min[dim], self._max[dim]
            if hi > lo:
                self._counts[dim] += np.histogram(data[:, dim], bins=self._bins, range=(lo, hi))[0]
            else:  # a constant: every value in the first bin
                self._counts[dim, 0] += data.shape[0]

    def quantiles(self) -> dict[str, npt.NDArray[np.float64]]:
        """``q01``... per dimension, each within one bin width of the exact (inverted-CDF) quantile."""
        cumulative = np.cumsum(self._counts, axis=1)
        total = cumulative[:, -1].astype(np.float64)
        width = self.bin_width()
        out: dict[str, npt.NDArray[np.float64]] = {}
        for key, q in QUANTILES.items():
            values = np.empty(self._min.size, dtype=np.float64)
            for dim in range(self._min.size):
                target = q * total[dim]
                idx = int(np.searchsorted(cumulative[dim], target, side="left"))
                idx = min(idx, self._bins - 1)
                before = float(cumulative[dim, idx - 1]) if idx > 0 else 0.0
                inside = float(self._counts[dim, idx])
                fraction = (target - before) / inside if inside > 0 else 0.0
                value = self._min[dim] + (idx + fraction) * width[dim]
                values[dim] = min(max(value, self._min[dim]), self._max[dim])
            out[key] = values
        return out
