"""The frame grid and hold selection, checked against brute force."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from bagport.align import NS_PER_S, grid_ticks_ns, select_for_ticks, select_hold, tick_count


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
    assert asof.tolist() == [0, 0, -1, 1, -1]
    drop = select_for_ticks(stamps, ticks, strategy="drop", fps=30, tol_ms=None)
    assert drop.tolist() == [0, -1, -1, 1, -1]
    hold = select_for_ticks(stamps, ticks, strategy="hold", fps=30, tol_ms=None)
    assert hold.tolist() == [0, 0, 0, 1, 1]
