"""Statistics: per-episode partials and their merge into dataset stats."""

from __future__ import annotations

from bagport.stats.merge import merge_feature_stats, merge_histograms, stats_from_json, stats_to_json
from bagport.stats.numeric import (
    QUANTILES,
    STAT_KEYS,
    FeatureStats,
    ImageStatsAccumulator,
    histogram_stats,
    vector_stats,
)
from bagport.stats.quantiles import QUANTILE_BINS, QuantileHistogram

__all__ = [
    "QUANTILES",
    "QUANTILE_BINS",
    "QuantileHistogram",
    "STAT_KEYS",
    "FeatureStats",
    "ImageStatsAccumulator",
    "histogram_stats",
    "merge_feature_stats",
    "merge_histograms",
    "stats_from_json",
    "stats_to_json",
    "vector_stats",
]
