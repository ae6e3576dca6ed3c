"""The first steps of every pass over one episode, for conversion and ``bagport qa`` alike.

:func:`prepare_episode` checks the bag against the contract, scans its timeline (pass 1,
:mod:`bagport.episode.timeline`) and aligns every source to the frame ticks
(:mod:`bagport.episode.alignment`): a :class:`PreparedEpisode` of immutable values, decided before
any message is decoded. Then :func:`~bagport.episode.assemble.iter_frames` streams pass 2, the
frames going to the sinks (:mod:`bagport.episode.sinks`) or to QA's value monitor alone, and
:func:`~bagport.episode.quality.assess_episode` scores the result.
"""

from __future__ import annotations

from dataclasses import dataclass

from bagport.bags import BagReader, BagWindow
from bagport.contract import ContractPlan
from bagport.episode.alignment import Alignment, align_sources
from bagport.episode.checks import check_bag_fits, check_window_has_data
from bagport.episode.replay import replayable
from bagport.episode.timeline import Timeline, scan_plan_timeline
from bagport.request import EpisodeRequest
from bagport.timewindow import WindowNs

__all__ = ["PreparedEpisode", "prepare_episode"]


@dataclass(frozen=True, slots=True)
class PreparedEpisode:
    """One episode of an open bag, scanned and aligned."""

    whole: BagReader
    """The open bag (a small one behind a :class:`~bagport.episode.replay.ReplayReader`: pass 2 replays
    pass 1's read)."""
    reader: BagReader
    """The episode's window of it (the whole bag without one)."""
    timeline: Timeline
    window_ns: WindowNs | None
    """The window's log time in the bag (``None``: the whole bag)."""
    alignment: Alignment


def prepare_episode(whole: BagReader, plan: ContractPlan, request: EpisodeRequest) -> PreparedEpisode:
    """The request's episode of an open bag, once the bag fits the contract and every stream has data
    in the window: its reader, timeline, window and alignment."""
    info = whole.info
    check_bag_fits(info, plan)
    whole = replayable(whole)
    window = request.window.resolve(info.start_ns, info.end_ns)
    reader: BagReader = whole if window is None else BagWindow(whole, *window)
    timeline = scan_plan_timeline(whole, plan, window)
    if window is not None:
        check_window_has_data(timeline, window, info.start_ns, request.bag_uri)
    return PreparedEpisode(whole, reader, timeline, window, align_sources(plan, timeline, request.bag_uri))
