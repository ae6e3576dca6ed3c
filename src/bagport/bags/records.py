"""Value types shared by every bag reader."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

__all__ = ["BagInfo", "Storage", "TopicInfo"]


class Storage(StrEnum):
    MCAP = "mcap"
    SQLITE3 = "sqlite3"
    ROS1 = "ros1"


@dataclass(frozen=True, slots=True)
class TopicInfo:
    name: str
    msgtype: str
    """ROS 2 style (``sensor_msgs/msg/Image``) for ROS 1 bags too."""
    count: int
    first_log_ns: int | None = None
    """Not filled from the index (rosbags does not expose it cheaply); ``None``."""
    last_log_ns: int | None = None


@dataclass(frozen=True, slots=True)
class BagInfo:
    uri: str
    storage: Storage
    files: tuple[str, ...]
    size_bytes: int
    start_ns: int
    end_ns: int
    message_count: int
    topics: tuple[TopicInfo, ...]
    custom_data: dict[str, str] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    """What was odd about the bag and how it was read anyway (e.g. a stale metadata.yaml)."""

    @property
    def duration_ns(self) -> int:
        return max(0, self.end_ns - self.start_ns)

    def topic(self, name: str) -> TopicInfo | None:
        return next((t for t in self.topics if t.name == name), None)

    def to_dict(self) -> dict[str, Any]:
        return {
            "uri": self.uri,
            "storage": str(self.storage),
            "files": list(self.files),
            "size_bytes": self.size_bytes,
            "start_ns": self.start_ns,
            "end_ns": self.end_ns,
            "message_count": self.message_count,
            "topics": [{"name": t.name, "msgtype": t.msgtype, "count": t.count} for t in self.topics],
            "warnings": list(self.warnings),
        }
