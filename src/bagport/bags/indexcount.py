"""How many messages a bag's own index promises per topic inside a time window.

The short-read check of a windowed read compares what the reader yielded in
``[start_ns, stop_ns)`` with these counts. Each storage answers from its index, without
reading message data:

- MCAP with chunks: chunks wholly inside the window count from the chunk index; a chunk
  straddling an edge counts the log times of its message index (16 bytes per message).
- SQLite: ``COUNT(*)`` over the topic's rows in the timestamp range.
- ROS 1: the connection's index entries (one per message, with its time).

An MCAP written without chunks has no message index: its topics get no count (unchecked).

:func:`index_time_range` gives the first and last log time the data files' own indexes hold (rosbags
takes a rosbag2 folder's times from its ``metadata.yaml``, which can be stale).
"""

from __future__ import annotations

import struct
from bisect import bisect_left
from collections import Counter
from collections.abc import Collection, Iterator
from typing import Any

import numpy as np
from rosbags.rosbag1 import Reader as Ros1Reader
from rosbags.rosbag2.reader import DirectoryReader
from rosbags.rosbag2.storage_mcap import McapReader
from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader

__all__ = ["UNBOUNDED_NS", "index_time_range", "window_counts"]

UNBOUNDED_NS = 2**63 - 1
_MESSAGE_INDEX = 0x07
_INDEX_HEAD = struct.Struct("<BQHI")  # opcode, record length, channel id, records byte length


def _storages(reader: Any) -> Iterator[Any]:
    """The readers that own the data files (and their indexes) under rosbags' AnyReader."""
    for sub in reader.readers:
        if isinstance(sub, Ros1Reader):
            yield sub
        elif isinstance(sub.storage, DirectoryReader):
            yield from sub.storage.storages
        else:
            yield sub.storage


def _timestamp_indexed(conn: Any) -> bool:
    """Whether an index of ``messages`` starts with ``timestamp`` (rosbag2's ``timestamp_idx``), so its
    least and greatest value are each one lookup."""
    for row in conn.execute("PRAGMA index_list(messages)"):
        name = str(row[1]).replace('"', '""')
        columns = [info[2] for info in conn.execute(f'PRAGMA index_info("{name}")')]
        if columns[:1] == ["timestamp"]:
            return True
    return False


def _sqlite_time_range(storage: Sqlite3Reader) -> tuple[int, int] | None:
    """The first and last ``messages.timestamp`` (``(UNBOUNDED_NS, -1)``: no message), when an index that
    starts with it answers (two lookups: a single query of both reads the whole index); else ``None``."""
    if storage.dbconn is None:
        raise ValueError("the SQLite storage is closed")
    if not _timestamp_indexed(storage.dbconn):
        return None
    ((first, last),) = storage.dbconn.execute(
        "SELECT (SELECT MIN(timestamp) FROM messages), (SELECT MAX(timestamp) FROM messages)"
    )
    return (UNBOUNDED_NS, -1) if first is None else (int(first), int(last))


def index_time_range(reader: Any) -> tuple[int, int] | None:
    """``(first, last)`` log time (ns) of the messages of a rosbag2 bag (rosbags' AnyReader ``reader``)
    from its data files' indexes (MCAP statistics or chunk indexes, SQLite's timestamp index); ``None`` for
    a ROS 1 bag (rosbags reads its times from its data already), an empty bag, or a file that cannot say."""
    first, last = UNBOUNDED_NS, -1
    for storage in _storages(reader):
        if isinstance(storage, McapReader):
            statistics = storage.statistics
            if statistics is None:
                return None
            found = (statistics.start_time, statistics.end_time) if statistics.message_count else None
        elif isinstance(storage, Sqlite3Reader):
            found = _sqlite_time_range(storage)
            if found is None:
                return None
        else:
            return None
        if found is not None:
            first, last = min(first, found[0]), max(last, found[1])
    return (first, last) if last >= 0 else None


