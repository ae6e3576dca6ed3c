"""Episodes inside a bag: pure functions from events, stream stamps and done signals to time windows.

Every time is a bag log (receive) time in integer ns; a window ``[start_ns, end_ns]`` is inclusive.

Event semantics (:class:`EventKind`):

- ``START`` opens an episode. A ``START`` while one is open ends the open one just before it
  (unlabelled: no outcome was recorded).
- ``SUCCESS`` / ``FAIL`` / ``DISCARD`` end the open episode with the label ``success`` / ``failed`` /
  ``discarded``. Without a ``START`` the episode began at the previous boundary: the bag start or the
  previous outcome event (recorders that only mark outcomes).
- ``RESET`` ends the open episode (unlabelled) and begins a reset period, which belongs to no
  episode and lasts until the next ``START``; an outcome inside a reset period is ignored (and said so).
- Data after the last event that no ``START`` opened is not an episode; a bag without any event is
  one unlabelled episode.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from enum import StrEnum

import numpy as np
import numpy.typing as npt

from bagport.align import NS_PER_S
from bagport.timewindow import TimeWindow

__all__ = [
    "EpisodeWindow",
    "Event",
    "EventKind",
    "Segmentation",
    "done_edges_ns",
    "drop_short",
    "label_reason",
    "split_at_done",
    "split_at_gaps",
    "windows_from_events",
]


class EventKind(StrEnum):
    START = "START"
    SUCCESS = "SUCCESS"
    FAIL = "FAIL"
    DISCARD = "DISCARD"
    RESET = "RESET"


OUTCOME_LABELS = {EventKind.SUCCESS: "success", EventKind.FAIL: "failed", EventKind.DISCARD: "discarded"}
EXCLUDED_LABELS = frozenset({"failed", "discarded"})
"""Labels whose episodes are left out of the dataset unless asked to keep them."""


def label_reason(label: str | None, note: str) -> str:
    """Why an episode is left out for its label (one of :data:`EXCLUDED_LABELS`)."""
    return f"labelled {label}" + (f" ({note})" if note else "") + "; --keep-failed keeps it"


@dataclass(frozen=True, slots=True)
class Event:
    t_ns: int
    kind: EventKind
    note: str = ""
    episode_id: str = ""
    """The recorder's own episode id (the seed's event schema), if the event carries one."""


@dataclass(frozen=True, slots=True)
class EpisodeWindow:
    start_ns: int
    end_ns: int
    label: str | None = None
    """``success``, ``failed``, ``discarded``, or ``None`` (no outcome recorded)."""
    note: str = ""
    ended_by: str = ""
    """What ended the window: an event name, ``gap``, ``done``, ``bag end``."""
    episode_id: str = ""
    """The recorder's episode id from the events that opened or ended the window (empty: none)."""

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / NS_PER_S

    @property
    def window(self) -> TimeWindow:
        """The episode's window of the bag, as an episode request holds it."""
        return TimeWindow.of_ns(self.start_ns, self.end_ns)


@dataclass(frozen=True, slots=True)
class Segmentation:
    windows: tuple[EpisodeWindow, ...]
    ignored: tuple[str, ...] = ()
    """Events and windows left out, each with the reason (for the run's log)."""


def _s(t_ns: int, origin_ns: int) -> str:
    return f"{(t_ns - origin_ns) / NS_PER_S:.3f} s"


