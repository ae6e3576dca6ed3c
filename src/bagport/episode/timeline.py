"""Pass 1 over a bag: when did each contract topic publish, by header and by log time.

Only stamps are read (header stamps through the reader's fast path, without
deserialising payloads), so this pass is cheap next to decoding and encoding.
Task prompts (small strings) are collected here too.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from bagport.bags import BagMessage, BagReader
from bagport.errors import BagReadError

__all__ = ["TaskMessage", "Timeline", "TopicTimeline", "scan_timeline"]

Int64Array = npt.NDArray[np.int64]


@dataclass(frozen=True, slots=True)
class TopicTimeline:
    topic: str
    log_ns: Int64Array
    header_ns: Int64Array | None
    """``None`` when the type has no header, any stamp is zero, or the stamps never advance
    (publishers that stamp every message with one constant time)."""

    @property
    def count(self) -> int:
        return int(self.log_ns.size)

    def stamps(self, source: str) -> Int64Array:
        if source == "header":
            if self.header_ns is None:
                raise ValueError(f"{self.topic} has no usable header stamps")
            return self.header_ns
        return self.log_ns


@dataclass(frozen=True, slots=True)
class TaskMessage:
    stamp_ns: int
    text: str


@dataclass(frozen=True, slots=True)
class Timeline:
    topics: dict[str, TopicTimeline]
    tasks: tuple[TaskMessage, ...]


def _task_message(message: BagMessage) -> TaskMessage:
    stamp = message.header_stamp_ns()
    return TaskMessage(stamp if stamp else message.log_time_ns, str(message.msg().data))


def scan_timeline(
    reader: BagReader,
    topics: Iterable[str],
    task_topics: Iterable[str],
    window_ns: tuple[int, int] | None = None,
) -> Timeline:
    """Stamps of ``topics`` and the task prompts; with ``window_ns`` (log time, inclusive) only the
    messages inside it, plus the task prompts before it (a prompt holds until the next)."""
    feature_topics = tuple(topics)
    task_set = frozenset(task_topics)
    log: dict[str, list[int]] = {t: [] for t in feature_topics}
    header: dict[str, list[int | None]] = {t: [] for t in feature_topics}
    tasks: list[TaskMessage] = []
    start_ns, stop_ns = (None, None) if window_ns is None else (window_ns[0], window_ns[1] + 1)
    if start_ns is not None and task_set:
        tasks += [_task_message(m) for m in reader.messages(tuple(sorted(task_set)), stop_ns=start_ns)]
    wanted = tuple(dict.fromkeys((*feature_topics, *task_set)))
    for message in reader.messages(wanted, start_ns=start_ns, stop_ns=stop_ns):
        if message.topic in task_set:
            tasks.append(_task_message(message))
        if message.topic in log:
            log[message.topic].append(message.log_time_ns)
            header[message.topic].append(message.header_stamp_ns())
    for topic in feature_topics:
        promised = reader.info.topic(topic)
        if window_ns is None and promised is not None and promised.count != len(log[topic]):
            raise BagReadError(
                f"yielded {len(log[topic])} messages on {topic}, its index promises {promised.count}",
                uri=reader.info.uri,
                topic=topic,
                fix="the bag is truncated or its index is stale: reindex it (`ros2 bag reindex` / `rosbag reindex`).",
            )
    result: dict[str, TopicTimeline] = {}
    for topic in feature_topics:
        stamps = header[topic]
        usable = bool(stamps) and all(s is not None and s > 0 for s in stamps)
        if usable and len(stamps) > 1 and len(set(stamps)) == 1:
            usable = False
        result[topic] = TopicTimeline(
            topic=topic,
            log_ns=np.asarray(log[topic], dtype=np.int64),
            header_ns=np.asarray(stamps, dtype=np.int64) if usable else None,
        )
    return Timeline(topics=result, tasks=tuple(tasks))