def _mcap_in_window(bio: Any, offset: int, start_ns: int, stop_ns: int) -> int:
    """Messages of one channel's message index record (at ``offset``) logged in the window."""
    bio.seek(offset)
    head = bio.read(_INDEX_HEAD.size)
    opcode, _, _, size = _INDEX_HEAD.unpack(head)
    if opcode != _MESSAGE_INDEX:
        raise ValueError(f"no message index at offset {offset} (opcode {opcode:#04x})")
    entries = np.frombuffer(bio.read(size), dtype="<u8").reshape(-1, 2)
    log_ns = entries[:, 0]
    return int(np.count_nonzero((log_ns >= start_ns) & (log_ns < stop_ns)))


def _mcap_counts(
    storage: McapReader, cids: Collection[int], start_ns: int, stop_ns: int
) -> Counter[int] | None:
    if not storage.chunks:
        return None  # unchunked: no message index
    counts: Counter[int] = Counter()
    for chunk in storage.chunks:
        if chunk.message_end_time < start_ns or chunk.message_start_time >= stop_ns:
            continue
        inside = start_ns <= chunk.message_start_time and chunk.message_end_time < stop_ns
        for cid in cids:
            if not chunk.channel_count.get(cid, 0):
                continue
            counts[cid] += (
                chunk.channel_count[cid]
                if inside
                else _mcap_in_window(storage.bio, chunk.message_index_offsets[cid], start_ns, stop_ns)
            )
    return counts


def _sqlite_counts(
    storage: Sqlite3Reader, cids: Collection[int], start_ns: int, stop_ns: int
) -> Counter[int]:
    if storage.dbconn is None:
        raise ValueError("the SQLite storage is closed")
    counts: Counter[int] = Counter()
    for cid in cids:
        ((count,),) = storage.dbconn.execute(
            "SELECT COUNT(*) FROM messages WHERE topic_id = ? AND timestamp >= ? AND timestamp < ?",
            (cid, start_ns, stop_ns),
        )
        counts[cid] = int(count)
    return counts


def _ros1_counts(reader: Ros1Reader, cids: Collection[int], start_ns: int, stop_ns: int) -> Counter[int]:
    counts: Counter[int] = Counter()
    for cid in cids:
        entries = reader.indexes[cid]
        first = bisect_left(entries, start_ns, key=lambda e: e.time)
        counts[cid] = bisect_left(entries, stop_ns, key=lambda e: e.time) - first
    return counts


def window_counts(
    reader: Any, connections: Collection[Any], start_ns: int | None, stop_ns: int | None
) -> dict[str, int]:
    """``{topic: messages its index promises in [start_ns, stop_ns)}`` for the topics of
    ``connections`` (connections of rosbags' AnyReader ``reader``) every data file can count.

    Raises ``OSError`` / ``ValueError`` when an index the file points at cannot be read.
    """
    start = 0 if start_ns is None else start_ns
    stop = UNBOUNDED_NS if stop_ns is None else stop_ns
    wanted = {(c.topic, c.msgtype) for c in connections}
    totals: Counter[str] = Counter({topic: 0 for topic, _ in wanted})
    uncounted: set[str] = set()
    for storage in _storages(reader):
        topic_of = {c.id: c.topic for c in storage.connections if (c.topic, c.msgtype) in wanted}
        if not topic_of:
            continue
        counts: Counter[int] | None
        if isinstance(storage, McapReader):
            counts = _mcap_counts(storage, topic_of, start, stop)
        elif isinstance(storage, Sqlite3Reader):
            counts = _sqlite_counts(storage, topic_of, start, stop)
        elif isinstance(storage, Ros1Reader):
            counts = _ros1_counts(storage, topic_of, start, stop)
        else:
            counts = None
        if counts is None:
            uncounted.update(topic_of.values())
            continue
        for cid, count in counts.items():
            totals[topic_of[cid]] += count
    return {topic: count for topic, count in totals.items() if topic not in uncounted}
