"""Episodes of one bag whose windows overlap: the frames both hold are in the dataset twice.

A manifest may list a bag several times, each entry with its own window (one episode each), and an
``--append`` adds a window of a bag the dataset does not hold yet as a new episode: it never replaces the
episode of another window (so a window edited in the manifest becomes a second episode). Where two windows
of a bag share more than an instant, the plan says so, one line each. A warning, not a refusal: overlapping
windows can be meant (a sub-task inside a longer episode), and a scheduled run goes on.
"""

from __future__ import annotations

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
        head = f"bags[{self.entry}] {self.uri}: its window {self.window.text()} overlaps "
        if self.other_entry is not None:
            return (
                f"{head}bags[{self.other_entry}]'s window {self.other.text()}: the frames in both are in two "
                "episodes (give each entry its own part of the bag if that is not meant)"
            )
        return (
            f"{head}the window {self.other.text()} the dataset holds already: the frames in both are in two "
            "episodes. An append adds a window as a new episode and never replaces one; to change an "
            "episode's window, write the dataset again (--overwrite, without --append)"
        )


def window_overlaps(
    planned: Sequence[BagEntry], held: Iterable[tuple[str, str | None]] = ()
) -> tuple[WindowOverlap, ...]:
    """The overlaps among the ``planned`` bags' windows, then between them and ``held`` (``(URI, window
    key)`` of the dataset's episodes; a key ``None``, from an older record, is never compared). Windows on
    different clocks (seconds from the bag's start against ROS time) are not compared: that needs the bag."""
    by_uri: dict[str, list[BagEntry]] = {}
    for bag in planned:
        by_uri.setdefault(bag.uri, []).append(bag)
    found = [
        WindowOverlap(uri, bag.entry, bag.window, other.window, other.entry)
        for uri, entries in by_uri.items()
        for n, bag in enumerate(entries)
        for other in entries[:n]
        if bag.window.overlaps(other.window)
    ]
    for uri, key in held:
        window = TimeWindow.from_key(key) if uri in by_uri else None
        if window is None:
            continue
        found += [
            WindowOverlap(uri, bag.entry, bag.window, window, None)
            for bag in by_uri[uri]
            if bag.window != window and bag.window.overlaps(window)  # the same window: a re-recorded bag
        ]
    return tuple(sorted(found, key=lambda o: (o.entry, o.other_entry is None, o.other_entry or 0)))
