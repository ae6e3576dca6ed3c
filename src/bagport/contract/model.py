"""The contract: a Rosetta-compatible YAML mapping ROS topics to LeRobot features.

The schema follows Rosetta's v1 contract (``robot_type``, ``fps``,
``observations``, ``actions`` with ``publish``, ``tasks``, ``rewards``,
``signals``, ``complementary_data``, ``adjunct``) so a contract a team already
has works unchanged.  Live-only sections are accepted and ignored offline.
"""

from __future__ import annotations

import re
from typing import Annotated, Literal

from pydantic import (
    AfterValidator,
    AliasChoices,
    BaseModel,
    ConfigDict,
    Field,
    PositiveFloat,
    PositiveInt,
    StrictInt,
)

from bagport.msgtypes import normalize_msgtype
from bagport.yamlsource import YamlJson

__all__ = [
    "ActionEntry",
    "AlignOptions",
    "Contract",
    "DoneSignal",
    "EpisodeEvents",
    "EpisodesOptions",
    "MAX_FPS",
    "MAX_RESIZE_PX",
    "ImageOptions",
    "ObservationEntry",
    "Publish",
    "ScalarEntry",
    "Selector",
    "TaskEntry",
    "normalize_msgtype",
]

_MSGTYPE = re.compile(r"^[A-Za-z][\w]*/(msg/)?[A-Za-z][\w]*$")
MAX_RESIZE_PX = 8192
"""Largest ``image.resize`` side: an 8192 x 8192 RGB frame is 192 MiB, and video codecs stop about there."""
MAX_FPS = 1000
"""Largest ``fps``: one frame per millisecond (the frame grid of a one-hour bag is then 3.6 M frames)."""


def _check_key(key: str) -> str:
    if not key or "/" in key:
        raise ValueError(
            f"feature key {key!r} must be non-empty and must not contain '/' (LeRobot forbids it)"
        )
    return key


def _check_topic(topic: str) -> str:
    if not topic.startswith("/"):
        raise ValueError(
            f"topic {topic!r} must be an absolute ROS topic name starting with '/' "
            f"(a ROS 1 bag's relative {topic!r} is matched by '/{topic}')"
        )
    return topic


def _check_msgtype(msgtype: str) -> str:
    if not _MSGTYPE.match(msgtype.strip()):
        raise ValueError(f"message type {msgtype!r} is not of the form 'pkg/msg/Type' (or ROS 1 'pkg/Type')")
    return normalize_msgtype(msgtype)


def _check_decoder(ref: str) -> str:
    module, sep, func = ref.partition(":")
    if not sep or not module or not func:
        raise ValueError(f"decoder {ref!r} must be 'python.module:function'")
    return ref


FeatureKey = Annotated[str, AfterValidator(_check_key)]
Topic = Annotated[str, AfterValidator(_check_topic)]
MsgType = Annotated[str, AfterValidator(_check_msgtype)]
DecoderRef = Annotated[str, AfterValidator(_check_decoder)]
StampSource = Literal["header", "receive", "publish"]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)


class Selector(_Strict):
    """Which dimensions of a message make up the feature, in order."""

    names: tuple[str, ...] = ()
    child_frame: str | None = None
    """tf2_msgs/msg/TFMessage only: the transform whose ``child_frame_id`` is this frame."""
    parent_frame: str | None = None
    """tf2_msgs/msg/TFMessage only, optional: and whose ``header.frame_id`` is this frame."""


def _check_resize(size: tuple[int, int] | None) -> tuple[int, int] | None:
    if size is not None and max(size) > MAX_RESIZE_PX:
        raise ValueError(
            f"resize {list(size)} asks for frames larger than {MAX_RESIZE_PX} pixels a side "
            f"({size[0] * size[1] * 3 / 2**20:,.0f} MiB per RGB frame)"
        )
    return size


def _check_fps(fps: int) -> int:
    if fps > MAX_FPS:
        raise ValueError(f"fps {fps} is above {MAX_FPS} (one frame per millisecond)")
    return fps


def _check_depth_range(bounds: tuple[float, float] | None) -> tuple[float, float] | None:
    if bounds is not None and not 0 <= bounds[0] < bounds[1]:
        raise ValueError(f"depth_range_m {list(bounds)} must be [min, max] metres with 0 <= min < max")
    return bounds


class ImageOptions(_Strict):
    resize: Annotated[tuple[PositiveInt, PositiveInt] | None, AfterValidator(_check_resize)] = None
    """Target ``[height, width]``, each side at most :data:`MAX_RESIZE_PX`."""
    depth_range_m: Annotated[tuple[float, float] | None, AfterValidator(_check_depth_range)] = None
    """Depth cameras only: ``[min, max]`` metres the 12-bit depth codes span (LeRobot's
    ``depth_min``/``depth_max``; default ``[0.01, 10.0]``)."""


