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

__all__ = ["merge_feature_stats", "merge_histograms", "stats_from_json", "stats_to_json"]


def merge_feature_stats(parts: Sequence[FeatureStats]) -> FeatureStats:
    counts = np.array([int(p["count"][0]) for p in parts], dtype=np.float64)
    total = counts.sum()
    means = np.stack([p["mean"] for p in parts])
    variances = np.stack([p["std"] for p in parts]) ** 2
    weights = counts.reshape((-1,) + (1,) * (means.ndim - 1))
    mean = (means * weights).sum(axis=0) / total
    var = ((variances + (means - mean) ** 2) * weights).sum(axis=0) / total
    merged: FeatureStats = {
        "min": np.min(np.stack([p["min"] for p in parts]), axis=0),
        "max": np.max(np.stack([p["max"] for p in parts]), axis=0),
        "mean": mean,
        "std": np.sqrt(var),
        "count": np.array([int(total)], dtype=np.int64),
    }
    for key in QUANTILES:
        merged[key] = (np.stack([p[key] for p in parts]) * weights).sum(axis=0) / total
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
