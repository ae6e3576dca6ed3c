"""What a contract will produce: its feature table, alone or resolved against a bag.

``bagport contract check`` prints this before any conversion starts, so a wrong topic,
type, joint name or field shows up in seconds, with the fix.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from bagport.bags import BagReader, open_bag
from bagport.contract import ContractPlan, FeatureKind, SourceSpec
from bagport.decode import (
    decode_image,
    image_channels,
    make_extractor,
    resize_image,
)
from bagport.decode.joint_state_cdr import joint_lists
from bagport.decode.video import video_packet
from bagport.episode.checks import check_bag_fits
from bagport.episode.samples import MIXED_JOINT_LISTS_FIX, mixed_joint_lists, sample_tests
from bagport.errors import ContractError, DecodeError
from bagport.msgtypes import VIDEO_TYPES
from bagport.segment import check_episode_topics

__all__ = ["FeatureRow", "describe_features", "format_feature_table"]


@dataclass(frozen=True, slots=True)
class FeatureRow:
    key: str
    dtype: str
    shape: tuple[int, ...] | None
    """``None`` when it depends on the bag (no selector names, image size)."""
    names: tuple[str, ...] | None
    sources: tuple[str, ...]
    """``topic (type) strategy/stamp/fill`` per contract entry."""


def _source_text(topic: str, msgtype: str, strategy: str, stamp: str | None, fill: str) -> str:
    return f"{topic} ({msgtype}) {strategy}/{stamp or 'auto'}/{fill}"


def describe_features(
    plan: ContractPlan, bag_uri: str | None = None, msg_definitions: Mapping[str, str] | None = None
) -> list[FeatureRow]:
    """The feature table; with ``bag_uri`` every topic, type, joint and field is checked against the bag
    and shapes and names are resolved from its first messages."""
    first: dict[str, object] = {}
    if bag_uri is not None:
        with open_bag(bag_uri, msg_definitions=msg_definitions) as reader:
            check_bag_fits(reader.info, plan)
            check_episode_topics(reader, plan)
            first = _first_messages(reader, plan)
            _check_one_joint_list(reader, plan)
    rows = []
    for feature in plan.features:
        sources = tuple(
            _source_text(s.topic, s.msgtype, s.strategy, s.stamp, s.fill) for s in feature.sources
        )
        if feature.kind is FeatureKind.VIDEO:
            src = feature.sources[0]
            shape: tuple[int, ...] | None = (*src.resize_hw, 3) if src.resize_hw else None
            if src.topic in first and src.msgtype in VIDEO_TYPES:
                try:  # one packet is no picture (it may not be a key frame): check the codec only
                    video_packet(first[src.topic], src.msgtype)
                except DecodeError as err:
                    raise err.located(uri=bag_uri or "", topic=src.topic, t_ns=0) from err
            elif src.topic in first:
                try:
                    rgb = decode_image(first[src.topic], src.msgtype)
                except DecodeError as err:
                    raise err.located(uri=bag_uri or "", topic=src.topic, t_ns=0) from err
                if src.resize_hw:
                    rgb = resize_image(rgb, *src.resize_hw)
                shape = (int(rgb.shape[0]), int(rgb.shape[1]), image_channels(rgb))
            rows.append(FeatureRow(feature.key, "video", shape, ("height", "width", "channels"), sources))
            continue
        names: list[str] = []
        resolved = True
        for src in feature.sources:
            if src.stream in first:
                try:
                    extractor = make_extractor(src, first[src.stream])
                    extractor(first[src.stream])
                except DecodeError as err:
                    raise _in_contract(err, plan, src, bag_uri or "") from err
                names.extend(extractor.names)
            elif src.names:
                names.extend(src.names)
            else:
                resolved = False
        shape_v = (len(names),) if resolved else None
        rows.append(
            FeatureRow(feature.key, feature.dtype, shape_v, tuple(names) if resolved else None, sources)
        )
    return rows


_JOINT_LIST_MESSAGES = 400
"""Messages of a JointState topic read by index that ``contract check`` compares (each publisher sends at
every cycle of its driver, so a second one shows within the first few)."""


def _check_one_joint_list(reader: BagReader, plan: ContractPlan) -> None:
    """A JointState topic an entry reads by index alone must name one joint list in all its messages."""
    entries = plan.one_joint_list_topics()
    for topic, lists in joint_lists(reader, tuple(entries), _JOINT_LIST_MESSAGES).items():
        if len(lists) > 1:
            src = entries[topic]
            raise ContractError(
                mixed_joint_lists(topic, lists[0], lists[1], f"{src.section}[key={src.key}]")
                + f" (in {reader.info.uri})",
                file=plan.source_name,
                line=src.line,
                field=f"{src.section}[key={src.key}].selector.names",
                fix=MIXED_JOINT_LISTS_FIX,
            )


def _first_messages(reader: BagReader, plan: ContractPlan) -> dict[str, object]:
    """The first message of every stream (a filtered stream's first sample: a TF stream's first message
    carrying its transform)."""
    tests = sample_tests(plan.stream_filters())
    wanted = set(plan.streams())
    first: dict[str, object] = {}
    for message in reader.messages(tuple(dict.fromkeys(s.topic for s in plan.sources))):
        for stream in wanted - first.keys():
            test = tests.get(stream)
            sample = (
                stream == message.topic
                if test is None
                else test.spec.topic == message.topic and test.carries(message)
            )
            if sample:
                first[stream] = message.msg()
        if len(first) == len(wanted):
            break
    for src in plan.sources:
        test = tests.get(src.stream)
        if test is not None and src.stream not in first:
            raise ContractError(
                f"no message on {src.topic} in {reader.info.uri} carries {test.wanted()} ({test.seen_text()})",
                file=plan.source_name,
                line=src.line,
                field=f"{src.section}[key={src.key}].{test.field}",
                fix=test.fix(),
            )
    return first


def _in_contract(err: DecodeError, plan: ContractPlan, src: SourceSpec, bag_uri: str) -> ContractError:
    """A selector that does not fit the bag's messages is a contract mistake: say where it is."""
    return ContractError(
        f"{err.what} (first message on {src.topic} in {bag_uri})",
        file=plan.source_name,
        line=src.line,
        field=f"{src.section}[key={src.key}].selector",
        fix=err.fix,
    )


