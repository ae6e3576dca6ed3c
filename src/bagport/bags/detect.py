"""Tell a bag's format from its content, not its name."""

from __future__ import annotations

from pathlib import Path

from bagport.bags.metadata_yaml import read_metadata
from bagport.bags.records import Storage
from bagport.bags.remote import RemotePath
from bagport.errors import BagReadError

__all__ = ["MCAP_MAGIC", "detect_storage", "storage_by_content"]

ROS1_MAGIC = b"#ROSBAG V2.0"
MCAP_MAGIC = b"\x89MCAP0\r\n"
SQLITE_MAGIC = b"SQLite format 3\x00"


def _storage_of_head(head: bytes) -> Storage | None:
    if head.startswith(ROS1_MAGIC):
        return Storage.ROS1
    if head.startswith(MCAP_MAGIC):
        return Storage.MCAP
    if head.startswith(SQLITE_MAGIC):
        return Storage.SQLITE3
    return None


def storage_by_content(path: Path | RemotePath) -> Storage | None:
    """The storage a file's first bytes say, whatever its name; ``None`` when they say none."""
    try:
        with path.open("rb") as handle:
            return _storage_of_head(handle.read(16))
    except OSError:
        return None


def _file_storage(path: Path | RemotePath, uri: str) -> Storage:
    try:
        with path.open("rb") as handle:
            head = handle.read(16)
    except OSError as err:
        raise BagReadError(f"cannot be read ({err})", uri=uri) from err
    if not head:
        raise BagReadError(
            "is an empty file, not a bag", uri=uri, fix="re-copy the bag; the file has no data."
        )
    storage = _storage_of_head(head)
    if storage is not None:
        return storage
    if head.startswith(b"#ROSBAG"):
        raise BagReadError(
            f"is a ROS 1 bag of an unsupported version ({head[:13]!r})",
            uri=uri,
            fix="migrate it with `rosbag fix` to format 2.0.",
        )
    raise BagReadError(
        "is not a ROS bag (no ROS 1, MCAP or SQLite signature at its start)",
        uri=uri,
        fix="point the manifest at a rosbag2 folder, an .mcap, a .db3 or a ROS 1 .bag.",
    )


def detect_storage(path: Path | RemotePath, uri: str) -> Storage:
    """Storage of a bag: a single file or a rosbag2 folder by the magic of its (first) data file, by
    ``metadata.yaml`` only when the files are compressed whole; the layout warns when the two disagree."""
    if not path.exists():
        raise BagReadError(
            "does not exist", uri=uri, fix="check the manifest uri (relative to the manifest file)."
        )
    if path.is_file():
        return _file_storage(path, uri)
    if not path.is_dir():
        raise BagReadError(
            "is neither a file nor a folder (a device, a pipe or a socket)",
            uri=uri,
            fix="point the manifest at a rosbag2 folder, an .mcap, a .db3 or a ROS 1 .bag.",
        )
    info = read_metadata(path, uri) or {}
    storage_id = str(info.get("storage_identifier", ""))
    try:
        listed: list[Path | RemotePath] = list(path.iterdir())
    except OSError as err:
        raise BagReadError(
            f"is a folder that cannot be listed ({err.strerror or err})",
            uri=uri,
            fix="give bagport's user read access to the folder, or copy the bag somewhere it can read.",
        ) from err
    files = sorted((p for p in listed if p.suffix in (".mcap", ".db3") and p.is_file()), key=lambda p: p.name)
    if not files and storage_id in (Storage.MCAP, Storage.SQLITE3):
        return Storage(storage_id)  # files compressed whole (.mcap.zstd): their content cannot tell
    if not files:
        ros1 = sorted(p.name for p in listed if p.suffix == ".bag" and p.is_file())
        if ros1:
            raise BagReadError(
                f"is a folder of {len(ros1)} ROS 1 bag(s) ({', '.join(ros1[:5])}{', ...' if len(ros1) > 5 else ''}), "
                "not one recording (a ROS 1 recording is one .bag file)",
                uri=uri,
                fix="list each .bag in the manifest, or convert them all with --glob 'FOLDER/*.bag'.",
            )
        raise BagReadError(
            "is a folder without metadata.yaml, .mcap or .db3 files",
            uri=uri,
            fix="point the manifest at a rosbag2 folder or at the bag file itself.",
        )
    if storage_id in (Storage.MCAP, Storage.SQLITE3) and not _has_magic(files[0]):
        raise BagReadError(
            f"{files[0].name} has no ROS 1, MCAP or SQLite signature at its start (its first 16 bytes are "
            f"damaged; metadata.yaml says {storage_id})",
            uri=uri,
            fix="copy the bag again from the robot or a backup.",
        )
    return _file_storage(files[0], uri)


def _has_magic(path: Path | RemotePath) -> bool:
    try:
        with path.open("rb") as handle:
            head = handle.read(16)
    except OSError:
        return True  # unreadable: _file_storage reports it
    return head.startswith((ROS1_MAGIC, MCAP_MAGIC, SQLITE_MAGIC))
