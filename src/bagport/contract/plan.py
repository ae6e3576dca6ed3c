"""Compile a validated contract into the features a dataset will have."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import NamedTuple

from bagport.contract.model import (
    ActionEntry,
    Contract,
    ObservationEntry,
    ScalarEntry,
    StampSource,
    TaskEntry,
)
from bagport.decode.custom import registered_decoder
from bagport.decode.joints import selected_joints
from bagport.errors import ContractError
from bagport.msgtypes import IMAGE_TYPES, TF_TYPES, RosType

__all__ = [
    "ContractPlan",
    "FeatureKind",
    "FeatureSpec",
    "ImageFilter",
    "JointFilter",
    "LineOf",
    "SourceSpec",
    "StreamFilter",
    "TransformFilter",
    "compile_contract",
]

LineOf = Callable[[Sequence[int | str]], int | None]
"""Maps a value path in the contract (``("observations", 2, "key")``) to its line in the file."""


class TransformFilter(NamedTuple):
    """Only the messages of ``topic`` carrying this transform are samples of the stream."""

    topic: str
    child_frame: str
    parent_frame: str | None


class JointFilter(NamedTuple):
    """Only the JointState messages of ``topic`` naming every one of ``joints`` are samples of the stream:
    publishers with different joints (an arm's and a gripper's driver) may share the topic."""

    topic: str
    joints: tuple[str, ...]


class ImageFilter(NamedTuple):
    """Only the images of ``topic`` that have pixels (a compressed one: bytes) are samples: a camera driver
    publishes empty (0x0) images before its first frame or after a glitch, which are no frame (the previous
    one holds)."""

    topic: str
    compressed: bool


StreamFilter = TransformFilter | JointFilter | ImageFilter
"""Which messages of a topic are the samples of a stream (every message when there is none)."""


_NUMERIC_DTYPES = frozenset({"float32", "float64", "int32", "int64", "bool", "uint8", "int16", "float16"})
DEFAULT_VECTOR_DTYPE = "float32"


class FeatureKind(StrEnum):
    VECTOR = "vector"
    VIDEO = "video"


@dataclass(frozen=True, slots=True)
class SourceSpec:
    """One contract entry: a topic contributing (part of) a feature."""

    key: str
    section: str
    topic: str
    msgtype: str
    names: tuple[str, ...]
    stamp: StampSource | None
    """``None`` means automatic: the header stamp when the message has a non-zero one, else receive time."""
    strategy: str
    tol_ms: float | None
    resize_hw: tuple[int, int] | None
    decoder: str | None
    fill: str = "fail"
    offset_ns: int = 0
    """The source is sampled at ``tick + offset_ns``: ``action_offset_ms`` on actions plus ``align.clock_offset_ms``."""
    depth_range_m: tuple[float, float] | None = None
    """``image.depth_range_m``: the metres a depth camera's codes span (``None``: LeRobot's default)."""
    line: int | None = None
    """Line of the entry in the contract file, for errors."""
    child_frame: str | None = None
    parent_frame: str | None = None
    joints: tuple[str, ...] = ()
    """A JointState read by joint name: the joints a message must name to be a sample (:class:`JointFilter`)."""
    joints_in_stream: bool = False
    """The stream's name says its joints: entries on the topic select different joints."""
    one_joint_list: bool = False
    """A JointState read by index alone (``position[0]``): every message of the topic must name the same joints
    in the same order, or two publishers' arrays would mix (:class:`bagport.episode.samples.JointListGuard`)."""

    @property
    def msg_type(self) -> str:
        """:attr:`msgtype` under the name Rosetta's decoder spec uses, so its decoders run unchanged."""
        return self.msgtype

    @property
    def stream(self) -> str:
        """What the timeline tracks: the topic, ``topic#child_frame`` for a TF lookup, or ``topic#j1,j2`` (the
        joints sorted) for joints that other entries on the topic do not select."""
        if self.child_frame is not None:
            return f"{self.topic}#{self.child_frame}"
        if self.joints_in_stream:
            return f"{self.topic}#{','.join(json.dumps(j) if ',' in j else j for j in sorted(self.joints))}"
        return self.topic

    @property
    def stream_filter(self) -> StreamFilter | None:
        if self.child_frame is not None:
            return TransformFilter(self.topic, self.child_frame, self.parent_frame)
        if self.joints:
            return JointFilter(self.topic, self.joints)
        if self.msgtype in (RosType.IMAGE, RosType.COMPRESSED_IMAGE):
            return ImageFilter(self.topic, compressed=self.msgtype == RosType.COMPRESSED_IMAGE)
        return None

    def where(self, source_name: str) -> str:
        """``file:line`` of this entry, for error messages."""
        return f"{source_name}:{self.line}" if self.line is not None else source_name

    def entry_text(self, source_name: str) -> str:
        """``contract.yaml:12, observations[key=observation.state]``: the entry, for error messages."""
        return f"{self.where(source_name)}, {self.section}[key={self.key}]"


