"""Pass 2: stream the bag once and yield aligned frames in order (:func:`iter_frames`).

Which message feeds which tick is decided beforehand from the timeline (pure index arrays,
:class:`~bagport.episode.alignment.Alignment`).  While streaming, only the selected messages are
deserialised and decoded, kept until the last tick that uses them, then dropped: memory is bounded
by the arrival skew between topics, not by episode length. That state lives here and nowhere else.

A camera's :class:`~bagport.decode.ImageKind` (colour or depth) is decided once: from the contract
for a video stream (always colour), else from its first decoded message; a later message of the
other kind is an error, and a zeros fill before the first message waits for it to know its kind.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from bagport.align import QuaternionGroup, blend, quaternion_groups
from bagport.bags import BagMessage, BagReader
from bagport.contract.plan import FeatureKind, FeatureSpec
from bagport.decode import (
    ImageKind,
    VectorExtractor,
    decode_image,
    make_extractor,
    resize_image,
)
from bagport.decode.joint_state_cdr import JointStateCdr, joint_state_reader
from bagport.episode.alignment import AlignedSource
from bagport.episode.samples import sample_tests
from bagport.episode.video import VideoFeed
from bagport.errors import AlignmentError, DecodeError
from bagport.msgtypes import VIDEO_TYPES

__all__ = ["Frame", "iter_frames"]

Int64Array = npt.NDArray[np.int64]


@dataclass(frozen=True, slots=True)
class Frame:
    index: int
    tick_ns: int
    vectors: dict[str, npt.NDArray[np.float64]]
    images: dict[str, npt.NDArray[Any]]
    """RGB uint8 (H, W, 3), or depth float32 (H, W) metres with NaN for invalid: see ``kinds``."""
    kinds: Mapping[str, ImageKind] = field(default_factory=dict)
    """Each camera's kind, decided once (see the module docstring)."""
    names: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    """Each vector's dimension names, from the extractors its sources' first messages built so far."""


class _SourceStream:
    """One aligned source while it streams: the decoded messages some tick still needs, the
    extractor or decoder built from its first message, and its camera's kind."""

    def __init__(self, source: AlignedSource) -> None:
        self.source = source
        self.src = source.src
        self.cache: dict[int, Any] = {}
        self.last_use: dict[int, int] = {}
        self.extractor: VectorExtractor | None = None
        self.joint_states: JointStateCdr | None = None
        """Reads further JointState messages from their bytes (:mod:`bagport.decode.joint_state_cdr`)."""
        self.quaternions: tuple[QuaternionGroup, ...] = ()
        """``x, y, z, w`` index groups of the extractor's names: slerped, not blended linearly."""
        self.video: VideoFeed | None = None
        """The decoder of a camera recorded as a video stream."""
        self.image_kind: ImageKind | None = None
        lo, hi = source.selection.lo, source.selection.hi
        self.needed = np.zeros(source.timeline.count, dtype=np.bool_)
        self.needed[lo[lo >= 0]] = True
        self.required: Int64Array = lo.copy()
        for k, index in enumerate(lo.tolist()):
            if index >= 0:
                self.last_use[index] = k
        if hi is not None:
            self.needed[hi[hi >= 0]] = True
            self.required = np.maximum(lo, hi)
            for k, index in enumerate(hi.tolist()):
                if index >= 0:
                    self.last_use[index] = max(k, self.last_use.get(index, k))
        if source.kind is FeatureKind.VIDEO:
            self._decide_kind_early()

    @property
    def stream(self) -> str:
        return self.src.stream

    def _decide_kind_early(self) -> None:
        if self.src.msgtype in VIDEO_TYPES:
            self.image_kind = ImageKind.COLOUR  # a video stream decodes to RGB
            return
        first = np.flatnonzero(self.needed)
        if first.size:  # fill ticks wait for the first message, which tells colour from depth
            self.required = np.where(
                self.source.selection.lo < 0, np.maximum(self.required, first[0]), self.required
            )

    def decided(self, kind: ImageKind) -> None:
        """The kind of a decoded message: the first decides, a later one must agree."""
        if self.image_kind is None:
            self.image_kind = kind
        elif kind is not self.image_kind:
            raise DecodeError(
                f"{self.src.key}: this message decodes as a {kind.value} image, the messages before "
                f"were {self.image_kind.value}",
                fix="map depth and colour topics to different keys.",
            )

    def value(self, k: int) -> Any:
        selection = self.source.selection
        lo = int(selection.lo[k])
        if lo < 0:  # fill: zeros, checked against the contract beforehand
            return self._zeros()
        value = self.cache[lo]
        if selection.hi is not None and selection.weight is not None:
            weight = float(selection.weight[k])
            if weight > 0:
                value = blend(value, self.cache[int(selection.hi[k])], weight, self.quaternions)
        return value

    def _zeros(self) -> Any:
        if self.source.kind is FeatureKind.VIDEO and self.src.resize_hw is not None:
            if self.image_kind is ImageKind.DEPTH:
                return np.full(self.src.resize_hw, np.nan, dtype=np.float32)
            return np.zeros((*self.src.resize_hw, 3), dtype=np.uint8)
        return np.zeros(max(1, len(self.src.names)), dtype=np.float64)

    def release(self, k: int) -> None:
        """Drop the messages whose last tick was ``k``."""
        for array in (self.source.selection.lo, self.source.selection.hi):
            if array is None:
                continue
            index = int(array[k])
            if index >= 0 and self.last_use.get(index) == k:
                self.cache.pop(index, None)


