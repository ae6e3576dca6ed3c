"""Which files of a bag rosbags should open, and under which names.

Real recordings are messier than the ones we write: a rosbag2 folder may be named
``*.bag``, a single file may have no suffix, a split recording may come without its
``metadata.yaml``, or with one whose storage id is empty or whose file list does not
match the folder. The plan reads what is there: a consistent rosbag2 folder is handed
to rosbags whole (it honours compression, counts and custom data); anything else is read
as the data files present, merged in log-time order, with a warning saying why. One thing
is refused: a ``metadata.yaml`` listing data files the folder lacks (an incomplete recording).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path, PurePath
from typing import Any

from bagport.bags.detect import storage_by_content
from bagport.bags.metadata_yaml import read_metadata
from bagport.bags.records import Storage
from bagport.bags.remote import RemotePath
from bagport.errors import BagReadError

__all__ = ["ReadPlan", "plan_reads"]

SUFFIX = {Storage.ROS1: ".bag", Storage.MCAP: ".mcap", Storage.SQLITE3: ".db3"}
_DATA_SUFFIXES = (".mcap", ".db3", ".mcap.zstd", ".db3.zstd")

BagPath = Path | RemotePath


@dataclass
class ReadPlan:
    paths: list[Any]
    """What rosbags' AnyReader opens (``Path`` or :class:`RemotePath`)."""
    files: list[BagPath]
    """Every file of the bag (for names and sizes)."""
    data_files: list[BagPath]
    """The files holding messages, in split order (for readers other than rosbags)."""
    warnings: list[str] = field(default_factory=list)
    message_compression: bool = False
    """Payloads are zstd-compressed one by one and rosbags does not know (metadata bypassed)."""
    custom_data: dict[str, str] = field(default_factory=dict)
    """``metadata.yaml``'s ``custom_data`` (``{}`` without one, or when it is not a mapping)."""
    metadata_yaml: bool = False
    """The bag is a folder with a ``metadata.yaml`` (read or bypassed): it promises what the files hold."""


