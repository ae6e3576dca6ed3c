"""Merged KLL sketches against exact quantiles on designed skewed data: many episodes of very different
lengths, a bimodal joint, a heavy-tailed one, and a constant one."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
from hypothesis import given, settings
from hypothesis import strategies as st

from bagport.stats import QUANTILES, VectorSketch, episode_sketch_fields, rank_error


def rank_interval(pooled: npt.NDArray[np.float64], value: float) -> tuple[float, float]:
    """The normalised ranks ``value`` spans in ``pooled`` (share strictly below, share at or below)."""
    ordered = np.sort(pooled)
    below = np.searchsorted(ordered, value, side="left") / ordered.size
    at_or_below = np.searchsorted(ordered, value, side="right") / ordered.size
    return float(below), float(at_or_below)


def assert_within_rank_bound(pooled: npt.NDArray[Any], quantiles: dict[str, npt.NDArray[Any]]) -> float:
    """Every quantile lies within the stated rank error of the exact one; returns the worst rank error."""
    eps = rank_error()
    worst = 0.0
    data = np.asarray(pooled, dtype=np.float64).reshape(len(pooled), -1)
    for key, q in QUANTILES.items():
        for dim in range(data.shape[1]):
            below, at_or_below = rank_interval(data[:, dim], float(np.ravel(quantiles[key])[dim]))
            error = max(below - q, q - at_or_below, 0.0)
            worst = max(worst, error)
            assert error <= eps, (key, dim, error, eps)
    return worst


def skewed_episodes(count: int, seed: int) -> list[npt.NDArray[np.float64]]:
    """Episodes of 3 to ~20,000 frames (log-uniform); dims: bimodal joint, lognormal, constant."""
    rng = np.random.default_rng(seed)
    episodes = []
    for n in range(count):
        length = int(np.exp(rng.uniform(np.log(3), np.log(20_000))))
        mode = n % 7 == 0  # one episode in seven sits in the second mode
        bimodal = rng.normal(2.0 if mode else -1.0, 0.3 if mode else 0.05, length)
        heavy = rng.lognormal(0.0, 2.0, length)
        episodes.append(np.stack([bimodal, heavy, np.full(length, 0.25)], axis=1))
    return episodes


def test_merged_sketches_are_within_the_rank_bound_before_and_after_an_append() -> None:
    first, second = skewed_episodes(120, seed=1), skewed_episodes(40, seed=2)
    stored = VectorSketch.merged(VectorSketch.from_json(episode_sketch_fields(e)["sketch"]) for e in first)
    assert stored is not None
    worst = assert_within_rank_bound(np.concatenate(first), stored.quantiles())
    # an append: the stored sketch (through its JSON form) merged with the new episodes' sketches
    appended = VectorSketch.from_json(stored.to_json())
    for episode in second:
        appended.merge(VectorSketch.of(episode))
    pooled = np.concatenate(first + second)
    assert appended.count == len(pooled)
    worst = max(worst, assert_within_rank_bound(pooled, appended.quantiles()))
    assert worst > 0  # the sketch really estimated (it holds far fewer values than it saw)
    # LeRobot's count-weighted mean of per-episode quantiles is far off on the bimodal joint
    lengths = np.array([len(e) for e in first + second], dtype=np.float64)
    averaged = sum(np.quantile(e[:, 0], 0.5) * n for e, n in zip(first + second, lengths, strict=True))
    below, above = rank_interval(pooled[:, 0], float(averaged / lengths.sum()))
    assert min(abs(below - 0.5), abs(above - 0.5)) > 10 * rank_error()


def test_short_sketches_are_exact_and_skip_non_finite_values() -> None:
    values = np.array([[0.0, 1.0], [np.nan, 2.0], [3.0, np.inf], [1.0, 4.0]])
    sketch = VectorSketch.of(values)
    assert [s.n for s in sketch.sketches] == [3, 3]
    for key, q in QUANTILES.items():
        for dim in range(2):
            column = values[:, dim][np.isfinite(values[:, dim])]
            exact = np.quantile(column, q, method="inverted_cdf")
            assert sketch.quantiles()[key][dim] == exact, (key, dim)


def test_episode_fields_find_the_largest_step_and_its_frame() -> None:
    values = np.zeros((30, 2))
    values[:, 0] = np.linspace(0, 0.29, 30)  # 0.01 rad per frame
    values[12, 1] = 1.0  # a one-frame spike
    fields = episode_sketch_fields(values)
    np.testing.assert_allclose(fields["max_step"], [0.01, 1.0])
    assert fields["max_step_frame"][1] == 12
    steps = VectorSketch.from_json(fields["step_sketch"])
    assert steps.count == 29
    assert steps.quantile(0.5)[1] == 0.0


@settings(max_examples=40, deadline=None)
@given(
    sizes=st.lists(st.integers(1, 600), min_size=1, max_size=6),
    seed=st.integers(0, 1000),
    discrete=st.booleans(),
)
def test_sketches_merged_in_any_pieces_stay_within_the_bound(
    sizes: list[int], seed: int, discrete: bool
) -> None:
    rng = np.random.default_rng(seed)
    parts = [rng.standard_cauchy(size=(n, 2)) for n in sizes]  # heavy tails: wide, uneven ranges
    if discrete:
        parts = [np.round(p) for p in parts]
    for part in parts:
        part[:, 1] = 3.0  # a constant dimension too
    merged = VectorSketch.merged(VectorSketch.of(p) for p in parts)
    assert merged is not None
    assert_within_rank_bound(np.concatenate(parts), merged.quantiles())


def test_a_one_frame_episode_has_no_step() -> None:
    fields = episode_sketch_fields(np.array([[0.5, 1.0, np.nan]]))
    assert fields["max_step"] == [0.0, 0.0, 0.0]
    assert VectorSketch.from_json(fields["step_sketch"]).count == 0
    assert VectorSketch.from_json(fields["sketch"]).quantile(0.5).tolist()[:2] == [0.5, 1.0]
