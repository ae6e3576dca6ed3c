"""Pass 2: stream the bag once and emit aligned frames in order.

Which message feeds which tick is decided beforehand from the timeline (pure
index arrays).  While streaming, only the selected messages are deserialised and
decoded, kept until the last tick that uses them, then dropped: memory is bounded
by the arrival skew between topics, not by episode length.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from bagport.align import QuaternionGroup, Selection, blend, quaternion_groups
from bagport.bags import BagMessage, BagReader
from bagport.contract.plan import FeatureKind, FeatureSpec, SourceSpec
from bagport.decode import (
    VectorExtractor,
    decode_image,
    find_transform,
    is_depth,
    make_extractor,
    resize_image,
)
from bagport.episode.timeline import TopicTimeline
from bagport.episode.video import VideoFeed
from bagport.errors import AlignmentError, DecodeError
from bagport.msgtypes import VIDEO_TYPES

__all__ = ["AlignedSource", "Frame", "assemble_frames"]

Int64Array = npt.NDArray[np.int64]


@dataclass(slots=True)
class AlignedSource:
    """One contract source with its per-tick message selection."""

    src: SourceSpec
    kind: FeatureKind
    timeline: TopicTimeline
    stamp_used: str
    selection: Selection
    filled: npt.NDArray[np.bool_]
    """Ticks whose value comes from ``align.fill`` (held past a gap, or zeros)."""
    extractor: VectorExtractor | None = None
    quaternions: tuple[QuaternionGroup, ...] = ()
    """``x, y, z, w`` index groups of the extractor's names: slerped, not blended linearly."""
    cache: dict[int, Any] = field(default_factory=dict)
    last_use: dict[int, int] = field(default_factory=dict)
    needed: npt.NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, dtype=np.bool_))
    required: Int64Array = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    depth: bool = False
    """A camera whose messages decoded as depth maps (its zeros fill is then invalid depth)."""
    video: VideoFeed | None = None
    """The decoder of a camera recorded as a video stream (pass 2)."""

    def prepare(self) -> None:
        self.needed = np.zeros(self.timeline.count, dtype=np.bool_)
        lo, hi = self.selection.lo, self.selection.hi
        self.needed[lo[lo >= 0]] = True
        self.required = lo.copy()
        for k, index in enumerate(lo.tolist()):
            if index >= 0:
                self.last_use[index] = k
        if hi is not None:
            self.needed[hi[hi >= 0]] = True
            self.required = np.maximum(lo, hi)
            for k, index in enumerate(hi.tolist()):
                if index >= 0:
                    self.last_use[index] = max(k, self.last_use.get(index, k))

    def value(self, k: int) -> Any:
        lo = int(self.selection.lo[k])
        if lo < 0:  # fill: zeros, checked against the contract beforehand
            return self._zeros()
        value = self.cache[lo]
        if self.selection.hi is not None and self.selection.weight is not None:
            weight = float(self.selection.weight[k])
            if weight > 0:
                value = blend(value, self.cache[int(self.selection.hi[k])], weight, self.quaternions)
        return value

    def _zeros(self) -> Any:
        if self.kind is FeatureKind.VIDEO and self.src.resize_hw is not None:
            if self.depth:
                return np.full(self.src.resize_hw, np.nan, dtype=np.float32)
            return np.zeros((*self.src.resize_hw, 3), dtype=np.uint8)
        return np.zeros(max(1, len(self.src.names)), dtype=np.float64)


@dataclass(frozen=True, slots=True)
class Frame:
    index: int
    tick_ns: int
    vectors: dict[str, npt.NDArray[np.float64]]
    images: dict[str, npt.NDArray[Any]]
    """RGB uint8 (H, W, 3), or depth float32 (H, W) metres with NaN for invalid."""


def _decode(source: AlignedSource, message: BagMessage) -> Any:
    msg = message.msg()
    if source.kind is FeatureKind.VIDEO:
        image = decode_image(msg, source.src.msgtype)
        source.depth = is_depth(image)
        if source.src.resize_hw is not None:
            image = resize_image(image, *source.src.resize_hw)
        return image
    if source.extractor is None:
        source.extractor = make_extractor(source.src, msg)
        source.quaternions = quaternion_groups(source.extractor.names)
    return source.extractor(msg)


def _start_video(source: AlignedSource, whole: BagReader, uri: str, contract_name: str) -> None:
    """A video camera's decoder, run over the packets from the key frame before the window first."""
    preroll = source.timeline.preroll_ns
    messages = None
    if preroll is not None:
        messages = whole.messages([source.src.topic], start_ns=preroll[0], stop_ns=preroll[1])
    try:
        source.video = VideoFeed(source.needed, source.src.resize_hw, messages)
    except DecodeError as err:
        raise _at_entry(
            err.located(uri=uri, topic=source.src.topic, t_ns=0), source.src, contract_name
        ) from err


