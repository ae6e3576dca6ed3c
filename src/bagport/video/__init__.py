"""Video: streaming encoder, remux concatenation, probing, decoding and fidelity checks."""

from __future__ import annotations

from bagport.video.encode import ClipInfo, StreamingEncoder, stream_codec
from bagport.video.fidelity import ClipFidelity, FidelityParams, FidelityRecorder, FramePair, compare_clip
from bagport.video.remux import ClipPlacement, VideoStreamInfo, concat_clips, iter_frames, probe_video
from bagport.video.settings import DEFAULT_ENCODER, EncoderSettings

__all__ = [
    "DEFAULT_ENCODER",
    "ClipFidelity",
    "ClipInfo",
    "ClipPlacement",
    "EncoderSettings",
    "FidelityParams",
    "FidelityRecorder",
    "FramePair",
    "StreamingEncoder",
    "VideoStreamInfo",
    "compare_clip",
    "concat_clips",
    "iter_frames",
    "probe_video",
    "stream_codec",
]