def _decode(source: _SourceStream, message: BagMessage) -> Any:
    if source.joint_states is not None and source.extractor is not None:
        cdr = message.cdr
        arrays = source.joint_states.read(cdr) if cdr is not None else None
        if arrays is not None:
            return source.extractor(arrays)
    msg = message.msg()
    if source.source.kind is FeatureKind.VIDEO:
        image = decode_image(msg, source.src.msgtype)
        source.decided(ImageKind.of(image))
        if source.src.resize_hw is not None:
            image = resize_image(image, *source.src.resize_hw)
        return image
    if source.extractor is None:
        source.extractor = make_extractor(source.src, msg)
        source.quaternions = quaternion_groups(source.extractor.names)
        source.joint_states = joint_state_reader(source.src, source.extractor, message.cdr, msg)
    return source.extractor(msg)


class _Streaming:
    """The state of one pass 2: which streams arrived how far, and the next tick to emit."""

    def __init__(
        self,
        features: Sequence[FeatureSpec],
        sources: Sequence[AlignedSource],
        ticks_ns: Int64Array,
        uri: str,
        contract_name: str,
    ) -> None:
        self.uri, self.contract_name, self.ticks_ns = uri, contract_name, ticks_ns
        self.streams = [_SourceStream(source) for source in sources]
        self.by_topic: dict[str, dict[str, list[_SourceStream]]] = {}
        for stream in self.streams:
            self.by_topic.setdefault(stream.src.topic, {}).setdefault(stream.stream, []).append(stream)
        self.video_streams = {
            s.stream
            for s in self.streams
            if s.source.kind is FeatureKind.VIDEO and s.src.msgtype in VIDEO_TYPES
        }
        self.filters = sample_tests(  # only where pass 1 found messages of the topic that are not samples
            {
                s.stream: f
                for s in self.streams
                if (f := s.src.stream_filter) and s.source.timeline.passed_over
            }
        )
        self.arrived = {stream: 0 for streams in self.by_topic.values() for stream in streams}
        self.by_key = {f.key: [s for s in self.streams if s.src.key == f.key] for f in features}
        self.features = features
        self.next_tick = 0
        self.names: dict[str, tuple[str, ...]] = {}
        """Replaced (never changed) when an extractor is built: each frame keeps the one of its time."""

    @property
    def done(self) -> bool:
        return self.next_tick == int(self.ticks_ns.size)

    def start_video(self, whole: BagReader) -> None:
        """Each video camera's decoder, run over the packets from the key frame before the window first."""
        for stream in self.streams:
            if stream.stream not in self.video_streams:
                continue
            preroll = stream.source.timeline.preroll_ns
            messages = None
            if preroll is not None:
                messages = whole.messages([stream.src.topic], start_ns=preroll[0], stop_ns=preroll[1])
            try:
                stream.video = VideoFeed(stream.needed, stream.src.resize_hw, messages)
            except DecodeError as err:
                located = err.located(uri=self.uri, topic=stream.src.topic, t_ns=0)
                raise located.at_entry(stream.src.entry_text(self.contract_name)) from err

    def ready_frames(self) -> Iterator[Frame]:
        """The frames every source has delivered for, in order."""
        total = int(self.ticks_ns.size)
        while self.next_tick < total and all(
            self.arrived[s.stream] > s.required[self.next_tick] for s in self.streams
        ):
            k = self.next_tick
            frame = self._frame(k)
            for stream in self.streams:
                stream.release(k)
            self.next_tick += 1
            yield frame

    def _frame(self, k: int) -> Frame:
        vectors: dict[str, npt.NDArray[np.float64]] = {}
        images: dict[str, npt.NDArray[Any]] = {}
        kinds: dict[str, ImageKind] = {}
        for feature in self.features:
            streams = self.by_key[feature.key]
            parts = [stream.value(k) for stream in streams]
            if feature.kind is FeatureKind.VIDEO:
                images[feature.key] = parts[0]
                kinds[feature.key] = streams[0].image_kind or ImageKind.COLOUR
            else:
                vectors[feature.key] = parts[0] if len(parts) == 1 else np.concatenate(parts)
        return Frame(k, int(self.ticks_ns[k]), vectors, images, kinds, self.names)

    def take(self, message: BagMessage) -> bool:
        """Count and decode one message for every stream that wants it; whether any did."""
        wanted = False
        for stream, streams in self.by_topic[message.topic].items():
            if stream in self.video_streams:
                self.arrived[stream] = self._push_video(streams, message)
                wanted = True
                continue
            test = self.filters.get(stream)
            if test is not None and not test.carries(message):
                continue  # the same test as the timeline's: this message is no sample of the stream
            index = self.arrived[stream]
            self.arrived[stream] = index + 1
            for source in streams:
                if index < source.needed.size and source.needed[index]:
                    wanted = True
                    had_extractor = source.extractor is not None
                    try:
                        source.cache[index] = _decode(source, message)
                    except DecodeError as err:
                        located = err.located(uri=self.uri, topic=message.topic, t_ns=message.log_time_ns)
                        raise located.at_entry(source.src.entry_text(self.contract_name)) from err
                    if not had_extractor and source.extractor is not None:
                        self._name(source.src.key)
        return wanted

    def _name(self, key: str) -> None:
        streams = self.by_key.get(key, ())
        names = tuple(n for s in streams for n in (s.extractor.names if s.extractor else ()))
        self.names = {**self.names, key: names}

    def finish_video(self) -> None:
        """The frames still inside the video decoders, at the end of the bag."""
        for streams in self.by_topic.values():
            for stream, video_sources in streams.items():
                if stream in self.video_streams:
                    self.arrived[stream] = self._push_video(video_sources, None)

    def _push_video(self, streams: Sequence[_SourceStream], message: BagMessage | None) -> int:
        """Feed one packet (``None``: the end of the stream) to each video source of a stream; returns
        how far the stream has arrived (its first unresolved sample)."""
        feeds = [(source, source.video) for source in streams if source.video is not None]
        for source, feed in feeds:
            try:
                frames = feed.finish() if message is None else feed.push(message)
            except DecodeError as err:
                t_ns = 0 if message is None else message.log_time_ns
                located = err.located(uri=self.uri, topic=source.src.topic, t_ns=t_ns)
                raise located.at_entry(source.src.entry_text(self.contract_name)) from err
            for sample, image in frames:
                source.cache[sample] = image
        return min(feed.watermark for _, feed in feeds)


