"""Value types shared by every bag reader."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

__all__ = ["ZSTD_FRAME_MAGIC", "BagInfo", "Checksums", "Storage", "TopicInfo", "compressed_whole"]


ZSTD_FRAME_MAGIC = b"\x28\xb5\x2f\xfd"
"""The first bytes of a zstd frame: a data file rosbag2 compressed whole, or a message it compressed alone."""


def compressed_whole(file_name: str) -> bool:
    """A data file rosbag2 compressed whole (``.mcap.zstd``/``.db3.zstd``: ``compression_mode: file``): its
    own format's bytes are only reached through its decompression."""
    return file_name.endswith(".zstd")


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
class Checksums:
    """Whether what is read from a bag is checked against checksums its recorder wrote."""

    checked: bool
    detail: str
    """What protects the bytes (``MCAP chunk CRC-32s``), or why nothing does."""
    fix: str = ""
    """The recorder setting that would add checksums (when ``checked`` is false)."""

    def warning(self) -> str | None:
        """The one-line warning for a bag whose bytes nobody can check, else ``None``."""
        if self.checked:
            return None
        return (
            f"{self.detail}: a flipped bit in a message converts into a different value and nobody can tell. "
            f"Fix: {self.fix}"
        )


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
    checksums: Checksums | None = None
    """Whether reads are checked against the recorder's checksums (``None``: not determined)."""
    listed_span_ns: tuple[int, int] | None = None
    """``(start_ns, end_ns)`` as ``metadata.yaml`` gives them, when they differ from the data files' own
    (:attr:`start_ns`, :attr:`end_ns`); the bag's fingerprint hashes these, as it did before bagport read
    the times from the data files, so a dataset's recorded fingerprints still match."""

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
            "checksums": None
            if self.checksums is None
            else {"checked": self.checksums.checked, "detail": self.checksums.detail},
        }