def windows_from_events(events: Iterable[Event], start_ns: int, end_ns: int) -> Segmentation:
    """Windows of the bag ``[start_ns, end_ns]`` delimited by ``events`` (see the module doc)."""
    ordered = sorted(events, key=lambda e: e.t_ns)
    if not ordered:
        return Segmentation((EpisodeWindow(start_ns, end_ns, ended_by="bag end"),))
    windows: list[EpisodeWindow] = []
    ignored: list[str] = []
    opened: int | None = None  # time of the START of the open episode
    boundary: int | None = start_ns  # start of an implicit episode; None inside a reset period
    reset_at = start_ns
    opened_id = ""  # the episode id the START carried

    def close(
        begin: int, end: int, label: str | None, note: str, ended_by: str, episode_id: str = ""
    ) -> None:
        begin = max(begin, windows[-1].end_ns + 1) if windows else begin  # simultaneous events
        if begin <= end:
            windows.append(EpisodeWindow(begin, end, label, note, ended_by, opened_id or episode_id))

    for event in ordered:
        t = event.t_ns
        if event.kind is EventKind.START:
            if opened is not None:
                close(opened, t - 1, None, "", "START")
            opened, opened_id = t, event.episode_id
        elif event.kind is EventKind.RESET:
            if opened is not None:
                close(opened, t - 1, None, "", "RESET")
            elif boundary is not None and boundary < t:
                ignored.append(f"{_s(boundary, start_ns)}..{_s(t, start_ns)}: no START before the RESET")
            opened, boundary, reset_at, opened_id = None, None, t, ""
        else:
            begin = opened if opened is not None else boundary
            if begin is None:
                ignored.append(
                    f"{event.kind.value} at {_s(t, start_ns)} ignored: inside the reset period that began at "
                    f"{_s(reset_at, start_ns)} (no START since)"
                )
                continue
            close(begin, t, OUTCOME_LABELS[event.kind], event.note, event.kind.value, event.episode_id)
            opened, boundary, opened_id = None, t + 1, ""
    if opened is not None:
        close(opened, end_ns, None, "", "bag end")
    elif boundary is not None and boundary < end_ns:
        ignored.append(f"{_s(boundary, start_ns)}..{_s(end_ns, start_ns)}: after the last event, no START")
    return Segmentation(tuple(windows), tuple(ignored))


def split_at_gaps(segmentation: Segmentation, stamps_ns: npt.NDArray[np.int64], gap_s: float) -> Segmentation:
    """Cut every window at silences longer than ``gap_s`` in ``stamps_ns`` (all contract streams merged).

    The silence itself belongs to no episode: the piece before ends at the last message before it,
    the piece after starts at the first message after it. Pieces keep their window's label.
    """
    stamps = np.sort(np.asarray(stamps_ns, dtype=np.int64))
    if stamps.size < 2:
        return segmentation
    gap_ns = round(gap_s * NS_PER_S)
    at = np.flatnonzero(np.diff(stamps) > gap_ns)
    silences = list(zip(stamps[at].tolist(), stamps[at + 1].tolist(), strict=True))
    out: list[EpisodeWindow] = []
    for window in segmentation.windows:
        start = window.start_ns
        for before, after in silences:
            if after <= start or before >= window.end_ns:
                continue
            if before >= start:
                out.append(replace(window, start_ns=start, end_ns=before, ended_by="gap"))
            start = after
        if start <= window.end_ns:
            out.append(replace(window, start_ns=start))
    return Segmentation(tuple(out), segmentation.ignored)


def done_edges_ns(stamps_ns: Sequence[int], values: Sequence[float]) -> list[int]:
    """Times at which the done signal turns true (rising edges; a signal true from the start counts)."""
    edges: list[int] = []
    previous = False
    for t_ns, value in sorted(zip(stamps_ns, values, strict=True)):
        current = bool(value)
        if current and not previous:
            edges.append(int(t_ns))
        previous = current
    return edges


def split_at_done(segmentation: Segmentation, edges_ns: Iterable[int]) -> Segmentation:
    """End a window at every done edge inside it; the next window starts just after the edge."""
    cuts = sorted(edges_ns)
    out: list[EpisodeWindow] = []
    for window in segmentation.windows:
        start = window.start_ns
        for edge in cuts:
            if start <= edge < window.end_ns:
                out.append(replace(window, start_ns=start, end_ns=edge, ended_by="done"))
                start = edge + 1
        out.append(replace(window, start_ns=start))
    return Segmentation(tuple(out), segmentation.ignored)


def drop_short(segmentation: Segmentation, min_duration_s: float, origin_ns: int) -> Segmentation:
    """Leave out windows shorter than ``min_duration_s`` (listed in ``ignored``)."""
    kept: list[EpisodeWindow] = []
    ignored = list(segmentation.ignored)
    for window in segmentation.windows:
        if window.duration_s < min_duration_s:
            ignored.append(
                f"{_s(window.start_ns, origin_ns)}..{_s(window.end_ns, origin_ns)}: shorter than "
                f"min_duration_s {min_duration_s:g}"
            )
        else:
            kept.append(window)
    return Segmentation(tuple(kept), tuple(ignored))
