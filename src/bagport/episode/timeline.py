"""Pass 1 over a bag: when did each contract topic publish, by header and by log time.

Only stamps are read (header stamps through the reader's fast path, without
deserialising payloads), so this pass is cheap next to decoding and encoding; a
video stream's packets are deserialised to find its key frames, never decoded.
Task prompts (small strings) are collected here too.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from bagport.bags import BagMessage, BagReader
from bagport.contract import ContractPlan, FeatureKind
from bagport.contract.plan import StreamFilter
from bagport.decode.video import KeyframeGate, video_packet
from bagport.episode.samples import (
    MIXED_JOINT_LISTS_FIX,
    JointListGuard,
    SampleTest,
    mixed_joint_lists,
    sample_tests,
)
from bagport.episode.video import keyframe_before
from bagport.errors import AlignmentError, BagReadError, DecodeError
from bagport.msgtypes import VIDEO_TYPES
from bagport.timewindow import WindowNs

__all__ = ["TaskMessage", "Timeline", "TopicTimeline", "scan_plan_timeline", "scan_timeline"]

Int64Array = npt.NDArray[np.int64]


@dataclass(frozen=True, slots=True)
class TopicTimeline:
    topic: str
    log_ns: Int64Array
    header_ns: Int64Array | None
    """``None`` when the type has no header, any stamp is zero, or the stamps never advance
    (publishers that stamp every message with one constant time)."""
    publish_ns: Int64Array | None = None
    """MCAP publish times, read only for sources with ``stamp: publish``; ``None`` otherwise."""
    skipped_packets: int | None = None
    """Video streams: packets before the first key frame, not samples (``None``: not a video stream).
    Sample ``i`` is the stream's packet ``i + skipped_packets`` (counted from the window's start)."""
    preroll_ns: tuple[int, int] | None = None
    """Video streams in a window that starts inside a GOP: the log times ``[key frame, window start)``
    to decode before the window (frames dropped), so that every packet in the window decodes."""
    passed_over: int = 0
    """A filtered stream: its topic's messages that were not its samples (0: every message was one, so
    pass 2 need not ask again)."""

    @property
    def count(self) -> int:
        return int(self.log_ns.size)

    def stamps(self, source: str) -> Int64Array:
        if source == "header":
            if self.header_ns is None:
                raise ValueError(f"{self.topic} has no usable header stamps")
            return self.header_ns
        if source == "publish":
            if self.publish_ns is None:
                raise ValueError(f"{self.topic} has no publish times")
            return self.publish_ns
        return self.log_ns


@dataclass(frozen=True, slots=True)
class TaskMessage:
    stamp_ns: int
    text: str


@dataclass(frozen=True, slots=True)
class Timeline:
    topics: dict[str, TopicTimeline]
    tasks: tuple[TaskMessage, ...]


def _publish_times(
    reader: BagReader,
    log: dict[str, list[int]],
    streams: Mapping[str, str],
    samples: Mapping[str, list[int]],
    window: tuple[int | None, int | None],
    skipped: Mapping[str, int],
) -> dict[str, Int64Array]:
    """MCAP publish times of ``streams`` (a stream -> its topic) logged in the ``window`` ``[start, stop)``
    (minus a video stream's ``skipped`` packets before its first key frame; a filtered stream's are its
    ``samples``' positions in its topic), checked message by message against the log times read."""
    out: dict[str, Int64Array] = {}
    start_ns, stop_ns = window
    by_topic = reader.publish_times_ns(tuple(dict.fromkeys(streams.values())))
    for stream, topic in streams.items():
        if topic not in by_topic:  # no publish times in this bag: the alignment says so
            continue
        all_log_ns, all_publish_ns = by_topic[topic]
        inside = np.ones(all_log_ns.shape, dtype=bool)
        if start_ns is not None:
            inside &= all_log_ns >= start_ns
        if stop_ns is not None:
            inside &= all_log_ns < stop_ns
        first = skipped.get(topic, 0)
        log_ns, publish_ns = all_log_ns[inside][first:], all_publish_ns[inside][first:]
        if stream in samples:
            positions = np.asarray(samples[stream], dtype=np.intp)
            positions = positions[positions < log_ns.size]  # a missing one: the lengths differ below
            log_ns, publish_ns = log_ns[positions], publish_ns[positions]
        if not np.array_equal(log_ns, np.asarray(log[stream], dtype=np.int64)):
            raise BagReadError(
                "the publish times read with the mcap library do not line up with the log times",
                uri=reader.info.uri,
                topic=topic,
                fix="use 'align: {stamp: receive}' or 'stamp: header' for this topic.",
            )
        out[stream] = publish_ns
    return out


def _task_message(message: BagMessage) -> TaskMessage:
    stamp = message.header_stamp_ns()
    return TaskMessage(stamp if stamp else message.log_time_ns, str(message.msg().data))


def _video_gates(
    reader: BagReader, topics: Iterable[str], window_ns: WindowNs | None
) -> tuple[dict[str, KeyframeGate], dict[str, tuple[int, int]]]:
    """A key-frame gate per video topic, open from the start when a key frame precedes the window."""
    gates, prerolls = {}, {}
    for topic in topics:
        key_ns = None if window_ns is None else keyframe_before(reader, topic, window_ns[0])
        gates[topic] = KeyframeGate(started=key_ns is not None)
        if key_ns is not None and window_ns is not None:
            prerolls[topic] = (key_ns, window_ns[0])
    return gates, prerolls


def _admitted(message: BagMessage, gate: KeyframeGate, uri: str) -> bool:
    try:
        return gate.admit(video_packet(message.msg(), message.msgtype))
    except DecodeError as err:
        raise err.located(uri=uri, topic=message.topic, t_ns=message.log_time_ns) from err


def _check_samples_found(
    uri: str,
    gates: Mapping[str, KeyframeGate],
    tests: Mapping[str, SampleTest],
    log: Mapping[str, list[int]],
    window_ns: WindowNs | None,
    entries: Mapping[str, str],
    passed_over: Mapping[str, int],
) -> None:
    """Every video stream has a key frame, every filtered stream a message that is its sample."""
    for topic, gate in gates.items():
        if gate.skipped and not log[topic]:
            raise AlignmentError(
                f"none of the {gate.skipped} video packets on {topic}"
                + ("" if window_ns is None else " in the episode window or before it")
                + " is a key frame, so no frame can be decoded",
                uri=uri,
                topic=topic,
                fix="record the camera with periodic key frames (the encoder's GOP / keyint setting), "
                "or leave the topic out of the contract.",
            )
    for stream, test in tests.items():
        # no message of the topic at all is not the filter's to say: the window's or the bag's checks say it
        if stream in log and not log[stream] and passed_over.get(stream):
            entry = f" ({entries[stream]})" if stream in entries else ""
            raise AlignmentError(
                f"no message on {test.spec.topic} carries {test.wanted()} ({test.seen_text()}){entry}",
                uri=uri,
                topic=test.spec.topic,
                fix=test.fix(),
            )


def _topic_timeline(
    topic: str,
    log_ns: list[int],
    stamps: list[int | None],
    publish_ns: Int64Array | None,
    gate: KeyframeGate | None,
    preroll_ns: tuple[int, int] | None,
) -> TopicTimeline:
    """One stream's timeline; its header stamps only when all are set and they advance."""
    usable = bool(stamps) and all(s is not None and s > 0 for s in stamps)
    if usable and len(stamps) > 1 and len(set(stamps)) == 1:
        usable = False
    return TopicTimeline(
        topic=topic,
        log_ns=np.asarray(log_ns, dtype=np.int64),
        header_ns=np.asarray(stamps, dtype=np.int64) if usable else None,
        publish_ns=publish_ns,
        skipped_packets=gate.skipped if gate is not None else None,
        preroll_ns=preroll_ns,
    )


class _Streams:
    """Pass 1's record of every stream: log and header stamps of its samples, how many messages of its topic a
    filtered stream passed over, and a filtered stream's samples' positions in its topic (for publish times)."""

    def __init__(
        self, streams: tuple[str, ...], tests: Mapping[str, SampleTest], publish: Iterable[str]
    ) -> None:
        self.tests = tests
        self.log: dict[str, list[int]] = {s: [] for s in streams}
        self.header: dict[str, list[int | None]] = {s: [] for s in streams}
        self.topic_of = {s: tests[s].spec.topic if s in tests else s for s in streams}
        self.by_topic: dict[str, list[str]] = {}
        for stream in streams:
            self.by_topic.setdefault(self.topic_of[stream], []).append(stream)
        self.publish = {stream: self.topic_of[stream] for stream in dict.fromkeys(publish)}
        self.positions: dict[str, list[int]] = {s: [] for s in self.publish if s in tests}
        self.passed_over = dict.fromkeys(tests, 0)
        self._counted = dict.fromkeys((self.topic_of[s] for s in self.positions), 0)

    def take(self, message: BagMessage) -> None:
        for stream in self.by_topic.get(message.topic, ()):
            test = self.tests.get(stream)
            if test is None:
                stamp_ns = message.header_stamp_ns()
            elif test.carries(message):
                stamp_ns = test.stamp_ns(message)
                if stream in self.positions:
                    self.positions[stream].append(self._counted[message.topic])
            else:
                self.passed_over[stream] += 1
                continue
            self.log[stream].append(message.log_time_ns)
            self.header[stream].append(stamp_ns)
        if message.topic in self._counted:
            self._counted[message.topic] += 1


def _check_joint_list(
    guards: Mapping[str, JointListGuard], entries: Mapping[str, str], message: BagMessage, uri: str
) -> None:
    """Refuse a JointState topic read by index whose messages name different joints."""
    guard = guards.get(message.topic)
    if guard is not None and (lists := guard.other_list(message)) is not None:
        raise AlignmentError(
            mixed_joint_lists(message.topic, *lists, entries[message.topic]),
            uri=uri,
            topic=message.topic,
            fix=MIXED_JOINT_LISTS_FIX,
        )


def scan_timeline(
    reader: BagReader,
    topics: Iterable[str],
    task_topics: Iterable[str],
    filters: Mapping[str, StreamFilter] | None = None,
    publish_topics: Iterable[str] = (),
    window_ns: WindowNs | None = None,
    video_topics: Iterable[str] = (),
    entries: Mapping[str, str] | None = None,
    one_joint_lists: Mapping[str, str] | None = None,
) -> Timeline:
    """Stamps of every stream; ``topics`` are stream names (see ``SourceSpec.stream``): a topic, or a
    name in ``filters`` whose samples are only some messages of its topic (:mod:`bagport.episode.samples`).
    MCAP publish times too for the streams in ``publish_topics`` (``stamp: publish``).
    The samples of ``video_topics`` are their packets from a key frame on (:mod:`bagport.episode.video`).
    ``entries`` names the contract entry of a filtered stream in its error when no message is its sample;
    ``one_joint_lists`` (a topic -> its entry) are JointState topics read by index, whose messages must all
    name the same joints (:class:`JointListGuard`).
    With ``window_ns`` (log time, inclusive) only the messages inside it, plus the task prompts
    before it (a prompt holds until the next). The reader checks the counts against the bag's index."""
    feature_topics = tuple(topics)
    streams = _Streams(feature_topics, sample_tests(dict(filters or {})), publish_topics)
    task_set = frozenset(task_topics)
    tasks: list[TaskMessage] = []
    start_ns, stop_ns = (None, None) if window_ns is None else (window_ns[0], window_ns[1] + 1)
    if start_ns is not None and task_set:
        tasks += [_task_message(m) for m in reader.messages(tuple(sorted(task_set)), stop_ns=start_ns)]
    gates, prerolls = _video_gates(reader, dict.fromkeys(video_topics), window_ns)
    wanted = tuple(dict.fromkeys((*streams.by_topic, *task_set)))
    one_joint_lists = one_joint_lists or {}
    guards = {topic: JointListGuard() for topic in one_joint_lists}
    for message in reader.messages(wanted, start_ns=start_ns, stop_ns=stop_ns):
        if message.topic in task_set:
            tasks.append(_task_message(message))
        _check_joint_list(guards, one_joint_lists, message, reader.info.uri)
        gate = gates.get(message.topic)
        if gate is None or _admitted(message, gate, reader.info.uri):
            streams.take(message)
    log = streams.log
    _check_samples_found(
        reader.info.uri, gates, streams.tests, log, window_ns, entries or {}, streams.passed_over
    )
    skipped = {topic: gate.skipped for topic, gate in gates.items()}
    publish_ns = _publish_times(reader, log, streams.publish, streams.positions, (start_ns, stop_ns), skipped)
    result = {
        topic: _topic_timeline(
            topic,
            log[topic],
            streams.header[topic],
            publish_ns.get(topic),
            gates.get(topic),
            prerolls.get(topic),
        )
        for topic in feature_topics
    }
    for stream, count in streams.passed_over.items():
        if stream in result:
            result[stream] = replace(result[stream], passed_over=count)
    return Timeline(topics=result, tasks=tuple(tasks))


def scan_plan_timeline(reader: BagReader, plan: ContractPlan, window_ns: WindowNs | None = None) -> Timeline:
    """:func:`scan_timeline` of every topic a contract reads (publish times where it asks for them)."""
    return scan_timeline(
        reader,
        plan.streams(),
        [t.topic for t in plan.task_topics],
        plan.stream_filters(),
        [s.stream for s in plan.sources if s.stamp == "publish"],
        window_ns,
        [
            s.topic
            for f in plan.features
            if f.kind is FeatureKind.VIDEO
            for s in f.sources
            if s.msgtype in VIDEO_TYPES
        ],
        {s.stream: s.entry_text(plan.source_name) for s in reversed(plan.sources) if s.stream_filter},
        {topic: src.entry_text(plan.source_name) for topic, src in plan.one_joint_list_topics().items()},
    )
