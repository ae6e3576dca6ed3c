"""Video packets: codec from the message, key frames from the bitstream, a decoder that hands each frame
back under the pts of the packet that carried it, and clear errors for what it cannot decode."""

from __future__ import annotations

from fractions import Fraction
from types import SimpleNamespace
from typing import Any

import av
import numpy as np
import pytest

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
from bagport.synth.video import encode_video

H, W = 96, 128


def _hevc_packets(count: int) -> list[bytes]:
    context: Any = av.CodecContext.create("libx265", "w")
    context.width, context.height, context.pix_fmt = W, H, "yuv420p"
    context.time_base = Fraction(1, 30)
    context.options = {"x265-params": "keyint=10:min-keyint=10:bframes=2:open-gop=0:log-level=error"}
    out = []
    for k in range(count):
        frame = av.VideoFrame.from_ndarray(render_frame(H, W, k), format="rgb24").reformat(format="yuv420p")
        frame.pts = k
        out += [bytes(p) for p in context.encode(frame)]
    out += [bytes(p) for p in context.encode(None)]
    return out


@pytest.mark.parametrize(
    ("msgtype", "field", "name", "codec"),
    [
        (RosType.COMPRESSED_VIDEO, "format", "h264", "h264"),
        (RosType.COMPRESSED_VIDEO, "format", "h265", "hevc"),
        (RosType.FFMPEG_PACKET, "encoding", "h264_nvenc", "h264"),
        (RosType.FFMPEG_PACKET, "encoding", "hevc_nvenc", "hevc"),
        (RosType.FFMPEG_PACKET, "encoding", "libx264", "h264"),
    ],
)
def test_codec_comes_from_format_or_encoding(msgtype: str, field: str, name: str, codec: str) -> None:
    msg = SimpleNamespace(**{field: name}, data=np.frombuffer(b"\x00\x00\x01\x65", np.uint8))
    packet = video_packet(msg, msgtype)
    assert (packet.codec, packet.data) == (codec, b"\x00\x00\x01\x65")


def test_other_codecs_are_refused_with_a_fix() -> None:
    with pytest.raises(DecodeError, match=r"format 'av1' is not a codec bagport decodes.*Fix: re-encode"):
        video_packet(SimpleNamespace(format="av1", data=b""), RosType.COMPRESSED_VIDEO)


@pytest.mark.parametrize("codec", ["h264", "hevc"])
def test_gate_and_decoder_from_mid_stream_give_every_frame_its_packet(codec: str) -> None:
    if codec == "h264":
        encoded = encode_video(
            (render_frame(H, W, k) for k in range(40)), width=W, height=H, fps=30, bframes=2, gop=10
        )
        datas, keys = zip(*[(p.data, p.keyframe) for p in encoded], strict=True)
    else:
        datas = tuple(_hevc_packets(40))
        keys = tuple(p is datas[0] or None for p in datas)  # checked below through is_keyframe
    packets = [VideoPacket(codec, data) for data in datas]
    flags = [is_keyframe(p) for p in packets]
    assert [i for i, f in enumerate(flags) if f] == [0, 10, 20, 30]
    if codec == "h264":
        assert list(keys) == flags  # the bitstream agrees with the encoder
    gate, decoder, shown = KeyframeGate(), StreamDecoder(codec), {}
    admitted = []
    for j, packet in enumerate(packets[4:], start=4):  # the recording starts mid-GOP
        if gate.admit(packet):
            admitted.append(j)
            for pts, frame in decoder.decode(packet, j):
                shown[pts] = decode_frame_index(frame_rgb(frame))
    for pts, frame in decoder.flush():
        shown[pts] = decode_frame_index(frame_rgb(frame))
    assert gate.skipped == 6 and admitted == list(range(10, 40))
    assert sorted(shown) == admitted
    assert sorted(shown.values()) == list(range(10, 40))  # closed GOPs: every frame from the key frame on


def test_corrupt_packet_is_a_decode_error() -> None:
    decoder = StreamDecoder("h264")
    with pytest.raises(DecodeError, match=r"h264 video packet cannot be decoded.*Fix:"):
        decoder.decode(VideoPacket("h264", b"\x00\x00\x01\x67" + b"\xff" * 64), 0)
    with pytest.raises(DecodeError, match="changes codec from h264 to hevc"):
        decoder.decode(VideoPacket("hevc", b""), 1)
