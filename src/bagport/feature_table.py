"""What a contract will produce: its feature table, alone or resolved against a bag.

``bagport contract check`` prints this before any conversion starts, so a wrong topic,
type, joint name or field shows up in seconds, with the fix.
"""

from __future__ import annotations

from dataclasses import dataclass

from bagport.bags import open_bag
from bagport.contract import ContractPlan, FeatureKind
from bagport.decode import decode_image, image_channels, make_extractor, resize_image
from bagport.episode.checks import check_bag_fits
from bagport.errors import DecodeError

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


def describe_features(plan: ContractPlan, bag_uri: str | None = None) -> list[FeatureRow]:
    """The feature table; with ``bag_uri`` every topic, type, joint and field is checked against the bag
    and shapes and names are resolved from its first messages."""
    first: dict[str, object] = {}
    if bag_uri is not None:
        with open_bag(bag_uri) as reader:
            check_bag_fits(reader.info, plan)
            wanted = {s.topic for s in plan.sources}
            for message in reader.messages(tuple(wanted)):
                if message.topic not in first:
                    first[message.topic] = message.msg()
                if len(first) == len(wanted):
                    break
    rows = []
    for feature in plan.features:
        sources = tuple(
            _source_text(s.topic, s.msgtype, s.strategy, s.stamp, s.fill) for s in feature.sources
        )
        if feature.kind is FeatureKind.VIDEO:
            src = feature.sources[0]
            shape: tuple[int, ...] | None = (*src.resize_hw, 3) if src.resize_hw else None
            if src.topic in first:
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
            if src.topic in first:
                extractor = make_extractor(src, first[src.topic])
                try:
                    extractor(first[src.topic])
                except DecodeError as err:
                    raise err.located(uri=bag_uri or "", topic=src.topic, t_ns=0) from err
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
    return "\n".join(lines)
