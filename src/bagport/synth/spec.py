"""What a synthetic episode contains: cameras, joints, actions, a task prompt."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from bagport.synth.faults import Faults, Window

__all__ = ["VIDEO_KINDS", "CameraSpec", "EpisodeSpec"]

CameraKind = Literal["raw", "jpeg", "png", "compressed_depth", "video", "ffmpeg"]
VIDEO_KINDS = ("video", "ffmpeg")
"""H.264 streams: ``video`` as foxglove_msgs/CompressedVideo, ``ffmpeg`` as ffmpeg_image_transport's
FFMPEGPacket (see :mod:`bagport.synth.video`)."""


@dataclass(frozen=True, slots=True)
class CameraSpec:
    name: str
    kind: CameraKind
    encoding: str = "bgr8"
    """Raw cameras: rgb8, bgr8, rgba8, bgra8, mono8, mono16, 8UC1, 8UC3, bayer_<pattern>8, or depth
    (16UC1, 32FC1; see :mod:`bagport.synth.images`). ``compressed_depth`` cameras: 16UC1 or 32FC1."""
    height: int = 96
    width: int = 128
    rate_hz: float = 30.0
    jitter_ns: int = 2_000_000
    latency_ns: int = 15_000_000
    noise: float = 0.0
    """Gaussian noise (std, in grey levels) on the colour bars, like a real sensor."""
    depth_codec: Literal["png", "rvl"] = "png"
    """``compressed_depth`` cameras: compressed_depth_image_transport's ``png`` or ``rvl`` format."""
    bframes: int = 0
    """Video cameras: B-frames in a row (0: decode order = capture order)."""
    gop: int = 30
    """Video cameras: a key frame every ``gop`` frames."""
    skip_packets: int = 0
    """Video cameras: the bag lacks the stream's first packets (the recording started mid-GOP)."""

    @property
    def is_video(self) -> bool:
        return self.kind in VIDEO_KINDS

    @property
    def is_depth(self) -> bool:
        return self.encoding.lower() in ("16uc1", "32fc1")

    @property
    def topic(self) -> str:
        if self.kind == "video":
            return f"/{self.name}/video"
        suffix = {"raw": "", "compressed_depth": "/compressedDepth", "ffmpeg": "/ffmpeg"}.get(
            self.kind, "/compressed"
        )
        return f"/{self.name}/image_raw{suffix}"

    @property
    def msgtype(self) -> str:
        if self.kind == "video":
            return "foxglove_msgs/msg/CompressedVideo"
        if self.kind == "ffmpeg":
            return "ffmpeg_image_transport_msgs/msg/FFMPEGPacket"
        return "sensor_msgs/msg/Image" if self.kind == "raw" else "sensor_msgs/msg/CompressedImage"


DEFAULT_CAMERAS = (CameraSpec("front", "raw", "bgr8"), CameraSpec("wrist", "jpeg"))


@dataclass(frozen=True, slots=True)
class EpisodeSpec:
    duration_s: float = 3.0
    start_ns: int = 1_700_000_000_000_000_000
    joint_names: tuple[str, ...] = ("j1", "j2", "j3", "j4", "j5", "j6")
    joint_rate_hz: float = 100.0
    joint_latency_ns: int = 2_000_000
    action_rate_hz: float = 50.0
    action_latency_ns: int = 1_000_000
    action_lead_s: float = 0.1
    """The action commands the position ``action_lead_s`` ahead of its stamp."""
    cameras: tuple[CameraSpec, ...] = DEFAULT_CAMERAS
    task: str | None = "pick up the red cube"
    seed: int = 0
    faults: Faults = field(default_factory=Faults)
    prompts: tuple[tuple[float, str], ...] = ()
    """More task prompts ``(t_s, text)`` on the task topic after the first (the task changes)."""
    events: tuple[tuple[float, str], ...] = ()
    """Episode events ``(t_s, text)`` on ``/episode_events`` (std_msgs/String), e.g. ``(3.0, "SUCCESS")``."""
    done_at_s: tuple[float, ...] = ()
    """``/done`` (std_msgs/Bool) turns true at these times and false 50 ms later."""
    pauses: tuple[Window, ...] = ()
    """No joint, action or camera message inside these windows (the recorder paused)."""
    publish_lag_ns: int | None = None
    """MCAP only: ``publish_time`` = capture time + this (a recorder that stores send times);
    ``None``: ``publish_time`` = log time, as rosbags writes it."""
    mcap_crcs: bool = False
    """MCAP only: re-write the file with the ``mcap`` library's writer, in 64 KiB chunks with chunk and
    data-section CRC-32s (as rosbag2's MCAP plugin writes them by default); rosbags' writer leaves them 0."""

    JOINT_TOPIC = "/joint_states"
    ACTION_TOPIC = "/cmd"
    TASK_TOPIC = "/task_prompt"
    EVENTS_TOPIC = "/episode_events"
    DONE_TOPIC = "/done"