@dataclass(frozen=True, slots=True)
class FeatureSpec:
    key: str
    kind: FeatureKind
    dtype: str
    sources: tuple[SourceSpec, ...]


@dataclass(frozen=True, slots=True)
class ContractPlan:
    """What a contract asks for, ready for the converter."""

    contract: Contract
    source_name: str
    features: tuple[FeatureSpec, ...]
    task_topics: tuple[TaskEntry, ...]
    episode_lines: dict[str, int] = field(default_factory=dict)
    """Lines of the ``episodes`` section's topics and fields (``events.field`` -> line), for errors."""

    @property
    def fps(self) -> int:
        return self.contract.fps

    @property
    def robot_type(self) -> str:
        return self.contract.robot_type

    @property
    def clock(self) -> str | None:
        """The feature key whose messages are the frames (``clock:``), or ``None`` for the fixed grid."""
        return self.contract.clock

    @property
    def sources(self) -> tuple[SourceSpec, ...]:
        return tuple(src for feature in self.features for src in feature.sources)

    def topics(self) -> tuple[str, ...]:
        """Every topic the conversion reads, features first, then task topics."""
        seen = dict.fromkeys([src.topic for src in self.sources] + [t.topic for t in self.task_topics])
        return tuple(seen)

    def streams(self) -> tuple[str, ...]:
        """Every stream the timeline tracks (a topic, or a TF child frame on a topic)."""
        return tuple(dict.fromkeys(src.stream for src in self.sources))

    def stream_filters(self) -> dict[str, StreamFilter]:
        return {src.stream: f for src in self.sources if (f := src.stream_filter) is not None}

    def one_joint_list_topics(self) -> dict[str, SourceSpec]:
        """JointState topics an entry reads by index alone (:attr:`SourceSpec.one_joint_list`): the entry."""
        return {src.topic: src for src in self.sources if src.one_joint_list}


def _source(
    entry: ObservationEntry | ActionEntry | ScalarEntry,
    section: str,
    default_stamp: StampSource | None,
    offset_ns: int = 0,
    line: int | None = None,
) -> SourceSpec:
    if isinstance(entry, ActionEntry):
        topic, msgtype = entry.publish.topic, entry.publish.type
    else:
        topic, msgtype = entry.topic, entry.type
    align = entry.align
    image = entry.image if isinstance(entry, ObservationEntry) else None
    resize = image.resize if image else None
    names = entry.selector.names if entry.selector else ()
    # the built-in JointState extractor reads joints by name; a decoder (the entry's, or one registered for
    # the type) makes its own values, which selector.names only label
    by_joint_name = (
        msgtype == RosType.JOINT_STATE and entry.decoder is None and registered_decoder(msgtype) is None
    )
    joints = selected_joints(names) if by_joint_name else ()
    return SourceSpec(
        key=entry.key,
        section=section,
        topic=topic,
        msgtype=msgtype,
        names=names,
        stamp=align.stamp if align and align.stamp else default_stamp,
        strategy=align.strategy if align else "hold",
        tol_ms=align.tol_ms if align else None,
        resize_hw=(resize[0], resize[1]) if resize else None,
        decoder=entry.decoder,
        fill=align.fill if align else "fail",
        offset_ns=offset_ns + (round(align.clock_offset_ms * 1_000_000) if align else 0),
        depth_range_m=image.depth_range_m if image else None,
        line=line,
        child_frame=entry.selector.child_frame if entry.selector else None,
        parent_frame=entry.selector.parent_frame if entry.selector else None,
        joints=joints,
        one_joint_list=by_joint_name and bool(names) and not joints,
    )


