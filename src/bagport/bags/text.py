"""Human-readable bag summary, like ``ros2 bag info``."""

from __future__ import annotations

from datetime import UTC, datetime

from bagport.bags.records import BagInfo

__all__ = ["format_bag_info"]


def _size(num_bytes: int) -> str:
    value = float(num_bytes)
    for unit in ("B", "KiB", "MiB", "GiB"):
        if value < 1024 or unit == "GiB":
            return f"{value:.1f} {unit}" if unit != "B" else f"{int(value)} B"
        value /= 1024
    return f"{value:.1f} TiB"


def _time(ns: int) -> str:
    stamp = datetime.fromtimestamp(ns / 1e9, tz=UTC)
    return f"{stamp:%b %d %Y %H:%M:%S}.{ns % 1_000_000_000:09d} UTC ({ns // 1_000_000_000}.{ns % 1_000_000_000:09d})"


def format_bag_info(info: BagInfo) -> str:
    duration_s = info.duration_ns / 1e9
    width = max((len(t.name) for t in info.topics), default=5)
    type_width = max((len(t.msgtype) for t in info.topics), default=4)
    lines = [
        f"Bag:               {info.uri}",
        f"Files:             {', '.join(info.files)}",
        f"Bag size:          {_size(info.size_bytes)}",
        f"Storage id:        {info.storage}",
        f"Duration:          {duration_s:.9f}s",
        f"Start:             {_time(info.start_ns)}",
        f"End:               {_time(info.end_ns)}",
        f"Messages:          {info.message_count}",
        "Topic information:",
    ]
    for topic in info.topics:
        rate = f"{(topic.count - 1) / duration_s:.2f} Hz" if topic.count > 1 and duration_s > 0 else "-"
        lines.append(
            f"  Topic: {topic.name:<{width}} | Type: {topic.msgtype:<{type_width}} | Count: {topic.count:>7} | "
            f"Rate: {rate}"
        )
    for key, value in sorted(info.custom_data.items()):
        lines.append(f"Custom data:       {key}: {value}")
    if info.checksums is not None:
        lines.append(
            f"Checksums:         {'verified on every read: ' if info.checksums.checked else 'none: '}"
            f"{info.checksums.detail}"
        )
    unchecked = info.checksums.warning() if info.checksums is not None else None
    lines.extend(f"Warning:           {warning}" for warning in (*info.warnings, *filter(None, [unchecked])))
    return "\n".join(lines)
