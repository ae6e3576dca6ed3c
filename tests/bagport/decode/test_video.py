"""Video packets: codec from the message, key frames from the bitstream, a decoder that hands each frame
back under the pts of the packet that carried it, and clear errors for what it cannot decode."""

from __future__ import annotations

from fractions import Fraction
from types import SimpleNamespace
from typing import Any

import av
import numpy as np
import pytest

from bagport.decode.keyframes import Codec
from bagport.decode.video import (
    KeyframeGate,
    StreamDecoder,
    VideoPacket,
    frame_rgb,
    is_keyframe,
    video_packet,
)
from bagport.errors import DecodeError
from bagport.msgtypes import RosType
from bagport.synth import decode_frame_index, render_frame

H, W = 96, 128
GOP = 10
ENCODERS: dict[Codec, tuple[str, dict[str, str]]] = {
    Codec.H264: ("libx264", {"g": str(GOP), "keyint_min": str(GOP), "sc_threshold": "0", "bf": "2"}),
    Codec.HEVC: (
        "libx265",
        {"x265-params": f"keyint={GOP}:min-keyint={GOP}:bframes=2:open-gop=0:log-level=error"},
    ),
    Codec.VP9: (
        "libvpx-vp9",
        {"g": str(GOP), "keyint_min": str(GOP), "auto-alt-ref": "1", "lag-in-frames": "8"},
    ),
    Codec.AV1: ("libaom-av1", {"g": str(GOP), "keyint_min": str(GOP), "cpu-used": "8", "lag-in-frames": "8"}),
}


def _encode(codec: Codec, count: int) -> list[tuple[bytes, bool]]:
    """``count`` frames (each showing its index) as ``(packet bytes, encoder's key flag)`` in decode order."""
    name, options = ENCODERS[codec]
    context: Any = av.CodecContext.create(name, "w")
    context.width, context.height, context.pix_fmt = W, H, "yuv420p"
    context.time_base = Fraction(1, 30)
    context.options = options
    out = []
    for k in range(count):
        frame = av.VideoFrame.from_ndarray(render_frame(H, W, k), format="rgb24").reformat(format="yuv420p")
        frame.pts = k
        out += [(bytes(p), bool(p.is_keyframe)) for p in context.encode(frame)]
    out += [(bytes(p), bool(p.is_keyframe)) for p in context.encode(None)]
    return out


@pytest.mark.parametrize(
    ("msgtype", "field", "name", "codec"),
    [
        (RosType.COMPRESSED_VIDEO, "format", "h264", Codec.H264),
        (RosType.COMPRESSED_VIDEO, "format", "h265", Codec.HEVC),
        (RosType.COMPRESSED_VIDEO, "format", "vp9", Codec.VP9),
        (RosType.COMPRESSED_VIDEO, "format", "av1", Codec.AV1),
        (RosType.FFMPEG_PACKET, "encoding", "h264_nvenc", Codec.H264),
        (RosType.FFMPEG_PACKET, "encoding", "hevc_nvenc", Codec.HEVC),
        (RosType.FFMPEG_PACKET, "encoding", "libx264", Codec.H264),
        (RosType.FFMPEG_PACKET, "encoding", "libsvtav1", Codec.AV1),
    ],
)
def test_codec_comes_from_format_or_encoding(msgtype: str, field: str, name: str, codec: Codec) -> None:
    msg = SimpleNamespace(**{field: name}, data=np.frombuffer(b"\x00\x00\x01\x65", np.uint8))
    packet = video_packet(msg, msgtype)
    assert (packet.codec, packet.data) == (codec, b"\x00\x00\x01\x65")


def test_other_codecs_are_refused_with_a_fix() -> None:
    with pytest.raises(DecodeError, match=r"format 'mjpeg' is not a codec bagport decodes.*Fix: re-encode"):
        video_packet(SimpleNamespace(format="mjpeg", data=b""), RosType.COMPRESSED_VIDEO)


@pytest.mark.parametrize("codec", list(Codec), ids=str)
def test_gate_and_decoder_from_mid_stream_give_every_frame_its_packet(codec: Codec) -> None:
    encoded = _encode(codec, 40)
    packets = [VideoPacket(codec, data) for data, _ in encoded]
    keys = [j for j, packet in enumerate(packets) if is_keyframe(packet)]
    assert keys == [j for j, (_, flag) in enumerate(encoded) if flag]  # the bitstream agrees with the encoder
    assert len(keys) == 4
    gate, decoder, shown = KeyframeGate(), StreamDecoder(codec), {}
    admitted = []
    for j, packet in enumerate(packets[keys[0] + 3 :], start=keys[0] + 3):  # the recording starts mid-GOP
        if gate.admit(packet):
            admitted.append(j)
            for pts, frame in decoder.decode(packet, j):
                shown[pts] = decode_frame_index(frame_rgb(frame))
    for pts, frame in decoder.flush():
        shown[pts] = decode_frame_index(frame_rgb(frame))
    assert gate.skipped == keys[1] - keys[0] - 3 and admitted[0] == keys[1]
    assert sorted(shown) == admitted  # each packet gives back one frame, under its own pts
    assert sorted(shown.values()) == list(range(GOP, 40))  # every frame from the key frame on, once


def test_corrupt_packet_is_a_decode_error() -> None:
    decoder = StreamDecoder(Codec.H264)
    with pytest.raises(DecodeError, match=r"h264 video packet cannot be decoded.*Fix:"):
        decoder.decode(VideoPacket(Codec.H264, b"\x00\x00\x01\x67" + b"\xff" * 64), 0)
    with pytest.raises(DecodeError, match="changes codec from h264 to hevc"):
        decoder.decode(VideoPacket(Codec.HEVC, b""), 1)
