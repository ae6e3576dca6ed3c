"""The pure segmentation functions: events, gaps, done signals, short windows."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from bagport.segment import (
    EpisodeWindow,
    Event,
    EventKind,
    Segmentation,
    done_edges_ns,
    drop_short,
    split_at_done,
    split_at_gaps,
    windows_from_events,
)

S = 1_000_000_000
T0 = 1_700_000_000 * S
END = T0 + 20 * S


def ev(t_s: float, kind: str, note: str = "") -> Event:
    return Event(T0 + round(t_s * S), EventKind(kind), note)


def spans(seg: Segmentation) -> list[tuple[float, float, str | None]]:
    return [((w.start_ns - T0) / S, (w.end_ns - T0) / S, w.label) for w in seg.windows]


def test_three_demonstrations_separated_by_reset_periods() -> None:
    events = [
        ev(1, "START"), ev(4, "SUCCESS", "clean"), ev(4.5, "RESET"),
        ev(7, "START"), ev(10, "FAIL", "dropped the cube"), ev(10.5, "RESET"),
        ev(13, "START"), ev(16, "SUCCESS"), ev(16.5, "RESET"),
    ]  # fmt: skip
    seg = windows_from_events(events, T0, END)
    assert spans(seg) == [(1, 4, "success"), (7, 10, "failed"), (13, 16, "success")]
    assert [w.note for w in seg.windows] == ["clean", "dropped the cube", ""]
    # the reset periods (4.5..7, 10.5..13, 16.5..) belong to no episode
    for window in seg.windows:
        for reset_s in (5.0, 11.0, 17.0):
            assert not window.start_ns <= T0 + reset_s * S <= window.end_ns


def test_start_without_end_runs_to_the_next_start_or_the_bag_end_unlabelled() -> None:
    seg = windows_from_events([ev(1, "START"), ev(5, "START")], T0, END)
    assert spans(seg) == [(1, 5 - 1e-9, None), (5, 20, None)]
    assert [w.ended_by for w in seg.windows] == ["START", "bag end"]


def test_success_without_start_begins_at_the_previous_boundary() -> None:
    seg = windows_from_events([ev(3, "SUCCESS"), ev(6, "DISCARD", "operator bumped the table")], T0, END)
    assert spans(seg) == [(0, 3, "success"), (3 + 1e-9, 6, "discarded")]
    assert any("after the last event" in reason for reason in seg.ignored)


def test_reset_ends_an_open_episode_and_an_outcome_inside_a_reset_period_is_ignored() -> None:
    events = [ev(1, "START"), ev(3, "RESET"), ev(4, "SUCCESS"), ev(6, "START"), ev(8, "FAIL")]
    seg = windows_from_events(events, T0, END)
    assert spans(seg) == [(1, 3 - 1e-9, None), (6, 8, "failed")]
    assert any("SUCCESS at 4.000 s ignored: inside the reset period" in r for r in seg.ignored)


def test_no_events_is_one_unlabelled_episode() -> None:
    assert spans(windows_from_events([], T0, END)) == [(0, 20, None)]


def test_events_out_of_order_in_the_list_are_sorted_by_time() -> None:
    seg = windows_from_events([ev(4, "SUCCESS"), ev(1, "START")], T0, END)
    assert spans(seg) == [(1, 4, "success")]


def test_gaps_cut_windows_and_the_silence_belongs_to_no_episode() -> None:
    stamps = (
        np.concatenate(
            [
                np.arange(0, 5 * S, S // 10),
                np.arange(8 * S, 12 * S, S // 10),
                np.arange(12 * S + S // 2, 20 * S, S // 10),
            ]
        ).astype(np.int64)
        + T0
    )  # silences 4.9..8 s (3.1 s) and 11.9..12.5 s (0.6 s)
    whole = windows_from_events([], T0, END)
    seg = split_at_gaps(whole, stamps, gap_s=1.0)
    assert spans(seg) == [(0, 4.9, None), (8, 20, None)]
    assert seg.windows[0].ended_by == "gap"
    finer = split_at_gaps(whole, stamps, gap_s=0.5)
    assert len(finer.windows) == 3


def test_gaps_keep_the_label_of_the_window_they_cut() -> None:
    stamps = (T0 + np.array([0, 1, 2, 6, 7, 8]) * S).astype(np.int64)
    seg = split_at_gaps(windows_from_events([ev(8, "FAIL")], T0, END), stamps, gap_s=2)
    assert spans(seg) == [(0, 2, "failed"), (6, 8, "failed")]


def test_done_edges_are_rising_edges_only() -> None:
    stamps = [T0 + k * S for k in range(8)]
    assert done_edges_ns(stamps, [0, 1, 1, 0, 0, 1, 0, 1]) == [T0 + S, T0 + 5 * S, T0 + 7 * S]
    assert done_edges_ns([T0], [1.0]) == [T0]


def test_done_signal_ends_the_episode_and_the_next_starts_right_after() -> None:
    seg = split_at_done(windows_from_events([], T0, END), [T0 + 5 * S, T0 + 12 * S, T0 + 30 * S])
    assert spans(seg) == [(0, 5, None), (5 + 1e-9, 12, None), (12 + 1e-9, 20, None)]
    assert [w.ended_by for w in seg.windows] == ["done", "done", "bag end"]


def test_short_windows_are_dropped_and_listed() -> None:
    seg = Segmentation((EpisodeWindow(T0, T0 + S // 2), EpisodeWindow(T0 + S, T0 + 3 * S)))
    kept = drop_short(seg, 1.0, T0)
    assert spans(kept) == [(1, 3, None)]
    assert kept.ignored == ("0.000 s..0.500 s: shorter than min_duration_s 1",)


KINDS = st.sampled_from([k.value for k in EventKind])


@given(st.lists(st.tuples(st.integers(0, 20 * S), KINDS), max_size=30))
def test_windows_are_ordered_disjoint_inside_the_bag_and_exclude_reset_periods(
    raw: list[tuple[int, str]],
) -> None:
    events = [Event(T0 + t, EventKind(kind)) for t, kind in raw]
    seg = windows_from_events(events, T0, END)
    previous_end = T0 - 1
    for window in seg.windows:
        assert previous_end < window.start_ns <= window.end_ns <= END
        previous_end = window.end_ns
    # a RESET instant is never inside an episode, nor is the time until the next START
    ordered = sorted(events, key=lambda e: e.t_ns)
    for i, event in enumerate(ordered):
        if event.kind is not EventKind.RESET:
            continue
        later = [e.t_ns for e in ordered[i + 1 :] if e.kind is EventKind.START and e.t_ns > event.t_ns]
        until = min(later) if later else END + 1
        same_time = [e for e in ordered if e.t_ns == event.t_ns and e is not event]
        if same_time:
            continue  # simultaneous events: their order is the list's
        for window in seg.windows:
            assert window.end_ns < event.t_ns or window.start_ns >= until


@pytest.mark.parametrize("gap_s", [0.5, 1.0, 3.0])
def test_gap_pieces_never_contain_a_silence_longer_than_gap_s(gap_s: float) -> None:
    rng = np.random.default_rng(1)
    stamps = np.sort(T0 + rng.integers(0, 20 * S, 60)).astype(np.int64)
    seg = split_at_gaps(windows_from_events([], T0, END), stamps, gap_s)
    for window in seg.windows:
        inside = stamps[(stamps >= window.start_ns) & (stamps <= window.end_ns)]
        assert inside.size == 0 or np.diff(inside).max(initial=0) <= gap_s * S
