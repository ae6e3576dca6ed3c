"""Cameras recorded as video streams, in both passes of an episode.

Pass 1 (:func:`~bagport.episode.timeline.scan_timeline`) counts a stream's samples: its packets from
the first key frame on (a :class:`~bagport.decode.video.KeyframeGate`; the packets skipped before it
are reported in QA). An episode window that starts inside a GOP decodes from the last key frame
before the window (:func:`keyframe_before`), so no packet inside the window is skipped.

Pass 2 (:class:`VideoFeed`) feeds every sample to one decoder with the sample index as its ``pts``
and files each decoded frame under the ``pts`` it comes back with: decoder delay and B-frame
reordering never move a frame to another message's stamp. A sample is *resolved* once its frame came
out; the stream counts as arrived up to the first unresolved sample, so the assembler emits ticks in
order and caches only the frames a tick uses.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np
import numpy.typing as npt

from bagport.bags import BagMessage, BagReader
from bagport.decode import resize_image
from bagport.decode.keyframes import Codec
from bagport.decode.video import KeyframeGate, StreamDecoder, frame_rgb, is_keyframe, video_packet
from bagport.errors import DecodeError
from bagport.qa import CheckResult

__all__ = ["VideoFeed", "keyframe_before", "skipped_packet_checks"]

_LOOKBACK_NS = 2_000_000_000
_MAX_DELAY = 64
"""Packets a frame may trail its own packet by (H.264/H.265 reorder at most 16); later, it is lost."""


def keyframe_before(reader: BagReader, topic: str, start_ns: int) -> int | None:
    """Log time of the last key frame of video ``topic`` logged before ``start_ns`` (``None``: none).

    Looks back 2 s, then twice as far each time, to the bag's start.
    """
    bag_start_ns, span_ns, stop_ns = reader.info.start_ns, _LOOKBACK_NS, start_ns
    while stop_ns > bag_start_ns:
        first_ns = max(bag_start_ns, start_ns - span_ns)
        found = None
        for message in reader.messages([topic], start_ns=first_ns, stop_ns=stop_ns):
            if is_keyframe(video_packet(message.msg(), message.msgtype)):
                found = message.log_time_ns
        if found is not None:
            return found
        stop_ns, span_ns = first_ns, span_ns * 2
    return None


class VideoFeed:
    """Pass 2 of one video camera: messages in, ``(sample, image)`` out for the samples ``needed``."""

    def __init__(
        self,
        needed: npt.NDArray[np.bool_],
        resize_hw: tuple[int, int] | None,
        preroll: Iterable[BagMessage] | None = None,
    ) -> None:
        self._needed = needed
        self._resize_hw = resize_hw
        self._decoder: StreamDecoder | None = None
        self._gate = KeyframeGate(started=preroll is not None)
        self._resolved: set[int] = set()
        self._samples = 0
        self.watermark = 0
        """Every sample before this one is resolved."""
        if preroll is not None:
            self._preroll(preroll)

    def _preroll(self, messages: Iterable[BagMessage]) -> None:
        """Packets from the key frame before the window: decoded for their references, frames dropped."""
        gate = KeyframeGate()
        for number, message in enumerate(messages, start=1):
            packet = video_packet(message.msg(), message.msgtype)
            if gate.admit(packet):
                self._collect(self._decoder_for(packet.codec).decode(packet, -number))

    def _decoder_for(self, codec: Codec) -> StreamDecoder:
        if self._decoder is None:
            self._decoder = StreamDecoder(codec)
        return self._decoder

    def push(self, message: BagMessage) -> list[tuple[int, Any]]:
        packet = video_packet(message.msg(), message.msgtype)
        if not self._gate.admit(packet):
            return []
        sample = self._samples
        self._samples += 1
        images = self._collect(self._decoder_for(packet.codec).decode(packet, sample))
        self._expire(sample - _MAX_DELAY)
        return images

    def finish(self) -> list[tuple[int, Any]]:
        """The frames left in the decoder at the end of the stream."""
        images = [] if self._decoder is None else self._collect(self._decoder.flush())
        self._expire(self._samples)
        return images

    def _collect(self, frames: list[tuple[int, Any]]) -> list[tuple[int, Any]]:
        images = []
        for pts, frame in frames:
            if pts < self.watermark or pts >= self._samples:
                continue  # a frame of the pre-roll before the window
            self._resolved.add(pts)
            if pts < self._needed.size and self._needed[pts]:
                image = frame_rgb(frame)
                if self._resize_hw is not None:
                    image = resize_image(image, *self._resize_hw)
                images.append((pts, image))
        while self.watermark in self._resolved:
            self._resolved.discard(self.watermark)
            self.watermark += 1
        return images

    def _expire(self, limit: int) -> None:
        """Samples before ``limit`` whose frame never came: an error if a tick needs one."""
        while self.watermark < limit:
            lost = self.watermark not in self._resolved
            if lost and self.watermark < self._needed.size and self._needed[self.watermark]:
                raise DecodeError(
                    f"video packet {self.watermark} (counted from the stream's first key frame) gave no frame",
                    fix="the stream is corrupt there; cut the episode window around it.",
                )
            self._resolved.discard(self.watermark)
            self.watermark += 1


def skipped_packet_checks(skipped: dict[str, int]) -> Iterator[CheckResult]:
    """QA of each video topic: packets skipped before its first key frame (a recording started mid-GOP)."""
    for topic, count in skipped.items():
        reason = (
            f"{count} packet(s) before the stream's first key frame skipped (the recording started mid-GOP)"
            if count
            else "the stream starts at a key frame"
        )
        yield CheckResult(
            "video.skipped_packets", topic, float(count), "warn" if count else "pass", False, reason
        )
