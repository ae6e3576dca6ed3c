"""Writing small bags of arbitrary message types for decoder tests (rosbags writers)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys.store import Typestore

Stream = tuple[str, str, Sequence[tuple[int, Any]]]
"""``(topic, msgtype, [(log_ns, message), ...])``."""


def write_bag(
    path: Path, storage: Literal["mcap", "sqlite3", "ros1"], store: Typestore, streams: Sequence[Stream]
) -> Path:
    """One bag holding every stream; messages are written in time order."""
    events = sorted(
        (
            (t_ns, i, topic, msgtype, msg)
            for i, (topic, msgtype, msgs) in enumerate(streams)
            for t_ns, msg in msgs
        ),
        key=lambda e: (e[0], e[1]),
    )
    if storage == "ros1":
        path = path.with_suffix(".bag")
        with Writer1(path) as writer1:
            conns1 = {
                topic: writer1.add_connection(topic, msgtype, typestore=store)
                for topic, msgtype, _ in streams
            }
            for t_ns, _, topic, msgtype, msg in events:
                writer1.write(conns1[topic], t_ns, store.serialize_ros1(msg, msgtype))
        return path
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        conns = {
            topic: writer.add_connection(topic, msgtype, typestore=store) for topic, msgtype, _ in streams
        }
        for t_ns, _, topic, msgtype, msg in events:
            writer.write(conns[topic], t_ns, store.serialize_cdr(msg, msgtype))
    return path
