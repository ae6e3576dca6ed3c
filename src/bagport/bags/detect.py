"""Tell a bag's format from its content, not its name."""

from __future__ import annotations

from pathlib import Path

from bagport.bags.metadata_yaml import read_metadata
from bagport.bags.records import ZSTD_FRAME_MAGIC, Storage
from bagport.bags.remote import RemotePath
from bagport.errors import BagReadError

__all__ = ["MCAP_MAGIC", "ROS1_MAGIC", "detect_storage", "storage_by_content"]

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
    if head.startswith(ZSTD_FRAME_MAGIC):
        raise BagReadError(
            "is compressed whole with zstd (rosbag2's compression_mode: file writes .mcap.zstd and .db3.zstd files, "
            "which the bag's metadata.yaml describes)",
            uri=uri,
            fix="give the bag's folder (its metadata.yaml beside the file), or decompress the file (`zstd -d FILE`) "
            "and give the result.",
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
    metadata = read_metadata(path, uri)
    info = metadata or {}
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
    first = _first_of_the_recording(files, storage_id, uri, has_metadata=metadata is not None)
    if storage_id in (Storage.MCAP, Storage.SQLITE3) and not _has_magic(first):
        raise BagReadError(
            f"{first.name} has no ROS 1, MCAP or SQLite signature at its start (its first 16 bytes are "
            f"damaged; metadata.yaml says {storage_id})",
            uri=uri,
            fix="copy the bag again from the robot or a backup.",
        )
    return _file_storage(first, uri)


def _first_of_the_recording(
    files: list[Path | RemotePath], storage_id: str, uri: str, *, has_metadata: bool
) -> Path | RemotePath:
    """The data file whose content tells the storage. A folder holding MCAP and SQLite files (by their
    content) is the storage its ``metadata.yaml`` names (the layout warns that the others are ignored), as
    rosbag2 reads it; without one naming either, which is the recording is unknown, so it is refused."""
    by_suffix: dict[str, Path | RemotePath] = {}
    for path in files:
        by_suffix.setdefault(path.suffix, path)
    if len(by_suffix) < 2:
        return files[0]
    by_content = {storage_by_content(path): path for path in by_suffix.values()}
    if Storage.MCAP not in by_content or Storage.SQLITE3 not in by_content:
        return files[0]  # a file named for another storage: read by its content
    if storage_id in by_content:
        return by_content[Storage(storage_id)]
    said = (
        f"its metadata.yaml names neither (storage_identifier {storage_id!r})"
        if has_metadata
        else ("no metadata.yaml says which is the recording")
    )
    raise BagReadError(
        f"holds both MCAP ({_names(files, '.mcap')}) and SQLite ({_names(files, '.db3')}) data files, and {said}",
        uri=uri,
        fix="move the files that are not part of this recording out of the folder, or write its metadata.yaml "
        "with `ros2 bag reindex FOLDER -s mcap` (or `-s sqlite3`).",
    )


def _names(files: list[Path | RemotePath], suffix: str) -> str:
    names = [path.name for path in files if path.suffix == suffix]
    return ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")


def _has_magic(path: Path | RemotePath) -> bool:
    try:
        with path.open("rb") as handle:
            head = handle.read(16)
    except OSError:
        return True  # unreadable: _file_storage reports it
    return head.startswith((ROS1_MAGIC, MCAP_MAGIC, SQLITE_MAGIC))
