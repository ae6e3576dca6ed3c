"""An episode's time window in a bag: one value from the manifest entry to the worker that reads it.

Each end is given on one of two clocks, or not at all: ``*_ns`` in the bag's log time (ROS time,
absolute), ``*_s`` in seconds from the bag's first message (a manifest's ``start_s``/``end_s``, known
in absolute time only once the bag is open). An end not given is the bag's own start or end; a window
with no end given is the whole bag (the default, :data:`WHOLE_BAG`).

A low, neutral module: the manifest (:mod:`bagport.manifest`), the episode request
(:mod:`bagport.request`), segmentation and conversion all pass a :class:`TimeWindow`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["WHOLE_BAG", "TimeWindow", "WindowNs"]

_NS_PER_S = 1_000_000_000

WindowNs = tuple[int, int]
"""A window resolved in a bag (:meth:`TimeWindow.resolve`): ``(start_ns, end_ns)`` in log time, inclusive."""


@dataclass(frozen=True, slots=True)
class TimeWindow:
    """``[start, end]`` (inclusive) of a bag; see the module doc for the two clocks."""

    start_ns: int | None = None
    end_ns: int | None = None
    """Bag log time (ROS time) in ns; ``None``: from the bag's start / to its end (or ``*_s``)."""
    start_s: float | None = None
    end_s: float | None = None
    """Seconds from the bag's first message (resolved when the bag is open)."""

    @classmethod
    def of_ns(cls, start_ns: int, end_ns: int) -> TimeWindow:
        """The window ``[start_ns, end_ns]`` in bag log time (an episode a segmentation found)."""
        return cls(start_ns=start_ns, end_ns=end_ns)

    @property
    def is_whole_bag(self) -> bool:
        """No end given: the whole bag (or the episodes a contract finds in it)."""
        return self.start_ns is None and self.end_ns is None and self.start_s is None and self.end_s is None

    def key(self) -> str:
        """The window as text, for the ids of what it stages (empty for the whole bag)."""
        if self.is_whole_bag:
            return ""
        return f"{self.start_ns}:{self.end_ns}:{self.start_s}:{self.end_s}"

    @classmethod
    def from_key(cls, key: str | None) -> TimeWindow | None:
        """The window whose :meth:`key` this is; ``None`` for anything else (an older record's ``None``)."""
        if key is None:
            return None
        if key == "":
            return cls()
        parts = key.split(":")
        if len(parts) != 4:
            return None
        try:
            start_ns, end_ns = (None if p == "None" else int(p) for p in parts[:2])
            start_s, end_s = (None if p == "None" else float(p) for p in parts[2:])
        except ValueError:
            return None
        return cls(start_ns=start_ns, end_ns=end_ns, start_s=start_s, end_s=end_s)

    def overlaps(self, other: TimeWindow) -> bool | None:
        """Whether two windows of one bag share more than an instant (consecutive windows, one ending where
        the next starts, do not); the whole bag overlaps every window. ``None`` when that needs the bag's
        start: one window is given in seconds from it and the other in ROS time, or one mixes the clocks."""
        if self.is_whole_bag or other.is_whole_bag:
            return True
        mine, theirs = self.span(), other.span()
        if mine is None or theirs is None or mine[0] != theirs[0]:
            return None
        return mine[1] < theirs[2] and theirs[1] < mine[2]

    def span(self) -> tuple[str | None, float, float] | None:
        """``(clock, start, end)`` on the window's one clock (``"ns"``, ``"s"``, ``None`` for the whole bag),
        an end not given as infinite (ns stay integers: exact); ``None`` for a window on both clocks."""
        on_ns = self.start_ns is not None or self.end_ns is not None
        on_s = self.start_s is not None or self.end_s is not None
        if on_ns and on_s:
            return None
        start, end = (self.start_ns, self.end_ns) if on_ns else (self.start_s, self.end_s)
        low = -math.inf if start is None else start
        high = math.inf if end is None else end
        return ("ns" if on_ns else "s" if on_s else None), low, high

    def text(self) -> str:
        """The window as a person reads it: ``the whole bag``, ``12.5..47 s`` (from the bag's start; the
        seconds as written), ``from 12.5 s``, ``1700000000000000000..1700000005000000000 ns`` (ROS time)."""
        if self.is_whole_bag:
            return "the whole bag"
        parts = []
        for start, end, unit in ((self.start_s, self.end_s, "s"), (self.start_ns, self.end_ns, "ns")):
            low, high = _number(start), _number(end)
            if start is not None and end is not None:
                parts.append(f"{low}..{high} {unit}")
            elif start is not None:
                parts.append(f"from {low} {unit}")
            elif end is not None:
                parts.append(f"to {high} {unit}")
        return " and ".join(parts)

    def resolve(self, bag_start_ns: int, bag_end_ns: int) -> WindowNs | None:
        """The window in log time (ns, inclusive) in a bag spanning ``[bag_start_ns, bag_end_ns]``;
        ``None`` for the whole bag."""
        if self.is_whole_bag:
            return None
        start, end = bag_start_ns, bag_end_ns
        if self.start_ns is not None:
            start = self.start_ns
        elif self.start_s is not None:
            start = bag_start_ns + round(self.start_s * _NS_PER_S)
        if self.end_ns is not None:
            end = self.end_ns
        elif self.end_s is not None:
            end = bag_start_ns + round(self.end_s * _NS_PER_S)
        return start, end


def _number(value: float | None) -> str:
    """Seconds or ns as written (``12345.61``, ``47``), never rounded to fewer digits."""
    if value is None:
        return ""
    return repr(value).removesuffix(".0") if isinstance(value, float) else str(value)


WHOLE_BAG = TimeWindow()