def _push_video(
    stream_sources: Sequence[AlignedSource], message: BagMessage | None, uri: str, contract_name: str
) -> int:
    """Feed one packet (``None``: the end of the stream) to each video source of a stream; returns
    how far the stream has arrived (its first unresolved sample)."""
    feeds = [(source, source.video) for source in stream_sources if source.video is not None]
    for source, feed in feeds:
        try:
            frames = feed.finish() if message is None else feed.push(message)
        except DecodeError as err:
            t_ns = 0 if message is None else message.log_time_ns
            located = err.located(uri=uri, topic=source.src.topic, t_ns=t_ns)
            raise _at_entry(located, source.src, contract_name) from err
        for sample, image in frames:
            source.cache[sample] = image
    return min(feed.watermark for _, feed in feeds)


def assemble_frames(
    reader: BagReader,
    uri: str,
    features: Sequence[FeatureSpec],
    sources: Sequence[AlignedSource],
    ticks_ns: Int64Array,
    on_frame: Callable[[Frame], None],
    contract_name: str = "contract",
    whole: BagReader | None = None,
) -> int:
    """Stream ``reader`` and call ``on_frame`` for every tick, in order; returns frames emitted.

    A message that cannot be decoded raises a :class:`DecodeError` naming the bag, topic, time and
    the contract entry (``contract_name:line``) that reads it. ``whole`` is the bag ``reader`` is a
    window of: video streams decode from the key frame before the window.
    """
    by_topic: dict[str, dict[str, list[AlignedSource]]] = {}
    video_streams: set[str] = set()
    for source in sources:
        source.prepare()
        by_topic.setdefault(source.src.topic, {}).setdefault(source.src.stream, []).append(source)
        if source.kind is FeatureKind.VIDEO and source.src.msgtype in VIDEO_TYPES:
            _start_video(source, whole or reader, uri, contract_name)
            video_streams.add(source.src.stream)
    filters = {s.src.stream: f for s in sources if (f := s.src.stream_filter) is not None}
    arrived = {stream: 0 for streams in by_topic.values() for stream in streams}
    total = int(ticks_ns.size)
    next_tick = 0
    by_key = {f.key: [s for s in sources if s.src.key == f.key] for f in features}

    def ready(k: int) -> bool:
        return all(arrived[s.src.stream] > s.required[k] for s in sources)

    def emit_ready() -> None:
        nonlocal next_tick
        while next_tick < total and ready(next_tick):
            on_frame(_frame(next_tick, int(ticks_ns[next_tick]), features, by_key))
            _release(sources, next_tick)
            next_tick += 1

    emit_ready()  # ticks made only of fills need no message
    for message in reader.messages(tuple(by_topic)):
        wanted = False
        for stream, stream_sources in by_topic[message.topic].items():
            if stream in video_streams:
                arrived[stream] = _push_video(stream_sources, message, uri, contract_name)
                wanted = True
                continue
            spec = filters.get(stream)
            if (
                spec is not None
                and find_transform(message.msg(), spec.child_frame, spec.parent_frame) is None
            ):
                continue  # the same test as the timeline's: this message is no sample of the stream
            index = arrived[stream]
            arrived[stream] = index + 1
            for source in stream_sources:
                if index < source.needed.size and source.needed[index]:
                    wanted = True
                    try:
                        source.cache[index] = _decode(source, message)
                    except DecodeError as err:
                        located = err.located(uri=uri, topic=message.topic, t_ns=message.log_time_ns)
                        raise _at_entry(located, source.src, contract_name) from err
        if wanted:
            emit_ready()
        if next_tick == total:
            break
    if next_tick < total and video_streams:  # the frames still inside the decoders
        for stream in video_streams:
            arrived[stream] = _push_video(_stream_sources(by_topic, stream), None, uri, contract_name)
        emit_ready()
    if next_tick < total:
        raise AlignmentError(
            f"the bag ended after {next_tick} of {total} frames: messages seen in the first pass were missing "
            "in the second",
            uri=uri,
            fix="the bag changed while it was read, or it is corrupt; re-run, or reindex the bag.",
        )
    return total


def _stream_sources(by_topic: dict[str, dict[str, list[AlignedSource]]], stream: str) -> list[AlignedSource]:
    return next(streams[stream] for streams in by_topic.values() if stream in streams)


def _at_entry(err: DecodeError, src: SourceSpec, contract_name: str) -> DecodeError:
    """The error naming the contract entry whose selector or decoder met the message."""
    entry = f"{src.where(contract_name)}, {src.section}[key={src.key}]"
    return DecodeError(f"{err.what} ({entry})", uri=err.uri, topic=err.topic, t_ns=err.t_ns, fix=err.fix)


def _frame(
    k: int,
    tick_ns: int,
    features: Sequence[FeatureSpec],
    by_key: dict[str, list[AlignedSource]],
) -> Frame:
    vectors: dict[str, npt.NDArray[np.float64]] = {}
    images: dict[str, npt.NDArray[Any]] = {}
    for feature in features:
        parts = [source.value(k) for source in by_key[feature.key]]
        if feature.kind is FeatureKind.VIDEO:
            images[feature.key] = parts[0]
        else:
            vectors[feature.key] = parts[0] if len(parts) == 1 else np.concatenate(parts)
    return Frame(k, tick_ns, vectors, images)


def _release(sources: Sequence[AlignedSource], k: int) -> None:
    for source in sources:
        for array in (source.selection.lo, source.selection.hi):
            if array is None:
                continue
            index = int(array[k])
            if index >= 0 and source.last_use.get(index) == k:
                source.cache.pop(index, None)
