"""Stats partials and their merge agree with stats computed over all data at once."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from bagport.stats import (
    QUANTILE_BINS,
    QUANTILES,
    ImageStatsAccumulator,
    QuantileHistogram,
    merge_feature_stats,
    merge_histograms,
    vector_stats,
)


@settings(max_examples=40, deadline=None)
@given(sizes=st.lists(st.integers(1, 50), min_size=1, max_size=6), seed=st.integers(0, 1000))
def test_merged_moments_equal_pooled_moments(sizes: list[int], seed: int) -> None:
    rng = np.random.default_rng(seed)
    parts = [rng.normal(size=(n, 3)) * (i + 1) for i, n in enumerate(sizes)]
    merged = merge_feature_stats([vector_stats(p) for p in parts])
    pooled = np.concatenate(parts)
    np.testing.assert_allclose(merged["mean"], pooled.mean(axis=0), atol=1e-9)
    np.testing.assert_allclose(merged["std"], pooled.std(axis=0), atol=1e-9)
    np.testing.assert_array_equal(merged["min"], pooled.min(axis=0))
    np.testing.assert_array_equal(merged["max"], pooled.max(axis=0))
    assert merged["count"].tolist() == [sum(sizes)]


def test_image_stats_are_per_channel_in_unit_range_and_exact() -> None:
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, size=(40, 60, 3), dtype=np.uint8) for _ in range(5)]
    frames[0][:, :, 0] = 255  # red channel saturated in one frame
    acc = ImageStatsAccumulator(max_side=1000)  # no subsampling: exact
    for frame in frames:
        acc.update(frame)
    stats = acc.result()
    pixels = np.stack(frames).reshape(-1, 3) / 255.0
    assert stats["mean"].shape == (3, 1, 1)
    np.testing.assert_allclose(stats["mean"].ravel(), pixels.mean(axis=0), atol=1e-12)
    np.testing.assert_allclose(stats["std"].ravel(), pixels.std(axis=0), atol=1e-9)
    np.testing.assert_allclose(stats["max"].ravel(), pixels.max(axis=0))
    np.testing.assert_allclose(stats["q50"].ravel(), np.quantile(pixels, 0.5, axis=0, method="inverted_cdf"))
    assert stats["count"].tolist() == [5]


def test_histogram_merge_is_exact_across_episodes() -> None:
    rng = np.random.default_rng(1)
    accs = []
    all_frames = []
    for _ in range(3):
        acc = ImageStatsAccumulator(max_side=1000)
        for _ in range(4):
            frame = rng.integers(0, 256, size=(8, 8, 3), dtype=np.uint8)
            acc.update(frame)
            all_frames.append(frame)
        accs.append(acc)
    merged = merge_histograms([a.histogram() for a in accs], [a.frames for a in accs])
    pixels = np.stack(all_frames).reshape(-1, 3) / 255.0
    np.testing.assert_allclose(merged["q90"].ravel(), np.quantile(pixels, 0.9, axis=0, method="inverted_cdf"))
    assert merged["count"].tolist() == [12]


@settings(max_examples=60, deadline=None)
@given(
    sizes=st.lists(st.integers(1, 200), min_size=1, max_size=5),
    seed=st.integers(0, 1000),
    discrete=st.booleans(),
    bins=st.sampled_from([7, 100, QUANTILE_BINS]),
)
def test_dataset_quantiles_are_within_one_bin_of_exact(
    sizes: list[int], seed: int, discrete: bool, bins: int
) -> None:
    rng = np.random.default_rng(seed)
    parts = [rng.standard_cauchy(size=(n, 2)) for n in sizes]  # heavy tails: wide, uneven ranges
    if discrete:
        parts = [np.round(p) for p in parts]
    pooled = np.concatenate(parts)
    pooled[:, 1] = 3.0 if discrete else pooled[:, 1]  # a constant dimension too
    counter = QuantileHistogram(pooled.min(axis=0), pooled.max(axis=0), bins=bins)
    start = 0
    for n in sizes:  # streamed in pieces, as the reduce step reads files
        counter.update(pooled[start : start + n])
        start += n
    width = counter.bin_width()
    for key, value in counter.quantiles().items():
        exact = np.quantile(pooled, QUANTILES[key], axis=0, method="inverted_cdf")
        assert np.all(np.abs(value - exact) <= width * (1 + 1e-9) + 1e-12), (key, value, exact, width)
