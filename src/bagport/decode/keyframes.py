"""Where a video stream can be decoded from: key frames, read from the bitstream of one packet.

- H.264 (Annex B): a NAL unit of type 5 (IDR).
- H.265 (Annex B): an IDR or BLA picture (NAL types 16-20). A CRA picture is not taken as a key
  frame: the pictures after it may need frames before it (open GOP).
- VP9: the first frame's uncompressed header says ``frame_type`` KEY_FRAME (a superframe's first
  frame comes first in the packet).
- AV1 (low-overhead OBU stream): a frame (header) OBU whose ``frame_type`` is KEY_FRAME, assuming
  the sequence has no reduced still-picture header (video never has).
"""

from __future__ import annotations

from collections.abc import Iterator
from enum import StrEnum

__all__ = ["Codec", "is_key_packet"]


class Codec(StrEnum):
    """Codecs of camera video streams, by their FFmpeg decoder family."""

    H264 = "h264"
    HEVC = "hevc"
    VP9 = "vp9"
    AV1 = "av1"


_START = b"\x00\x00\x01"
_H264_IDR = 5
_HEVC_KEYS = frozenset({16, 17, 18, 19, 20})  # BLA_W_LP, BLA_W_RADL, BLA_N_LP, IDR_W_RADL, IDR_N_LP
_VP9_FRAME_MARKER = 2
_AV1_FRAME_HEADER, _AV1_FRAME = 3, 6


def _nal_types(data: bytes, codec: Codec) -> Iterator[int]:
    at = data.find(_START)
    while at >= 0 and at + 3 < len(data):
        header = data[at + 3]
        yield header & 0x1F if codec is Codec.H264 else (header >> 1) & 0x3F
        at = data.find(_START, at + 3)


def _vp9_key(data: bytes) -> bool:
    if not data or data[0] >> 6 != _VP9_FRAME_MARKER:
        return False
    first = data[0]
    profile = ((first >> 5) & 1) | (((first >> 4) & 1) << 1)
    at = 2 if profile == 3 else 3  # bit position of show_existing_frame (profile 3 has a reserved bit)
    show_existing = (first >> at) & 1
    return not show_existing and ((first >> (at - 1)) & 1) == 0


def _leb128(data: bytes, at: int) -> tuple[int, int]:
    value = shift = 0
    while at < len(data):
        byte = data[at]
        value |= (byte & 0x7F) << shift
        at += 1
        if not byte & 0x80:
            break
        shift += 7
    return value, at


def _av1_key(data: bytes) -> bool:
    at = 0
    while at < len(data):
        header = data[at]
        obu_type, extension, has_size = (header >> 3) & 0xF, (header >> 2) & 1, (header >> 1) & 1
        at += 1 + extension
        if has_size:
            size, at = _leb128(data, at)
        else:
            size = len(data) - at
        if obu_type in (_AV1_FRAME_HEADER, _AV1_FRAME) and at < len(data):
            show_existing, frame_type = data[at] >> 7, (data[at] >> 5) & 0x3
            return not show_existing and frame_type == 0
        at += size
    return False


def is_key_packet(codec: Codec, data: bytes) -> bool:
    """Whether decoding can start at this packet of a ``codec`` stream."""
    if codec is Codec.VP9:
        return _vp9_key(data)
    if codec is Codec.AV1:
        return _av1_key(data)
    keys = {_H264_IDR} if codec is Codec.H264 else _HEVC_KEYS
    return any(kind in keys for kind in _nal_types(data, codec))