class AlignOptions(_Strict):
    strategy: Literal["hold", "asof", "drop", "nearest", "interpolate"] = "hold"
    tol_ms: PositiveFloat | None = None
    stamp: StampSource | None = None
    fill: Literal["fail", "hold", "zeros", "drop_frame"] = "fail"
    """What a frame without a valid message gets; never silent (recorded in provenance)."""
    clock_offset_ms: float = 0.0
    """How far this source's stamps run ahead of the other streams' (another machine's clock):
    the source is sampled at ``tick + clock_offset_ms``.  QA's ``time.clock_offset_ms`` measures it."""


class ObservationEntry(_Strict):
    key: FeatureKey
    topic: Topic
    type: MsgType
    selector: Selector | None = None
    align: AlignOptions | None = None
    dtype: str | None = None
    decoder: DecoderRef | None = None
    image: ImageOptions | None = None
    qos: dict[str, YamlJson] | None = None


class Publish(_Strict):
    topic: Topic
    type: MsgType
    qos: dict[str, YamlJson] | None = None


class ActionEntry(_Strict):
    key: FeatureKey
    publish: Publish
    selector: Selector | None = None
    align: AlignOptions | None = None
    dtype: str | None = None
    decoder: DecoderRef | None = None
    encoder: str | None = None
    safety_behavior: str | None = None


class TaskEntry(_Strict):
    key: str = "task"
    topic: Topic
    type: MsgType = "std_msgs/msg/String"
    qos: dict[str, YamlJson] | None = None


class ScalarEntry(_Strict):
    """``rewards``, ``signals`` and ``complementary_data`` entries (dtype required, as in Rosetta)."""

    key: FeatureKey
    topic: Topic
    type: MsgType
    dtype: str
    selector: Selector | None = None
    align: AlignOptions | None = None
    decoder: DecoderRef | None = None
    qos: dict[str, YamlJson] | None = None


class EpisodeEvents(_Strict):
    """An event topic whose messages split a bag into episodes (``START``, ``SUCCESS``, ``FAIL``,
    ``DISCARD``, ``RESET``): a ``std_msgs/String`` holding the event name or JSON
    ``{"event_type": ..., "note": ..., "stamp": ..., "episode_id": ...}`` (``event`` / ``type`` too),
    or ``field`` (a dot path; default ``data``, else ``event_type``) of any message."""

    topic: Topic
    type: MsgType = "std_msgs/msg/String"
    field: str | None = None
    """Dot path to the event name; default ``data``."""
    note_field: str | None = None
    """Dot path to a free-text note (JSON strings carry it as ``note``)."""
    time: Literal["stamp", "log"] = "stamp"
    """An event's time: its own ``stamp`` when it carries one (JSON key or message field), else the
    bag's log time; ``log`` always uses the log time."""


class DoneSignal(_Strict):
    """A topic whose value turning true (non-zero) ends the current episode (e.g. ``next.done``)."""

    topic: Topic
    type: MsgType = "std_msgs/msg/Bool"
    field: str | None = None
    """Dot path to the value; default ``data``."""


class EpisodesOptions(_Strict):
    """How a bag splits into episodes (bagport extension; without it one bag is one episode)."""

    events: EpisodeEvents | None = None
    gap_s: PositiveFloat | None = None
    """A silence longer than this on every contract stream splits the episode."""
    done_signal: DoneSignal | None = None
    min_duration_s: float = Field(default=1.0, ge=0)
    """Shorter windows are dropped (listed with the reason)."""


class Contract(_Strict):
    robot_type: str = Field(validation_alias=AliasChoices("robot_type", "name"))
    fps: Annotated[StrictInt, AfterValidator(_check_fps)] = Field(
        default=30, gt=0, validation_alias=AliasChoices("fps", "rate_hz")
    )
    """Frames per second of the dataset, 1 to :data:`MAX_FPS`."""
    observations: tuple[ObservationEntry, ...] = ()
    actions: tuple[ActionEntry, ...] = ()
    tasks: tuple[TaskEntry, ...] = ()
    rewards: tuple[ScalarEntry, ...] = ()
    signals: tuple[ScalarEntry, ...] = ()
    complementary_data: tuple[ScalarEntry, ...] = ()
    adjunct: YamlJson = None
    teleop: YamlJson = None
    reset: YamlJson = None
    visualization: YamlJson = None
    recording: YamlJson = None
    info: YamlJson = None
    timestamp_source: StampSource | None = None
    max_duration_s: PositiveFloat | None = None
    clock: str | None = None
    """A feature key: one frame per message of that stream instead of the fixed grid (see README)."""
    action_offset_ms: float | None = None
    """The action at tick t is the command at t + offset (command-to-execution delay); may be negative."""
    action_offset_frames: int | None = None
    """The same offset in frames (``action_offset_ms = frames * 1000 / fps``)."""
    episodes: EpisodesOptions | None = None
    """bagport extension: episodes inside a bag (events, gaps, a done signal)."""
    default_task: str | None = None
    """bagport extension: the task when neither a task topic, the bag nor the manifest gives one."""
