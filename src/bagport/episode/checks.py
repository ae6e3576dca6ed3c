"""Checks of a bag against a contract, before any work starts."""

from __future__ import annotations

import hashlib

from bagport.bags import BagInfo
from bagport.contract import ContractPlan, normalize_msgtype
from bagport.episode.timeline import Timeline
from bagport.errors import AlignmentError, ContractError
from bagport.timewindow import WindowNs

__all__ = ["bag_fingerprint", "check_bag_fits", "check_window_has_data"]


def check_bag_fits(info: BagInfo, plan: ContractPlan) -> None:
    """Every contract topic exists in the bag, has messages, and has the declared type."""
    available = {t.name: t for t in info.topics}
    wanted: list[tuple[str, str, str, int | None]] = [
        (s.topic, s.msgtype, s.key, s.line) for s in plan.sources
    ]
    wanted += [(t.topic, t.type, t.key, None) for t in plan.task_topics]
    if not info.topics:
        raise ContractError(
            f"bag {info.uri} holds no messages (no topics), so nothing can be converted",
            file=plan.source_name,
            fix="check the recording (a recorder that subscribed to nothing writes an empty bag), "
            "or remove this bag from the manifest.",
        )
    for topic, msgtype, key, line in wanted:
        found = available.get(topic)
        if found is None:
            listing = ", ".join(f"{t.name} ({t.msgtype})" for t in info.topics) or "none"
            raise ContractError(
                f"topic {topic} (for {key!r}) is not in bag {info.uri}; the bag has: {listing}",
                file=plan.source_name,
                line=line,
                field=key,
                fix="fix the topic name in the contract, or remove this bag from the manifest.",
            )
        if normalize_msgtype(found.msgtype) != msgtype:
            raise ContractError(
                f"topic {topic} in bag {info.uri} has type {found.msgtype}, the contract says {msgtype}",
                file=plan.source_name,
                line=line,
                field=f"{key}.type",
                fix=f"set 'type: {found.msgtype}' for this entry, or map the right topic.",
            )
    for source in plan.sources:
        if available[source.topic].count == 0:
            raise AlignmentError(
                f"topic {source.topic} (for {source.key!r}) has no messages",
                uri=info.uri,
                fix="record the topic, or drop this bag from the manifest.",
            )


def check_window_has_data(timeline: Timeline, window_ns: WindowNs, bag_start_ns: int, uri: str) -> None:
    """Every contract stream has messages inside an episode window."""
    start_s, end_s = ((t - bag_start_ns) / 1e9 for t in window_ns)
    for topic in timeline.topics.values():
        if topic.count == 0:
            raise AlignmentError(
                f"topic {topic.topic} has no messages in the episode window {start_s:.3f}..{end_s:.3f} s "
                "(from the bag start)",
                uri=uri,
                topic=topic.topic,
                fix="check the window (manifest start_s/end_s or start_ns/end_ns, or the episode events).",
            )


def bag_fingerprint(info: BagInfo) -> str:
    """A cheap fingerprint from the bag's index: files, sizes, counts and time range.

    It changes when a bag is re-recorded, re-split or truncated; it does not hash
    the payload bytes (that would cost a full read of multi-GB files).
    """
    digest = hashlib.sha256()
    start_ns, end_ns = info.listed_span_ns or (info.start_ns, info.end_ns)
    parts = [info.storage, *info.files, str(info.size_bytes), str(start_ns), str(end_ns)]
    parts += [f"{t.name}:{t.msgtype}:{t.count}" for t in sorted(info.topics, key=lambda t: t.name)]
    for part in parts:
        digest.update(part.encode())
        digest.update(b"\0")
    return "sha256-index:" + digest.hexdigest()[:32]
