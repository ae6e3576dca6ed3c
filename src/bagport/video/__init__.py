"""Video: streaming encoder, remux concatenation, probing and decoding."""

from __future__ import annotations

from bagport.video.encode import ClipInfo, StreamingEncoder
from bagport.video.remux import ClipPlacement, VideoStreamInfo, concat_clips, iter_frames, probe_video
from bagport.video.settings import EncoderSettings

__all__ = [
    "ClipInfo",
    "ClipPlacement",
    "EncoderSettings",
    "StreamingEncoder",
    "VideoStreamInfo",
    "concat_clips",
    "iter_frames",
    "probe_video",
]