def _name_joint_streams(sources: list[SourceSpec]) -> list[SourceSpec]:
    """Entries selecting different joints of one topic read different streams (their own messages)."""
    selections: dict[str, set[frozenset[str]]] = {}
    for src in sources:
        if src.child_frame is None:
            selections.setdefault(src.topic, set()).add(frozenset(src.joints))
    return [
        replace(src, joints_in_stream=True) if src.joints and len(selections[src.topic]) > 1 else src
        for src in sources
    ]


def action_offset_ns(contract: Contract, source_name: str) -> int:
    """``action_offset_ms`` or ``action_offset_frames`` in integer nanoseconds (0 when unset)."""
    if contract.action_offset_ms is not None and contract.action_offset_frames is not None:
        raise ContractError(
            "sets both action_offset_ms and action_offset_frames",
            file=source_name,
            field="action_offset_frames",
            fix="keep one of them.",
        )
    if contract.action_offset_frames is not None:
        return contract.action_offset_frames * 1_000_000_000 // contract.fps
    return round((contract.action_offset_ms or 0.0) * 1_000_000)


def _check_frames(src: SourceSpec, section: str, source_name: str) -> None:
    field = f"{section}[key={src.key}].selector"
    if src.msgtype in TF_TYPES and src.child_frame is None and src.decoder is None:
        raise ContractError(
            f"{src.key!r} reads {src.topic} ({src.msgtype}), which carries many transforms: say which one",
            file=source_name,
            line=src.line,
            field=f"{field}.child_frame",
            fix="add 'selector: {child_frame: <frame>}' (optionally parent_frame), e.g. child_frame: tool0.",
        )
    if src.msgtype not in TF_TYPES and (src.child_frame or src.parent_frame):
        raise ContractError(
            f"selector.child_frame / parent_frame only apply to {RosType.TF_MESSAGE} (or ROS 1 tf/tfMessage), "
            f"not {src.msgtype}",
            file=source_name,
            line=src.line,
            field=f"{field}.child_frame",
            fix="remove them, or set 'type: tf2_msgs/msg/TFMessage'.",
        )


_SCALAR_TYPES = frozenset(f"std_msgs/msg/{name}" for name in ("Float32", "Float64", "Int32", "Int64", "Bool"))


def _check_align(src: SourceSpec, section: str, source_name: str) -> None:
    field = f"{section}[key={src.key}].align"
    is_image = src.msgtype in IMAGE_TYPES
    if src.strategy in ("asof", "nearest") and src.tol_ms is None:
        raise ContractError(
            f"align.strategy {src.strategy!r} on {src.topic} needs tol_ms",
            file=source_name,
            line=src.line,
            field=f"{field}.tol_ms",
            fix="add e.g. 'tol_ms: 50', or use strategy 'hold'.",
        )
    if src.strategy == "interpolate" and is_image:
        raise ContractError(
            f"images cannot be interpolated ({src.key} on {src.topic})",
            file=source_name,
            line=src.line,
            field=f"{field}.strategy",
            fix="use 'hold', 'asof' or 'nearest' for cameras.",
        )
    if src.fill == "zeros":
        if is_image and src.resize_hw is None:
            raise ContractError(
                f"fill 'zeros' on camera {src.key} needs a known frame size",
                file=source_name,
                line=src.line,
                field=f"{field}.fill",
                fix="set 'image: {resize: [h, w]}', or use fill 'hold' / 'drop_frame' / 'fail'.",
            )
        if not is_image and not src.names and src.msgtype not in _SCALAR_TYPES:
            raise ContractError(
                f"fill 'zeros' on {src.key} needs a known width",
                file=source_name,
                line=src.line,
                field=f"{field}.fill",
                fix="list the dimensions in selector.names.",
            )


