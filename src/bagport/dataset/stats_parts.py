"""Many episodes' stats held compactly for the dataset merge: per feature and statistic one growing stacked
array (not a dict of small arrays per episode), pixel histograms summed as they come. The merge sees the
same stacked values as :func:`bagport.stats.merge_feature_stats` would, so ``stats.json`` is the same
bytes; memory per episode is its numbers, not Python objects."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from bagport.stats import FeatureStats

__all__ = ["StatsParts"]

_COMPACT_EVERY = 256


class StatsParts:
    def __init__(self) -> None:
        self._pending: dict[str, dict[str, list[npt.NDArray[np.generic]]]] = {}
        self._stacked: dict[str, dict[str, list[npt.NDArray[np.generic]]]] = {}
        self._histograms: dict[str, npt.NDArray[np.int64]] = {}
        self._with_histogram: dict[str, int] = {}
        self.episodes = 0

    def add(self, stats: dict[str, FeatureStats], histograms: dict[str, npt.NDArray[np.int64]]) -> None:
        """One episode's stats and pixel histograms."""
        for key, values in stats.items():
            pending = self._pending.setdefault(key, {})
            for stat, value in values.items():
                pending.setdefault(stat, []).append(np.asarray(value))
        for key, hist in histograms.items():
            total = self._histograms.get(key)
            self._histograms[key] = hist.astype(np.int64) if total is None else total + hist
            self._with_histogram[key] = self._with_histogram.get(key, 0) + 1
        self.episodes += 1
        if self.episodes % _COMPACT_EVERY == 0:
            self._compact()

    def _compact(self) -> None:
        for key, pending in self._pending.items():
            stacked = self._stacked.setdefault(key, {})
            for stat, values in pending.items():
                if values:
                    stacked.setdefault(stat, []).append(np.stack(values))
                    values.clear()

    def stacked(self, key: str) -> dict[str, npt.NDArray[np.generic]]:
        """Every episode's value of each statistic of ``key``, stacked in episode order."""
        self._compact()
        return {stat: np.concatenate(blocks) for stat, blocks in self._stacked[key].items()}

    def histogram(self, key: str) -> npt.NDArray[np.int64] | None:
        """The summed pixel histogram of ``key`` when every episode had one, else ``None``."""
        if self._with_histogram.get(key, 0) != self.episodes:
            return None
        return self._histograms[key]
