"""The frame grid and hold selection, checked against brute force."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from bagport.align import (
    NS_PER_S,
    Selection,
    grid_ticks_ns,
    hold_fill,
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


def test_hold_fill_carries_the_last_value_forward_but_not_backward() -> None:
    sel = Selection(np.array([-1, 0, -1, -1, 1, -1], dtype=np.int64))
    filled_sel, filled = hold_fill(sel)
    assert filled_sel.lo.tolist() == [-1, 0, 0, 0, 1, 1]
    assert filled.tolist() == [False, False, True, True, False, True]