def compile_contract(
    contract: Contract, source_name: str = "contract", line_of: LineOf | None = None
) -> ContractPlan:
    """Group entries by key (declaration order) and check what can be checked without a bag.

    ``line_of`` places errors on the entry's line in the file."""
    entries: list[tuple[ObservationEntry | ActionEntry | ScalarEntry, str, StampSource | None, int]] = []
    entries += [(e, "observations", None, i) for i, e in enumerate(contract.observations)]
    entries += [(e, "actions", contract.timestamp_source, i) for i, e in enumerate(contract.actions)]
    offset_ns = action_offset_ns(contract, source_name)
    for section in ("rewards", "signals", "complementary_data"):
        entries += [(e, section, None, i) for i, e in enumerate(getattr(contract, section))]
    if not entries:
        raise ContractError(
            "declares no features",
            file=source_name,
            fix="add at least one entry under 'observations' or 'actions'.",
        )

    sources = []
    for entry, section, stamp, index in entries:
        src = _source(
            entry,
            section,
            stamp,
            offset_ns if section == "actions" else 0,
            line_of((section, index)) if line_of else None,
        )
        _check_align(src, section, source_name)
        _check_frames(src, section, source_name)
        sources.append(src)
    grouped: dict[str, list[tuple[SourceSpec, str | None]]] = {}
    for src, (entry, *_) in zip(_name_joint_streams(sources), entries, strict=True):
        grouped.setdefault(src.key, []).append((src, entry.dtype))

    features = [_feature(key, group, source_name) for key, group in grouped.items()]
    if contract.clock is not None and contract.clock not in grouped:
        raise ContractError(
            f"clock {contract.clock!r} is not a feature key of this contract",
            file=source_name,
            field="clock",
            fix=f"use one of {sorted(grouped)}, or remove 'clock' for the fixed grid.",
        )
    return ContractPlan(
        contract=contract,
        source_name=source_name,
        features=tuple(features),
        task_topics=contract.tasks,
        episode_lines=_episode_lines(line_of),
    )


def _feature(key: str, group: list[tuple[SourceSpec, str | None]], source_name: str) -> FeatureSpec:
    """The feature of one key from its sources (with each entry's dtype): a camera (one image topic) or a
    numeric vector of one numeric dtype."""
    sources = tuple(src for src, _ in group)
    image_flags = {src.msgtype in IMAGE_TYPES for src in sources}
    if image_flags == {True}:
        if len(sources) > 1:
            topics = ", ".join(src.topic for src in sources)
            raise ContractError(
                f"image key {key!r} is declared on several topics ({topics})",
                file=source_name,
                line=sources[1].line,
                field=key,
                fix="give each camera its own key, e.g. observation.images.front and observation.images.wrist.",
            )
        return FeatureSpec(key, FeatureKind.VIDEO, "video", sources)
    if image_flags == {True, False}:
        raise ContractError(
            f"key {key!r} mixes image topics and numeric topics",
            file=source_name,
            line=sources[-1].line,
            field=key,
            fix="use separate keys for images and for numeric data.",
        )
    dtypes = {dtype for _, dtype in group if dtype}
    if len(dtypes) > 1:
        raise ContractError(
            f"entries of key {key!r} ask for different dtypes {sorted(dtypes)}",
            file=source_name,
            line=sources[-1].line,
            field=f"{key}.dtype",
            fix="use one dtype for every entry of a key.",
        )
    dtype = dtypes.pop() if dtypes else DEFAULT_VECTOR_DTYPE
    if dtype not in _NUMERIC_DTYPES:
        raise ContractError(
            f"dtype {dtype!r} of key {key!r} is not one a numeric feature can have",
            file=source_name,
            line=next(src.line for src, given in group if given == dtype),  # the entry that asks for it
            field=f"{key}.dtype",
            fix=f"use one of {sorted(_NUMERIC_DTYPES)} (a narrower integer fits a wider one: int8 in int16).",
        )
    return FeatureSpec(key, FeatureKind.VECTOR, dtype, sources)


def _episode_lines(line_of: LineOf | None) -> dict[str, int]:
    """``events.topic`` -> its line (or its section's line when the key is left out), and so on."""
    lines: dict[str, int] = {}
    for section in ("events", "done_signal"):
        for key in ("topic", "type", "field", "note_field"):
            line = line_of(("episodes", section, key)) if line_of else None
            if line is not None:
                lines[f"{section}.{key}"] = line
    return lines
