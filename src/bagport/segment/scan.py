"""Split a bag into episode requests: one cheap pass over the event, done-signal (and, for gaps,
the contract) topics; only event and done messages are deserialised."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bagport.bags import BagReader, open_bag, source_stamp
from bagport.contract import ContractPlan, parse_contract
from bagport.contract.model import EpisodesOptions
from bagport.decode import field_at
from bagport.errors import DecodeError
from bagport.request import EpisodeRequest
from bagport.segment.cache import read_segmentation, segmentation_uri, write_segmentation
from bagport.segment.events import event_from_message
from bagport.segment.windows import (
    EpisodeWindow,
    Event,
    Segmentation,
    done_edges_ns,
    drop_short,
    split_at_done,
    split_at_gaps,
    windows_from_events,
)

__all__ = ["SegmentedBag", "kept_segmentation", "segment_bag", "segment_request", "segments_bags"]


@dataclass(frozen=True, slots=True)
class SegmentedBag:
    """The episode requests of one bag, and what segmentation left out (with the reason)."""

    requests: tuple[EpisodeRequest, ...]
    ignored: tuple[str, ...] = ()
    cached: bool = False
    """Whether the segmentation came from the staging store (the bag was not read)."""

    def none_found(self) -> str:
        """The error for a bag in which no episode was found."""
        return f"no episode found in the bag ({'; '.join(self.ignored) or 'the bag is empty'})"


def segments_bags(plan: ContractPlan) -> bool:
    """Whether the contract asks for episodes inside bags (else one bag is one episode)."""
    options = plan.contract.episodes
    return options is not None and any(
        (options.events is not None, options.gap_s is not None, options.done_signal is not None)
    )


def segment_bag(reader: BagReader, options: EpisodesOptions, stream_topics: tuple[str, ...]) -> Segmentation:
    """The episode windows of an open bag under the contract's ``episodes`` options."""
    info = reader.info
    events_spec, done_spec = options.events, options.done_signal
    gap_topics = frozenset(stream_topics) if options.gap_s is not None else frozenset()
    topics = set(gap_topics)
    for spec in (events_spec, done_spec):
        if spec is not None and info.topic(spec.topic) is not None:
            topics.add(spec.topic)
    events: list[Event] = []
    unknown: list[str] = []
    done_ns: list[int] = []
    done_values: list[float] = []
    stamps: list[int] = []
    for message in reader.messages(tuple(sorted(topics))):
        t_ns = message.log_time_ns
        if message.topic in gap_topics:
            stamps.append(t_ns)
        try:
            if events_spec is not None and message.topic == events_spec.topic:
                found = event_from_message(message.msg(), t_ns, events_spec)
                if isinstance(found, Event):
                    events.append(found)
                else:
                    unknown.append(f"{(t_ns - info.start_ns) / 1e9:.3f} s: {found[:60]!r}")
            if done_spec is not None and message.topic == done_spec.topic:
                done_ns.append(t_ns)
                done_values.append(float(field_at(message.msg(), done_spec.field or "data", done_spec.topic)))
        except (DecodeError, TypeError, ValueError) as err:
            located = err if isinstance(err, DecodeError) else DecodeError(str(err), topic=message.topic)
            raise located.located(uri=info.uri, topic=message.topic, t_ns=t_ns) from err
    if events_spec is not None:
        _check_events(events, unknown, info.uri, events_spec.topic, (info.start_ns, info.end_ns))
        segmentation = windows_from_events(events, info.start_ns, info.end_ns)
    else:
        segmentation = Segmentation((EpisodeWindow(info.start_ns, info.end_ns, ended_by="bag end"),))
    if unknown:
        ignored = (*segmentation.ignored, f"{len(unknown)} message(s) naming no event, first at {unknown[0]}")
        segmentation = Segmentation(segmentation.windows, ignored)
    if options.gap_s is not None:
        segmentation = split_at_gaps(segmentation, np.asarray(stamps, dtype=np.int64), options.gap_s)
    if done_spec is not None:
        segmentation = split_at_done(segmentation, done_edges_ns(done_ns, done_values))
    return drop_short(segmentation, options.min_duration_s, info.start_ns)


