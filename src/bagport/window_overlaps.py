"""Episodes of one bag whose windows overlap: the frames both hold are in the dataset twice.

A manifest may list a bag several times, each entry with its own window (one episode each), and an
``--append`` adds a window of a bag the dataset does not hold yet as a new episode: it never replaces the
episode of another window (so a window edited in the manifest becomes a second episode). Where a planned
window shares more than an instant with another window of its bag, the plan says so, one line per planned
entry. A warning, not a refusal: overlapping windows can be meant (a sub-task inside a longer episode), and
a scheduled run goes on.

Windows of a bag are compared on one clock at a time (seconds from the bag's start, or ROS time; the whole
bag overlaps every window), sorted by start, so a plan with thousands of windows per bag stays cheap.
"""

from __future__ import annotations

from bisect import bisect_left
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from bagport.manifest import BagEntry
from bagport.timewindow import TimeWindow

__all__ = ["WindowOverlap", "window_overlaps"]


@dataclass(frozen=True, slots=True)
class WindowOverlap:
    """A planned episode's window that overlaps another window of its bag."""

    uri: str
    entry: int
    window: TimeWindow
    other: TimeWindow
    other_entry: int | None
    """The other window's manifest entry; ``None``: an episode the dataset holds already."""

    def note(self) -> str:
        """One line for the run's log and the CLI."""
        head = f"bags[{self.entry}] {self.uri}: {_its(self.window)} overlaps "
        if self.other_entry is not None:
            return (
                f"{head}bags[{self.other_entry}]'s {_named(self.other)}: the frames in both are in two episodes "
                "(give each entry its own part of the bag if that is not meant)"
            )
        return (
            f"{head}{_named(self.other)}, which the dataset holds already: the frames in both are in two "
            "episodes. An append adds a window as a new episode and never replaces one; to change an "
            "episode's window, write the dataset again (--overwrite, without --append)"
        )


def _its(window: TimeWindow) -> str:
    return "the whole bag" if window.is_whole_bag else f"its window {window.text()}"


def _named(window: TimeWindow) -> str:
    return "whole bag" if window.is_whole_bag else f"window {window.text()}"


def window_overlaps(
    planned: Sequence[BagEntry], held: Iterable[tuple[str, str | None]] = (), *, whole_bag_split: bool = False
) -> tuple[WindowOverlap, ...]:
    """For each ``planned`` bag whose window overlaps another window of its bag (another planned entry's,
    or one of ``held``: ``(URI, window key)`` of the dataset's episodes of the same recording; a key ``None``,
    from an older record, is never compared), one :class:`WindowOverlap`. Windows on different clocks are
    not compared (that needs the bag), but the whole bag overlaps every window. ``whole_bag_split``: the
    contract splits a whole bag into the episodes it finds, so a whole-bag window stands for episodes whose
    windows are not known here, and is not compared."""
    by_uri: dict[str, list[_Window]] = {}
    for bag in planned:
        by_uri.setdefault(bag.uri, []).append(_Window(bag.window, bag.entry))
    for uri, key in held:
        window = TimeWindow.from_key(key) if uri in by_uri else None
        if window is not None:
            by_uri[uri].append(_Window(window, None))
    found = []
    for uri, listed in by_uri.items():
        windows = _compared(listed, whole_bag_split)
        pairs = _first_overlaps(windows)
        for mine, theirs in pairs.items():
            entry, other = windows[mine].entry, windows[theirs]
            if pairs.get(theirs) == mine and (other.entry or 0) > (entry or 0):
                continue  # two entries naming each other: said once, on the later one
            if entry is not None:  # always: only planned windows are looked for
                found.append(WindowOverlap(uri, entry, windows[mine].window, other.window, other.entry))
    return tuple(sorted(found, key=lambda o: o.entry))


@dataclass(frozen=True, slots=True)
class _Window:
    window: TimeWindow
    entry: int | None
    """The planned entry; ``None`` for a window the dataset holds."""


def _compared(windows: Sequence[_Window], whole_bag_split: bool) -> list[_Window]:
    """The windows of a bag to compare: not a whole bag the contract splits, nor a held window a planned
    entry repeats (another recording's, a re-recorded bag: not an overlap)."""
    kept = [w for w in windows if not (whole_bag_split and w.window.is_whole_bag)]
    planned = {w.window for w in kept if w.entry is not None}
    return [w for w in kept if w.entry is not None or w.window not in planned]


def _first_overlaps(windows: Sequence[_Window]) -> dict[int, int]:
    """Per planned window (its index in ``windows``), one other window it overlaps (its index): a sweep per clock over
    the windows sorted by start, each planned window compared with the two that end last among those that
    start before it ends (itself, and the other)."""
    found: dict[int, int] = {}
    for clock in ("s", "ns"):
        spans = sorted(
            (span[1], span[2], n)
            for n, w in enumerate(windows)
            if (span := w.window.span()) is not None and span[0] in (clock, None)
        )
        starts = [start for start, _, _ in spans]
        last_two = _ends_so_far(spans)
        for start, end, n in spans:
            if windows[n].entry is None or n in found:
                continue
            before = bisect_left(starts, end) - 1  # the windows that start before this one ends
            if before < 0:
                continue
            other = next(((e, m) for e, m in last_two[before] if m != n), None)
            if other is not None and other[0] > start:
                found[n] = other[1]
    whole = [n for n, w in enumerate(windows) if w.window.is_whole_bag]
    for n, w in enumerate(windows):  # a window on both clocks overlaps the whole bag alone (as far as known)
        if w.entry is not None and n not in found and w.window.span() is None:
            whole_other = next((m for m in whole if m != n), None)
            if whole_other is not None:
                found[n] = whole_other
    return found


def _ends_so_far(spans: Sequence[tuple[float, float, int]]) -> list[tuple[tuple[float, int], ...]]:
    """For each prefix of ``spans``: the (end, index) of the two spans that end last."""
    best: tuple[tuple[float, int], ...] = ()
    prefixes = []
    for _, end, n in spans:
        best = tuple(sorted((*best, (end, n)), reverse=True)[:2])
        prefixes.append(best)
    return prefixes
