"""Camera topics recorded as a compressed video stream: ``foxglove_msgs/CompressedVideo`` and
``ffmpeg_image_transport_msgs/FFMPEGPacket``, one encoded access unit per message.

The codec comes from the message (``format``: ``h264``, ``h265``, ``vp9``, ``av1``; ``encoding``: the
ffmpeg encoder that wrote it, e.g. ``libx264``, ``hevc_nvenc``); parameter sets (SPS/PPS/VPS, AV1's
sequence header) come in-band from the stream (Annex B / OBUs, as both transports publish them). A
stream can be decoded only from a key frame (:mod:`bagport.decode.keyframes`): :class:`KeyframeGate`
drops the packets before the first one.
:class:`StreamDecoder` is one PyAV decoder: every packet goes in with a ``pts`` the caller chooses
(its sample index) and comes out, after the decoder's delay and B-frame reordering, as an RGB frame
with that ``pts``, so each frame keeps the stamp of the message that carried it.
"""

from __future__ import annotations

from typing import Any

import av
import numpy as np
import numpy.typing as npt

from bagport.decode.keyframes import Codec, is_key_packet
from bagport.errors import DecodeError
from bagport.msgtypes import RosType

__all__ = [
    "KeyframeGate",
    "StreamDecoder",
    "VideoPacket",
    "decoder_settings",
    "frame_rgb",
    "is_keyframe",
    "video_packet",
]

Rgb = npt.NDArray[np.uint8]
_DECODERS = {Codec.H264: "h264", Codec.HEVC: "hevc", Codec.VP9: "vp9", Codec.AV1: "libdav1d"}


def _codec(name: str) -> Codec | None:
    """``h264``/``h265`` (CompressedVideo ``format``) or an FFmpeg encoder name (FFMPEGPacket ``encoding``)."""
    text = name.lower()
    for codec, words in (
        (Codec.H264, ("264", "avc")),
        (Codec.HEVC, ("265", "hevc")),
        (Codec.VP9, ("vp9",)),
        (Codec.AV1, ("av1", "av01")),
    ):
        if any(word in text for word in words):
            return codec
    return None


class VideoPacket:
    """The codec and encoded bytes of one video message."""

    __slots__ = ("codec", "data")

    def __init__(self, codec: Codec, data: bytes) -> None:
        self.codec = codec
        self.data = data


def video_packet(msg: Any, msgtype: str) -> VideoPacket:
    """The packet a ``CompressedVideo`` or ``FFMPEGPacket`` message carries."""
    field = "format" if msgtype == RosType.COMPRESSED_VIDEO else "encoding"
    name = str(getattr(msg, field, ""))
    codec = _codec(name)
    if codec is None:
        raise DecodeError(
            f"video stream {field} {name!r} is not a codec bagport decodes (H.264, H.265, VP9, AV1)",
            fix="re-encode the camera in one of them, or leave the topic out of the contract.",
        )
    data = msg.data.tobytes() if isinstance(msg.data, np.ndarray) else bytes(msg.data)
    return VideoPacket(codec, data)


def is_keyframe(packet: VideoPacket) -> bool:
    """Whether decoding can start at this packet (see :mod:`bagport.decode.keyframes`)."""
    return is_key_packet(packet.codec, packet.data)


class KeyframeGate:
    """Admits a stream's packets from its first key frame on; counts the ones skipped before it."""

    def __init__(self, started: bool = False) -> None:
        self.started = started
        self.skipped = 0

    def admit(self, packet: VideoPacket) -> bool:
        if not self.started and is_keyframe(packet):
            self.started = True
        if not self.started:
            self.skipped += 1
        return self.started


class StreamDecoder:
    """One PyAV decoder: packets in (each with its ``pts``), ``(pts, frame)`` out in display order.

    Memory is the decoder's own: its reference frames and reorder delay, whatever the stream's length.
    """

    def __init__(self, codec: Codec) -> None:
        self.codec = codec
        self._context: Any = av.CodecContext.create(_DECODERS[codec], "r")

    def decode(self, packet: VideoPacket, pts: int) -> list[tuple[int, Any]]:
        """Frames the decoder gives back after ``packet``: ``(pts, av.VideoFrame)``."""
        if packet.codec != self.codec:
            raise DecodeError(
                f"the video stream changes codec from {self.codec} to {packet.codec}",
                fix="map each encoding to its own topic; one camera stream has one codec.",
            )
        av_packet = av.Packet(packet.data)
        av_packet.pts = pts
        return self._run(av_packet)

    def flush(self) -> list[tuple[int, Any]]:
        """The frames still inside the decoder at the end of the stream."""
        return self._run(None)

    def _run(self, av_packet: Any) -> list[tuple[int, Any]]:
        try:
            frames = self._context.decode(av_packet)
        except (av.error.FFmpegError, ValueError) as err:
            raise DecodeError(
                f"{self.codec} video packet cannot be decoded: {err}",
                fix="the stream is corrupt at this message; cut the episode window around it.",
            ) from err
        return [(int(frame.pts), frame) for frame in frames if frame.pts is not None]


def decoder_settings() -> dict[str, Any]:
    """What decides a video stream's decoded pixels besides its bytes: the decoder library versions."""
    return {"decoder": "pyav", "av": av.__version__, "libavcodec": av.library_versions.get("libavcodec")}


def frame_rgb(frame: Any) -> Rgb:
    """An ``av.VideoFrame`` as RGB uint8 (H, W, 3)."""
    rgb: Rgb = frame.to_ndarray(format="rgb24")
    return rgb
