"""Synthetic cameras recorded as a compressed video stream (H.264 through PyAV's libx264).

One packet per message, as ``foxglove_msgs/CompressedVideo`` and ffmpeg_image_transport publish
them: Annex B access units in decode order, parameter sets (SPS/PPS) in-band before every key
frame. With B-frames the decode order differs from the capture order: each packet carries the
capture index of the frame it holds (``pts``), and its message is stamped with that frame's
capture time. Frames are :func:`~bagport.synth.pixels.render_frame` images, so every decoded
frame shows its capture index.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from fractions import Fraction
from typing import Any

import av
import numpy as np
import numpy.typing as npt

__all__ = ["VideoPacket", "encode_video"]

Rgb = npt.NDArray[np.uint8]


@dataclass(frozen=True, slots=True)
class VideoPacket:
    pts: int
    """Capture index of the frame this packet carries."""
    data: bytes
    keyframe: bool


def encode_video(
    frames: Iterable[Rgb], *, width: int, height: int, fps: float, bframes: int = 0, gop: int = 30
) -> Iterator[VideoPacket]:
    """H.264 packets of ``frames`` in decode order: a key frame (IDR) every ``gop`` frames, at most
    ``bframes`` B-frames in a row (0: none, decode order = capture order), closed GOPs."""
    context: Any = av.CodecContext.create("libx264", "w")
    context.width, context.height, context.pix_fmt = width, height, "yuv420p"
    context.time_base = Fraction(1, max(1, round(fps)))
    context.options = {
        "bf": str(bframes),
        "g": str(gop),
        "keyint_min": str(gop),
        "sc_threshold": "0",
        "b-adapt": "0",
        "preset": "veryfast",
        "crf": "20",
    }
    for index, rgb in enumerate(frames):
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24").reformat(
            format="yuv420p"
        )
        frame.pts = index
        yield from _packets(context.encode(frame))
    yield from _packets(context.encode(None))


def _packets(packets: Iterable[Any]) -> Iterator[VideoPacket]:
    for packet in packets:
        yield VideoPacket(int(packet.pts), bytes(packet), bool(packet.is_keyframe))