def iter_frames(
    reader: BagReader,
    uri: str,
    features: Sequence[FeatureSpec],
    sources: Sequence[AlignedSource],
    ticks_ns: Int64Array,
    contract_name: str = "contract",
    whole: BagReader | None = None,
) -> Iterator[Frame]:
    """Stream ``reader`` and yield the frame of every tick, in order.

    A message that cannot be decoded raises a :class:`DecodeError` naming the bag, topic, time and
    the contract entry (``contract_name:line``) that reads it. ``whole`` is the bag ``reader`` is a
    window of: video streams decode from the key frame before the window.
    """
    state = _Streaming(features, sources, ticks_ns, uri, contract_name)
    state.start_video(whole or reader)
    yield from state.ready_frames()  # ticks made only of fills need no message
    for message in reader.messages(tuple(state.by_topic)):
        if state.take(message):
            yield from state.ready_frames()
        if state.done:
            break
    if not state.done and state.video_streams:
        state.finish_video()
        yield from state.ready_frames()
    if not state.done:
        raise AlignmentError(
            f"the bag ended after {state.next_tick} of {int(ticks_ns.size)} frames: messages seen in the "
            "first pass were missing in the second",
            uri=uri,
            fix="the bag changed while it was read, or it is corrupt; re-run, or reindex the bag.",
        )
