"""A damaged bag as one error: what failed, where (file and byte offset, or the last intact message),
the topics concerned, and the fix. Never the storage library's exception on its own."""

from __future__ import annotations

import re
import sqlite3
import struct
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import apsw
from backports import zstd
from rosbags.highlevel import AnyReaderError
from rosbags.rosbag1 import ReaderError as Ros1ReaderError
from rosbags.rosbag2 import ReaderError as Ros2ReaderError

from bagport.bags.locate import locate_damage
from bagport.bags.mcap_layout import FIX as MCAP_FIX
from bagport.bags.records import Storage
from bagport.bags.remote import RemotePath
from bagport.bags.sqlite_tail import salvage
from bagport.bags.typeload import one_line
from bagport.errors import BagReadError

__all__ = ["STORAGE_ERRORS", "checked_records", "damaged_bag", "short_read"]

STORAGE_ERRORS = (
    AnyReaderError,
    Ros1ReaderError,
    Ros2ReaderError,
    apsw.Error,
    sqlite3.Error,
    OSError,
    ValueError,
    KeyError,
    IndexError,
    EOFError,
    AssertionError,  # rosbags checks a ROS 1 record against its index with assert
    RuntimeError,  # lz4 decompression
    TypeError,  # a damaged QoS or metadata string parsed as the wrong shape
    OverflowError,  # a damaged length seeks past what the OS can address
    MemoryError,  # a damaged length asks for an impossible read (fails before allocating)
    struct.error,
    zstd.ZstdError,
)
"""What rosbags and the storage libraries under it raise on a damaged or truncated bag."""

_REINDEX_SHORT = "reindex it (`ros2 bag reindex` / `rosbag reindex`)."
_REINDEX = "reindex the bag (`rosbag reindex` for ROS 1, `ros2 bag reindex` for rosbag2)."
_ROS1_FIX = (
    "copy the bag again from the robot or a backup; if only its index is damaged (the messages are intact), "
    "`rosbag reindex` rebuilds it."
)
_NOT_INDEXED = re.compile(r"\b(not indexed|index(es)? (is|are) (missing|damaged|corrupt))\b", re.IGNORECASE)
"""The reader's words for a missing or broken index, which a reindex rebuilds (never for MCAP: its
summary holds the index, and `ros2 bag reindex` rewrites only metadata.yaml)."""

BagFile = Path | RemotePath


def _fix(storage: Storage, *, metadata_yaml: bool) -> str:
    """The storage's usual fix for damage; ``metadata_yaml``: the bag is a folder with one."""
    if storage is Storage.SQLITE3:
        return f"copy the bag again from the robot or a backup; without one, {salvage(metadata_yaml=metadata_yaml)}."
    return MCAP_FIX if storage is Storage.MCAP else _ROS1_FIX


def _one_line(err: BaseException) -> str:
    text = one_line(err, limit=1000)
    return (
        f"{type(err).__name__}: {text}"
        if text and not isinstance(err, BagReadError)
        else text or type(err).__name__
    )


def damaged_bag(
    err: BaseException,
    *,
    uri: str,
    storage: Storage,
    files: Iterable[BagFile],
    action: str,
    metadata_yaml: bool,
    last: tuple[str, int] | None = None,
) -> BagReadError:
    """The error for a bag whose ``action`` ("cannot be opened", "reading failed") raised ``err``;
    walks ``files`` to name the damaged record. ``last``: (topic, log_ns) of the last intact message;
    ``metadata_yaml``: the bag is a folder with one (the fix for a SQLite file depends on it).

    The library's words appear only when bagport finds nothing itself ("the reader said: ..."): where
    the damage is located, they repeat it less precisely (or mislead, as a damaged length's
    ``OverflowError`` does)."""
    damage = locate_damage(storage, list(files), metadata_yaml=metadata_yaml)
    if damage is not None:
        what = f"{action}: {damage.describe()}"
    else:
        what = f"{action}; the reader said: {_one_line(err)}"
    if last is not None and (damage is None or damage.fix is None):
        what += f"; the last intact message read was on {last[0]} at log time {last[1]} ns"
    topics = damage.topics if damage is not None else ()
    topic = topics[0] if len(topics) == 1 else last[0] if last is not None and not topics else None
    if damage is not None and damage.fix is not None:  # a file cut short is not a changed one
        return BagReadError(what, uri=uri, fix=damage.fix)
    index_only = damage is None and storage is not Storage.MCAP and _NOT_INDEXED.search(str(err)) is not None
    fix = _REINDEX if index_only else _fix(storage, metadata_yaml=metadata_yaml)
    return BagReadError(what, uri=uri, topic=topic, fix=fix)


def short_read(
    what: str, *, uri: str, topic: str, storage: Storage, files: Iterable[BagFile], metadata_yaml: bool
) -> BagReadError:
    """Fewer messages than the index promises: damage when the files show some, else a truncated bag
    or a stale index."""
    damage = locate_damage(storage, list(files), metadata_yaml=metadata_yaml)
    if damage is not None:
        return BagReadError(
            f"{what}; damage found in {damage.describe()}",
            uri=uri,
            topic=topic,
            fix=damage.fix or _fix(storage, metadata_yaml=metadata_yaml),
        )
    return BagReadError(
        what, uri=uri, topic=topic, fix=f"the bag is truncated or its index is stale: {_REINDEX_SHORT}"
    )


def checked_records(
    records: Iterable[tuple[Any, Any, Any]],
    *,
    uri: str,
    storage: Storage,
    files: Iterable[BagFile],
    metadata_yaml: bool,
) -> Iterator[tuple[Any, int, bytes | memoryview]]:
    """rosbags' ``(connection, log_ns, raw)`` records, each checked for its types (a damaged SQLite
    row can hold an integer where the payload belongs); any storage failure becomes :func:`damaged_bag`."""
    last: tuple[str, int] | None = None
    iterator = iter(records)
    while True:
        try:
            record = next(iterator)
        except StopIteration:
            return
        except STORAGE_ERRORS as err:
            raise damaged_bag(
                err,
                uri=uri,
                storage=storage,
                files=files,
                action="reading failed",
                metadata_yaml=metadata_yaml,
                last=last,
            ) from err
        conn, log_ns, raw = record
        if not isinstance(log_ns, int) or not isinstance(raw, bytes | memoryview):
            field, value = ("log time", log_ns) if not isinstance(log_ns, int) else ("payload", raw)
            where = f" after log time {last[1]} ns" if last is not None else ""
            raise BagReadError(
                f"the message record on {conn.topic}{where} is damaged: its {field} is "
                f"a {type(value).__name__}",
                uri=uri,
                topic=conn.topic,
                fix=_fix(storage, metadata_yaml=metadata_yaml),
            )
        last = (conn.topic, log_ns)
        yield conn, log_ns, raw