_CLOCK_SLACK_NS = 60 * 1_000_000_000


def _check_events(
    events: list[Event], unknown: list[str], uri: str, topic: str, span_ns: tuple[int, int]
) -> None:
    """An event topic whose messages name no event, or events stamped on another clock than the bag's,
    would silently make one episode of the whole bag: refuse them."""
    if unknown and not events:
        raise DecodeError(
            f"none of the {len(unknown)} message(s) on the episode events topic names an event (first at "
            f"{unknown[0]})",
            uri=uri,
            topic=topic,
            fix="publish START/SUCCESS/FAIL/DISCARD/RESET as the text or under the JSON key 'event_type' "
            "(or 'event' / 'type'), or point episodes.events.field at the field holding it.",
        )
    start_ns, end_ns = span_ns
    for event in events:
        if not start_ns - _CLOCK_SLACK_NS <= event.t_ns <= end_ns + _CLOCK_SLACK_NS:
            offset_s = (event.t_ns - start_ns) / 1e9
            raise DecodeError(
                f"the {event.kind.value} event is stamped {offset_s:.1f} s from the bag's start, outside the "
                "bag: its stamp is not on the bag's clock",
                uri=uri,
                topic=topic,
                fix="set 'time: log' under episodes.events to use the bag's log time, or fix the stamps.",
            )


def segment_request(request: EpisodeRequest) -> SegmentedBag:
    """One request per episode of the request's bag; the request itself when the contract does not
    segment bags or the manifest entry gives an explicit window.

    The windows are kept in the staging store (:mod:`bagport.segment.cache`): asked again for the same
    bag files, episodes options and definitions, this returns them without opening the bag.
    """
    splitting = _splitting(request, parse_contract(request.contract_text, request.contract_name))
    if splitting is None:
        return SegmentedBag((request,))
    segmentation, cached = _cached_or_scanned(request, *splitting)
    requests = tuple(
        request.for_window(k, w.window, w.label, w.note, w.episode_id)
        for k, w in enumerate(segmentation.windows)
    )
    return SegmentedBag(requests, segmentation.ignored, cached)


def kept_segmentation(request: EpisodeRequest, plan: ContractPlan) -> str | None:
    """Where the staging store keeps the segmentation of the request's bag under ``plan`` (the request's
    contract, parsed; ``None``: it keeps none)."""
    splitting = _splitting(request, plan)
    return None if splitting is None else segmentation_uri(request, *splitting, source_stamp(request.bag_uri))


def _splitting(request: EpisodeRequest, plan: ContractPlan) -> tuple[EpisodesOptions, tuple[str, ...]] | None:
    """The contract's episodes options and stream topics, or ``None`` when the request is not split
    (the contract does not segment bags, or the manifest entry gives an explicit window)."""
    options = plan.contract.episodes
    if options is None or not segments_bags(plan) or not request.window.is_whole_bag:
        return None
    return options, tuple(dict.fromkeys(src.topic for src in plan.sources))


def _cached_or_scanned(
    request: EpisodeRequest, options: EpisodesOptions, stream_topics: tuple[str, ...]
) -> tuple[Segmentation, bool]:
    """The bag's segmentation from the staging store, else from a scan of the bag (then kept); whether
    it was kept already."""
    uri = segmentation_uri(request, options, stream_topics, source_stamp(request.bag_uri))
    kept = read_segmentation(uri) if uri is not None else None
    if kept is not None:
        return kept, True
    with open_bag(request.bag_uri, msg_definitions=request.msg_definitions) as reader:
        segmentation = segment_bag(reader, options, stream_topics)
    if uri is not None:
        write_segmentation(uri, segmentation)
    return segmentation, False
