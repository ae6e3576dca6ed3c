"""Score one episode: the QA checks of :mod:`bagport.qa` fed from a conversion's own data.

Stream checks use the pass-1 stamps, sync checks the per-tick selections, value checks
the frames as they stream (a :class:`~bagport.qa.ValueMonitor` in the frame callback).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from bagport.bags import BagInfo, BagReader
from bagport.contract import FeatureKind
from bagport.episode.alignment import AlignedSource, Alignment
from bagport.episode.timeline import Timeline
from bagport.qa import (
    AlignedStamps,
    CheckResult,
    EpisodeQA,
    QAConfig,
    StreamStamps,
    ValueMonitor,
    alignment_checks,
    judge,
    stream_checks,
    sync_checks,
)

__all__ = ["assess_episode", "bag_checks", "integrity_check", "safety_check", "task_check"]

Int64Array = npt.NDArray[np.int64]


def _streams(timeline: Timeline, sources: Sequence[AlignedSource]) -> list[StreamStamps]:
    by_topic: dict[str, StreamStamps] = {}
    for source in sources:
        topic = timeline.topics[source.src.stream]
        if topic.topic not in by_topic:
            log_ns, header_ns, publish_ns = topic.log_ns, topic.header_ns, topic.publish_ns
            if topic.skipped_packets is not None and header_ns is not None:
                # a video stream's packets come in decode order: judge its stamps in capture order
                order = np.argsort(header_ns, kind="stable")
                log_ns, header_ns = log_ns[order], header_ns[order]
                publish_ns = None if publish_ns is None else publish_ns[order]
            by_topic[topic.topic] = StreamStamps(
                topic.topic,
                log_ns,
                header_ns,
                source.stamp_used,
                source.kind is FeatureKind.VIDEO,
                publish_ns,
            )
    return list(by_topic.values())


def _aligned(sources: Sequence[AlignedSource]) -> list[AlignedStamps]:
    out = []
    for source in sources:
        # in grid time: a source sampled at tick + offset is compared with the tick
        stamps = source.timeline.stamps(source.stamp_used) - source.src.offset_ns
        lo = source.selection.lo
        valid = (lo >= 0) & ~source.filled
        out.append(
            AlignedStamps(
                source.src.key,
                source.src.topic,
                stamps[np.maximum(lo, 0)],
                valid,
                source.kind is FeatureKind.VIDEO,
            )
        )
    return out


def safety_check(reader: BagReader, config: QAConfig, start_ns: int, end_ns: int) -> list[CheckResult]:
    """Messages of the safety topic with their flag set inside the window (an extra pass over one topic)."""
    topic = config.safety.topic
    if topic is None:
        return []
    if reader.info.topic(topic) is None:
        return [CheckResult("safety.active", topic, 0.0, "warn", False, "the safety topic is not in the bag")]
    active, first = 0, None
    for message in reader.messages((topic,)):
        stamp = message.header_stamp_ns() or message.log_time_ns
        if start_ns <= stamp <= end_ns and bool(getattr(message.msg(), "data", False)):
            active += 1
            first = stamp if first is None else first
    where = f", first {(first - start_ns) / 1e9:.2f} s into the episode" if first is not None else ""
    return [
        judge(
            "safety.active", topic, active, config.safety.active, f"{active} safety message(s) active{where}"
        )
    ]


def task_check(config: QAConfig, tasks: Sequence[str]) -> CheckResult:
    missing = float(not any(t.strip() for t in tasks))
    reason = "no task prompt for this episode" if missing else f"{len(set(tasks))} task prompt(s)"
    return judge("content.task_missing", "episode", missing, config.content.task_missing, reason)


def integrity_check(info: BagInfo, config: QAConfig) -> list[CheckResult]:
    """A warning (soft by default) when no checksum covers the bag's bytes, naming the recorder setting."""
    if info.checksums is None:
        return []
    unchecked = float(not info.checksums.checked)
    reason = info.checksums.warning() or f"checksums verified on read: {info.checksums.detail}"
    return [judge("integrity.unchecked", "bag", unchecked, config.integrity.unchecked, reason)]


def bag_checks(
    reader: BagReader, config: QAConfig, alignment: Alignment, frame_tasks: Sequence[str]
) -> list[CheckResult]:
    """The checks of an episode beside the streamed ones, for conversion and ``bagport qa`` alike:
    the safety topic, the bag's checksums, the task prompt."""
    ticks_ns = alignment.ticks_ns
    return [
        *safety_check(reader, config, int(ticks_ns[0]), int(ticks_ns[-1])),
        *integrity_check(reader.info, config),
        task_check(config, frame_tasks),
    ]


def assess_episode(
    bag_uri: str,
    config: QAConfig,
    timeline: Timeline,
    alignment: Alignment,
    monitor: ValueMonitor,
    extra: Sequence[CheckResult],
    fps: int,
    extra_plots: dict[str, Any] | None = None,
) -> EpisodeQA:
    """Every check of one episode: its streams, the alignment, the values monitored while streaming
    and the ``extra`` checks (:func:`bag_checks`, and a conversion's video checks)."""
    sources, ticks_ns = alignment.sources, alignment.ticks_ns
    start_ns, end_ns = int(ticks_ns[0]), int(ticks_ns[-1])
    checks, plots = stream_checks(_streams(timeline, sources), start_ns, end_ns, config)
    synced, sync_plots = sync_checks(_aligned(sources), ticks_ns, config.time)
    checks += synced
    checks += alignment_checks(alignment.report, config.time)
    checks += monitor.checks()
    checks += extra
    duration_s = int(ticks_ns.size) / fps
    return EpisodeQA.build(
        bag_uri,
        checks,
        duration_s=duration_s,
        frames=int(ticks_ns.size),
        plots={
            **plots,
            **sync_plots,
            **monitor.plots(),
            "window_ns": [start_ns, end_ns],
            **(extra_plots or {}),
            "alignment": list(alignment.report),
        },
    )
