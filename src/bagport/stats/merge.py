"""Merge per-episode stats into dataset stats (LeRobot 0.6.1 semantics).

min of mins, max of maxes, count-weighted mean, pooled variance; quantiles are the
count-weighted mean of per-episode quantiles, as LeRobot 0.6.1 does (an
approximation for vectors: the dataset writer replaces them with the merged sketches'
quantiles, :mod:`bagport.stats.sketch`, within its stated rank error).  Image quantiles are exact: they
come from the summed pixel histograms.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from bagport.stats.numeric import QUANTILES, FeatureStats, histogram_stats

__all__ = [
    "merge_feature_stats",
    "merge_histograms",
    "merge_stacked_stats",
    "stats_from_json",
    "stats_to_json",
]


def merge_feature_stats(parts: Sequence[FeatureStats]) -> FeatureStats:
    needed = ("min", "max", "mean", "std", "count", *QUANTILES)
    return merge_stacked_stats({stat: np.stack([p[stat] for p in parts]) for stat in needed})


def merge_stacked_stats(stacked: dict[str, npt.NDArray[Any]]) -> FeatureStats:
    """:func:`merge_feature_stats` of parts given as one stacked array per statistic (parts along axis 0)."""
    counts = stacked["count"][:, 0].astype(np.int64).astype(np.float64)
    total = counts.sum()
    means = stacked["mean"]
    variances = stacked["std"] ** 2
    weights = counts.reshape((-1,) + (1,) * (means.ndim - 1))
    mean = (means * weights).sum(axis=0) / total
    var = ((variances + (means - mean) ** 2) * weights).sum(axis=0) / total
    merged: FeatureStats = {
        "min": np.min(stacked["min"], axis=0),
        "max": np.max(stacked["max"], axis=0),
        "mean": mean,
        "std": np.sqrt(var),
        "count": np.array([int(total)], dtype=np.int64),
    }
    for key in QUANTILES:
        merged[key] = (stacked[key] * weights).sum(axis=0) / total
    return merged


def merge_histograms(
    hists: Sequence[npt.NDArray[np.int64]],
    frames: Sequence[int],
    levels: npt.NDArray[np.float64] | None = None,
) -> FeatureStats:
    """Exact image stats over several episodes from their pixel histograms (``levels``: see
    :func:`~bagport.stats.numeric.histogram_stats`)."""
    return histogram_stats(np.sum(np.stack(hists), axis=0), int(sum(frames)), levels)


def stats_to_json(stats: FeatureStats) -> dict[str, Any]:
    return {key: np.asarray(value).tolist() for key, value in stats.items()}


def stats_from_json(data: dict[str, Any]) -> FeatureStats:
    out: FeatureStats = {}
    for key, value in data.items():
        out[key] = np.asarray(value, dtype=np.int64 if key == "count" else np.float64)
    return out
