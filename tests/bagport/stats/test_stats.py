"""Stats partials and their merge agree with stats computed over all data at once."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
from hypothesis import given, settings
from hypothesis import strategies as st

from bagport.stats import (
    QUANTILES,
    ImageStatsAccumulator,
    column_stats,
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


@settings(max_examples=30, deadline=None)
@given(frames=st.integers(1, 40), dims=st.integers(1, 5), seed=st.integers(0, 1000))
def test_vector_quantiles_are_numpys_per_dimension(frames: int, dims: int, seed: int) -> None:
    values = np.random.default_rng(seed).normal(size=(frames, dims))
    stats = vector_stats(values)
    for key, q in QUANTILES.items():
        np.testing.assert_array_equal(stats[key], np.quantile(values, q, axis=0))
    assert stats["q50"].shape == (dims,)


@settings(max_examples=30, deadline=None)
@given(frames=st.sampled_from([1, 2, 3, 7, 60, 997, 30_001, 250_000]), fps=st.sampled_from([10, 15, 30, 50]))
def test_column_stats_equal_each_columns_vector_stats_bit_for_bit(frames: int, fps: int) -> None:
    """An episode's index columns (as the reduce builds them) in one call: the values of one call each,
    exactly, also where float sums depend on their order (long float32 timestamps)."""
    rng = np.random.default_rng(frames + fps)
    frame_index = np.arange(frames, dtype=np.int64)
    columns: list[npt.NDArray[Any]] = [
        (frame_index / fps).astype(np.float32),
        frame_index,
        np.full(frames, 41),
        np.arange(123_456, 123_456 + frames),
        np.sort(rng.integers(0, 4, size=frames)),
        rng.normal(size=frames) * 1e6,
    ]
    together = column_stats(columns)
    for column, stats in zip(columns, together, strict=True):
        alone = vector_stats(column)
        assert stats.keys() == alone.keys()
        for key, value in alone.items():
            assert stats[key].dtype == value.dtype and stats[key].shape == value.shape, key
            assert stats[key].tobytes() == value.tobytes(), key


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


def test_a_subsampled_frame_counts_exactly_the_sampled_pixels() -> None:
    """Frames larger than ``max_side`` are counted on every ``step``-th row and column (a strided view)."""
    frame = np.random.default_rng(2).integers(0, 256, size=(481, 641, 3), dtype=np.uint8)
    acc = ImageStatsAccumulator(max_side=150)
    acc.update(frame)
    sample = frame[::4, ::4]  # 641 // 150
    expected = [np.bincount(sample[:, :, c].ravel(), minlength=256) for c in range(3)]
    np.testing.assert_array_equal(acc.histogram(), np.stack(expected))


def _channel_counts(frames: list[npt.NDArray[np.uint8]]) -> npt.NDArray[np.int64]:
    pixels = np.concatenate([f.reshape(-1, 3) for f in frames])
    return np.stack([np.bincount(pixels[:, c], minlength=256) for c in range(3)])


def test_colour_frames_counted_in_batches_count_every_frame_once() -> None:
    """Frames are counted a batch at a time: full batches, a partial one, a size change, and a histogram
    read between frames all give exactly the counts of every frame seen so far."""
    rng = np.random.default_rng(3)
    batch = ImageStatsAccumulator.RGB_BATCH_FRAMES
    small = [rng.integers(0, 256, size=(12, 20, 3), dtype=np.uint8) for _ in range(2 * batch + 5)]
    large = [rng.integers(0, 256, size=(30, 16, 3), dtype=np.uint8) for _ in range(batch + 1)]
    acc = ImageStatsAccumulator(max_side=1000)
    for frame in small[:7]:
        acc.update(frame)
    np.testing.assert_array_equal(acc.histogram(), _channel_counts(small[:7]))  # a partial batch, read
    for frame in small[7:] + large:
        acc.update(frame)
    np.testing.assert_array_equal(acc.histogram(), _channel_counts(small + large))
    assert acc.frames == len(small) + len(large)
    assert acc.result()["count"].tolist() == [len(small) + len(large)]
