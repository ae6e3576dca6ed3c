"""Statistics: per-episode partials and their merge into dataset stats."""

from __future__ import annotations

from bagport.stats.merge import (
    merge_feature_stats,
    merge_histograms,
    merge_stacked_stats,
    stats_from_json,
    stats_to_json,
)
from bagport.stats.numeric import (
    QUANTILES,
    STAT_KEYS,
    FeatureStats,
    ImageStatsAccumulator,
    column_stats,
    histogram_stats,
    vector_stats,
)
from bagport.stats.sketch import SKETCH_K, VectorSketch, episode_sketch_fields, rank_error

__all__ = [
    "QUANTILES",
    "SKETCH_K",
    "STAT_KEYS",
    "FeatureStats",
    "VectorSketch",
    "ImageStatsAccumulator",
    "column_stats",
    "episode_sketch_fields",
    "histogram_stats",
    "merge_feature_stats",
    "merge_histograms",
    "merge_stacked_stats",
    "rank_error",
    "stats_from_json",
    "stats_to_json",
    "vector_stats",
]
