"""Episodes inside a bag: from an event topic, time gaps, a done signal (pure windows + one cheap scan)."""

from __future__ import annotations

from bagport.segment.check import check_episode_topics
from bagport.segment.events import event_from_message, parse_event_text
from bagport.segment.scan import SegmentedBag, kept_segmentation, segment_bag, segment_request, segments_bags
from bagport.segment.windows import (
    EXCLUDED_LABELS,
    EpisodeWindow,
    Event,
    EventKind,
    Segmentation,
    done_edges_ns,
    drop_short,
    label_reason,
    split_at_done,
    split_at_gaps,
    windows_from_events,
)

__all__ = [
    "EXCLUDED_LABELS",
    "EpisodeWindow",
    "Event",
    "EventKind",
    "SegmentedBag",
    "Segmentation",
    "check_episode_topics",
    "done_edges_ns",
    "drop_short",
    "event_from_message",
    "kept_segmentation",
    "label_reason",
    "parse_event_text",
    "segment_bag",
    "segment_request",
    "segments_bags",
    "split_at_done",
    "split_at_gaps",
    "windows_from_events",
]
