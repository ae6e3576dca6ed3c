"""The frame grid and hold selection, checked against brute force."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from hypothesis import given
from hypothesis import strategies as st

from bagport.align import (
    NS_PER_S,
    Selection,
    grid_drift_ns,
    grid_ticks_ns,
    hold_fill,
    interpolation_span_ns,
    reference_ticks_ns,
    select_for_ticks,
    select_hold,
    tick_count,
)


@given(start=st.integers(0, 2**62), span=st.integers(0, 10 * NS_PER_S), fps=st.integers(1, 240))
def test_tick_count_is_the_last_tick_within_the_span(start: int, span: int, fps: int) -> None:
    n = tick_count(start, start + span, fps)
    assert n * NS_PER_S // fps > span  # the next tick is past the end
    assert (n - 1) * NS_PER_S // fps <= span


def test_grid_does_not_drift_over_an_hour() -> None:
    ticks = grid_ticks_ns(10**18, 10**18 + 3600 * NS_PER_S, 30)
    assert ticks.size == 3600 * 30 + 1
    assert ticks[-1] == 10**18 + 3600 * NS_PER_S
    assert np.all(np.diff(ticks) >= NS_PER_S // 30)


@given(
    stamps=st.lists(st.integers(0, 1000), min_size=0, max_size=30),
    ticks=st.lists(st.integers(-10, 1100), min_size=1, max_size=30),
)
def test_hold_picks_the_latest_stamp_at_or_before_each_tick(stamps: list[int], ticks: list[int]) -> None:
    chosen = select_hold(np.array(stamps, dtype=np.int64), np.array(ticks, dtype=np.int64))
    for tick, index in zip(ticks, chosen, strict=True):
        eligible = [s for s in stamps if s <= tick]
        if not eligible:
            assert index == -1
        else:
            assert stamps[index] == max(eligible)
            # ties: the last logged message with that stamp
            assert index == max(i for i, s in enumerate(stamps) if s == max(eligible))


def test_asof_and_drop_mark_stale_ticks_missing() -> None:
    stamps = np.array([0, 100_000_000], dtype=np.int64)  # 0 s and 0.1 s
    ticks = np.array([0, 33_333_333, 66_666_666, 100_000_000, 180_000_000], dtype=np.int64)
    asof = select_for_ticks(stamps, ticks, strategy="asof", fps=30, tol_ms=50)
    assert asof.lo.tolist() == [0, 0, -1, 1, -1]
    drop = select_for_ticks(stamps, ticks, strategy="drop", fps=30, tol_ms=None)
    assert drop.lo.tolist() == [0, -1, -1, 1, -1]
    hold = select_for_ticks(stamps, ticks, strategy="hold", fps=30, tol_ms=None)
    assert hold.lo.tolist() == [0, 0, 0, 1, 1]
    nearest = select_for_ticks(stamps, ticks, strategy="nearest", fps=30, tol_ms=40)
    assert nearest.lo.tolist() == [0, 0, 1, 1, -1]


@given(
    stamps=st.lists(st.integers(0, 1000), min_size=1, max_size=30),
    ticks=st.lists(st.integers(-10, 1100), min_size=1, max_size=30),
    strategy=st.sampled_from(["hold", "asof", "drop"]),
)
def test_no_look_ahead_for_hold_asof_drop(stamps: list[int], ticks: list[int], strategy: str) -> None:
    stamp_arr = np.array(stamps, dtype=np.int64)
    sel = select_for_ticks(stamp_arr, np.array(ticks, dtype=np.int64), strategy=strategy, fps=30, tol_ms=50)
    for tick, index in zip(ticks, sel.lo.tolist(), strict=True):
        assert index == -1 or stamps[index] <= tick


@given(
    stamps=st.lists(st.integers(0, 10_000), min_size=2, max_size=40, unique=True),
    ticks=st.lists(st.integers(0, 10_000), min_size=1, max_size=30),
    slope=st.floats(-5, 5),
    offset=st.floats(-100, 100),
)
def test_interpolation_is_exact_on_linear_signals(
    stamps: list[int], ticks: list[int], slope: float, offset: float
) -> None:
    stamp_arr = np.array(stamps, dtype=np.int64)
    tick_arr = np.array(ticks, dtype=np.int64)
    sel = select_for_ticks(stamp_arr, tick_arr, strategy="interpolate", fps=30, tol_ms=None)
    assert sel.hi is not None and sel.weight is not None
    values = slope * stamp_arr + offset
    inside = (tick_arr >= stamp_arr.min()) & (tick_arr <= stamp_arr.max())
    assert np.array_equal(sel.lo >= 0, inside)
    got = (1 - sel.weight) * values[np.maximum(sel.lo, 0)] + sel.weight * values[np.maximum(sel.hi, 0)]
    np.testing.assert_allclose(got[inside], (slope * tick_arr + offset)[inside], atol=1e-6)


@given(
    stamps=st.lists(st.integers(0, 10**9), min_size=2, max_size=40, unique=True),
    ticks=st.lists(st.integers(0, 10**9), min_size=1, max_size=30),
    tol_ms=st.one_of(st.none(), st.floats(1, 500)),
)
def test_interpolation_never_bridges_a_silence_longer_than_its_span(
    stamps: list[int], ticks: list[int], tol_ms: float | None
) -> None:
    stamp_arr = np.array(stamps, dtype=np.int64)
    tick_arr = np.array(ticks, dtype=np.int64)
    span_ns = interpolation_span_ns(stamp_arr, 30, tol_ms)
    sel = select_for_ticks(stamp_arr, tick_arr, strategy="interpolate", fps=30, tol_ms=tol_ms)
    assert sel.hi is not None
    ordered = np.sort(stamp_arr)
    for tick, lo, hi in zip(ticks, sel.lo.tolist(), sel.hi.tolist(), strict=True):
        before, after = ordered[ordered <= tick], ordered[ordered >= tick]
        bridged = before.size > 0 and after.size > 0 and after.min() - before.max() <= span_ns
        assert (lo >= 0) == bridged
        if bridged:
            assert stamps[lo] == before.max() and stamps[hi] == after.min()


def test_interpolation_span_defaults_to_five_intervals_or_two_frames() -> None:
    at_500hz = np.arange(0, NS_PER_S, 2_000_000, dtype=np.int64)
    assert interpolation_span_ns(at_500hz, 30, None) == 2 * NS_PER_S // 30  # 10 ms < two frames
    at_10hz = np.arange(0, 10 * NS_PER_S, 100_000_000, dtype=np.int64)
    assert interpolation_span_ns(at_10hz, 30, None) == 500_000_000
    assert interpolation_span_ns(at_10hz, 30, 150) == 150_000_000


def test_hold_fill_carries_the_last_value_forward_but_not_backward() -> None:
    sel = Selection(np.array([-1, 0, -1, -1, 1, -1], dtype=np.int64))
    latest = np.array([-1, 0, 0, 2, 1, 3], dtype=np.int64)  # select_hold: messages 2, 3 came late
    filled_sel, filled = hold_fill(sel, latest)
    assert filled_sel.lo.tolist() == [-1, 0, 0, 2, 1, 3]
    assert filled.tolist() == [False, False, True, True, False, True]


@given(start=st.integers(0, 2**60), span=st.integers(0, 100 * NS_PER_S), fps=st.integers(1, 240))
def test_grid_ticks_strictly_increase_and_drift_zero(start: int, span: int, fps: int) -> None:
    ticks = grid_ticks_ns(start, start + span, fps)
    assert ticks[0] == start and ticks[-1] <= start + span
    assert np.all(np.diff(ticks) > 0)
    assert not grid_drift_ns(ticks, fps).any()


@given(
    stamps=st.lists(st.integers(0, 10_000), min_size=0, max_size=50),
    window=st.tuples(st.integers(-100, 10_100), st.integers(-100, 10_100)),
)
def test_reference_ticks_are_the_distinct_stamps_in_the_window(
    stamps: list[int], window: tuple[int, int]
) -> None:
    """Out-of-order and duplicated stamps of a clock stream still give strictly increasing ticks."""
    start, end = window
    ticks = reference_ticks_ns(np.array(stamps, dtype=np.int64), start, end)
    assert np.all(np.diff(ticks) > 0)
    assert ticks.tolist() == sorted({s for s in stamps if start <= s <= end})


def test_grid_drift_measures_a_slow_clock() -> None:
    ticks = np.arange(0, 31, dtype=np.int64) * 34_000_000  # 29.4 Hz against fps 30
    drift = grid_drift_ns(ticks, 30)
    assert drift[0] == 0
    assert drift[30] == 30 * 34_000_000 - NS_PER_S


strategies_with_tol = st.sampled_from(["hold", "asof", "drop", "nearest", "interpolate"])


@given(
    stamps=st.lists(st.integers(0, 10_000), min_size=1, max_size=40),
    ticks=st.lists(st.integers(-100, 10_100), min_size=1, max_size=40),
    strategy=strategies_with_tol,
)
def test_selected_times_never_go_back_as_ticks_advance(
    stamps: list[int], ticks: list[int], strategy: str
) -> None:
    """Monotonic output: for increasing ticks, the selected source times do not decrease."""
    stamp_arr = np.array(stamps, dtype=np.int64)
    tick_arr = np.sort(np.array(ticks, dtype=np.int64))
    sel = select_for_ticks(stamp_arr, tick_arr, strategy=strategy, fps=30, tol_ms=0.002)
    valid = sel.lo >= 0
    chosen = stamp_arr[sel.lo[valid]]
    assert np.all(np.diff(chosen) >= 0)
    if sel.hi is not None:
        assert np.all(np.diff(stamp_arr[sel.hi[valid]]) >= 0)


def _step(t: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """A signal that changes only at multiples of 1000: sampled at its changes, hold is exact."""
    return (t // 1000) ** 2


@given(
    changes=st.lists(st.integers(0, 20), min_size=1, max_size=21, unique=True),
    ticks=st.lists(st.integers(0, 25_000), min_size=1, max_size=40),
)
def test_hold_is_exact_on_a_signal_sampled_at_its_changes(changes: list[int], ticks: list[int]) -> None:
    stamp_arr = np.array(sorted(set(changes) | {0}), dtype=np.int64) * 1000
    values = _step(stamp_arr)
    tick_arr = np.array(ticks, dtype=np.int64)
    sel = select_for_ticks(stamp_arr, tick_arr, strategy="hold", fps=30, tol_ms=None)
    # the true value at the tick is the value at the last change before it
    last_change = stamp_arr[np.searchsorted(stamp_arr, tick_arr, side="right") - 1]
    np.testing.assert_array_equal(values[sel.lo], _step(last_change))


@given(
    stamps=st.lists(st.integers(0, 10_000_000), min_size=1, max_size=40, unique=True),
    ticks=st.lists(st.integers(0, 10_000_000), min_size=1, max_size=40),
    tol_ms=st.floats(0.001, 20.0),
)
def test_nearest_and_asof_exact_within_their_tolerance(
    stamps: list[int], ticks: list[int], tol_ms: float
) -> None:
    stamp_arr = np.array(stamps, dtype=np.int64)
    tick_arr = np.array(ticks, dtype=np.int64)
    tol_ns = round(tol_ms * 1e6)
    nearest = select_for_ticks(stamp_arr, tick_arr, strategy="nearest", fps=30, tol_ms=tol_ms)
    asof = select_for_ticks(stamp_arr, tick_arr, strategy="asof", fps=30, tol_ms=tol_ms)
    for k, tick in enumerate(ticks):
        gaps = np.abs(stamp_arr - tick)
        if gaps.min() <= tol_ns:
            assert abs(stamps[nearest.lo[k]] - tick) == gaps.min()
        else:
            assert nearest.lo[k] == -1
        before = stamp_arr[stamp_arr <= tick]
        if before.size and tick - before.max() <= tol_ns:
            assert stamps[asof.lo[k]] == before.max()
        else:
            assert asof.lo[k] == -1