def format_feature_table(plan: ContractPlan, rows: list[FeatureRow]) -> str:
    lines = [f"robot_type: {plan.robot_type}   fps: {plan.fps}   features: {len(rows)}"]
    for row in rows:
        shape = list(row.shape) if row.shape is not None else "from the bag"
        lines.append(f"  {row.key}  {row.dtype}  shape={shape}")
        if row.names and row.dtype != "video":
            lines.append(f"      names: {', '.join(row.names)}")
        lines.extend(f"      <- {source}" for source in row.sources)
    if plan.task_topics:
        lines.append("  task  <- " + ", ".join(t.topic for t in plan.task_topics))
    if (episodes := _episodes_text(plan)) is not None:
        lines.append(f"  episodes  <- {episodes}")
    return "\n".join(lines)


def _episodes_text(plan: ContractPlan) -> str | None:
    """How the contract splits bags, e.g. ``events /episode_events (std_msgs/msg/String), gap_s 2,
    min_duration_s 1``; ``None`` when it does not split them."""
    options = plan.contract.episodes
    if options is None:
        return None
    parts = [
        f"{name} {spec.topic} ({spec.type})"
        for name, spec in (("events", options.events), ("done_signal", options.done_signal))
        if spec is not None
    ]
    if options.gap_s is not None:
        parts.append(f"gap_s {options.gap_s:g}")
    if not parts:
        return None
    return ", ".join(parts) + f", min_duration_s {options.min_duration_s:g}"