def _natural_key(path: BagPath) -> list[Any]:
    """``rec_2.mcap`` before ``rec_10.mcap``, as rosbag2 numbers its splits."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name)]


def _alias(path: BagPath, name: str, scratch: Callable[[], Path]) -> Any:
    """``path`` presented as ``name`` (rosbags picks its reader by suffix); ``scratch`` gives the folder
    for the link (made when first asked)."""
    if isinstance(path, RemotePath):
        return path.renamed(name)
    link = scratch() / name
    link.symlink_to(path.resolve(), target_is_directory=path.is_dir())
    return link


def _data_files(folder: BagPath) -> list[BagPath]:
    files = [p for p in folder.iterdir() if p.name.endswith(_DATA_SUFFIXES) and p.is_file()]
    return sorted(files, key=_natural_key)


def _listed(metadata: dict[str, Any]) -> list[str]:
    """The data files ``metadata.yaml`` lists, by name."""
    return [PurePath(str(x)).name for x in metadata.get("relative_file_paths") or []]


def _metadata_problem(metadata: dict[str, Any], present: list[BagPath], storage: Storage) -> str | None:
    storage_id = str(metadata.get("storage_identifier") or "")
    if storage_id not in (Storage.MCAP, Storage.SQLITE3):
        return f"metadata.yaml has storage id {storage_id!r}"
    content = [p.name for p in present if p.suffix == SUFFIX[storage]]
    if storage_id != storage and content:
        return (
            f"metadata.yaml says storage_identifier: {storage_id}, but {content[0]} is {storage} by its content "
            f"(Fix: set storage_identifier: {storage} in metadata.yaml, or re-create it with `ros2 bag reindex`)"
        )
    listed = _listed(metadata)
    names = [p.name for p in present]
    if sorted(listed) != sorted(names):
        return f"metadata.yaml lists {listed} but the folder has {names}"
    return None


def _custom_data(metadata: dict[str, Any]) -> dict[str, str]:
    data = metadata.get("custom_data")
    return {str(k): str(v) for k, v in data.items()} if isinstance(data, dict) else {}


def _other_recording(metadata: dict[str, Any], present: list[BagPath], storage: Storage) -> list[BagPath]:
    """Data files of the other storage (by suffix and content) that ``metadata.yaml`` does not list, beside a
    recording of the ``storage`` it names: not part of it, as rosbag2 reads only the files it lists."""
    if str(metadata.get("storage_identifier") or "") != storage:
        return []
    listed = set(_listed(metadata))
    others = [p for p in present if p.suffix in SUFFIX.values() and p.suffix != SUFFIX[storage]]
    return [p for p in others if p.name not in listed and storage_by_content(p) not in (storage, None)]


def _ignoring(ignored: list[BagPath], storage: Storage) -> list[str]:
    if not ignored:
        return []
    names = ", ".join(p.name for p in ignored)
    return [
        f"{names} ignored: not part of the {storage} recording metadata.yaml describes (Fix: move it out of "
        "the bag folder)"
    ]


def _refuse_missing_files(metadata: dict[str, Any], present: list[BagPath], uri: str) -> None:
    """A recording whose ``metadata.yaml`` lists more data files than the folder holds, some of them absent,
    is incomplete (a split file lost, or a copy not finished): converted, it would be a shorter episode that
    looks whole. Fewer files is the test, so a folder whose files were renamed still reads (with a warning)."""
    listed = _listed(metadata)
    names = {p.name for p in present}
    missing = [name for name in listed if name not in names]
    if missing and len(present) < len(listed):
        raise BagReadError(
            f"metadata.yaml lists {len(listed)} data file(s) but the folder holds {len(present)}: {missing} "
            "missing, so the recording is incomplete (a split file was lost, or the copy has not finished)",
            uri=uri,
            fix="copy the missing file(s) from the robot or its backup; to convert only the files present, "
            "remove metadata.yaml from the folder (bagport then reads the data files it finds).",
        )


def plan_reads(path: BagPath, storage: Storage, scratch: Callable[[], Path], uri: str) -> ReadPlan:
    """The paths to open for a bag at ``path`` whose content is ``storage``; ``scratch`` gives a folder for
    the links that rename a file (only asked for when one is needed)."""
    suffix = SUFFIX[storage]
    if path.is_file():
        opened = path if path.suffix == suffix else _alias(path, f"bag{suffix}", scratch)
        return ReadPlan([opened], [path], [path])
    present = _data_files(path)
    metadata = read_metadata(path, uri)
    if metadata is not None:
        ignored = _other_recording(metadata, present, storage)
        present = [p for p in present if p not in ignored]
        _refuse_missing_files(metadata, present, uri)
        problem = _metadata_problem(metadata, present, storage)
        if problem is None:
            folder = _alias(path, "bag", scratch) if path.suffix == ".bag" else path
            return ReadPlan(
                [folder], [*present, path / "metadata.yaml"], present, _ignoring(ignored, storage),
                custom_data=_custom_data(metadata), metadata_yaml=True,
            )  # fmt: skip
        mode = str(metadata.get("compression_mode") or "").lower()
        if mode == "file":
            raise BagReadError(
                f"{problem}, and its files are compressed whole (compression_mode file)",
                uri=uri,
                fix="fix relative_file_paths and storage_identifier in metadata.yaml to match the folder.",
            )
        usable, renamed = _usable(present, storage, uri)
        warning = f"{problem}; reading the {len(usable)} {storage} file(s) present instead{renamed.said}"
        return ReadPlan(
            renamed.opened(usable, scratch),
            [*present, path / "metadata.yaml"],
            usable,
            [*_ignoring(ignored, storage), warning],
            message_compression=mode == "message",
            custom_data=_custom_data(metadata),
            metadata_yaml=True,
        )
    usable, renamed = _usable(present, storage, uri)
    return ReadPlan(renamed.opened(usable, scratch), list(present), usable, renamed.warnings())


@dataclass(frozen=True, slots=True)
class _Renamed:
    """Data files whose name says another storage than their content (read by their content)."""

    names: tuple[str, ...]
    suffix: str

    @property
    def said(self) -> str:
        return f" ({', '.join(self.names)} read as {self.suffix} by their content)" if self.names else ""

    def warnings(self) -> list[str]:
        return [f"data file(s) named for another storage{self.said}"] if self.names else []

    def opened(self, usable: list[BagPath], scratch: Callable[[], Path]) -> list[Any]:
        """What rosbags opens: each misnamed file behind a link with the right suffix (it goes by suffix)."""
        return [_alias(p, f"{p.name}{self.suffix}", scratch) if p.name in self.names else p for p in usable]


def _usable(present: list[BagPath], storage: Storage, uri: str) -> tuple[list[BagPath], _Renamed]:
    """The data files of ``storage``: by their suffix, or by their content when the suffix says another."""
    suffix = SUFFIX[storage]
    usable = [p for p in present if p.suffix == suffix or storage_by_content(p) == storage]
    if not usable:
        raise BagReadError(
            f"has no {suffix} files (found {[p.name for p in present]})",
            uri=uri,
            fix="point the manifest at a rosbag2 folder or at the bag file itself.",
        )
    return usable, _Renamed(tuple(p.name for p in usable if p.suffix != suffix), suffix)
