"""Re-record a synthetic rosbag2 bag as a split recording (several storage files, one metadata.yaml),
as ``ros2 bag record --max-bag-duration`` writes them."""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from typing import Any

import yaml
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Ros2Writer
from rosbags.typesys import Stores, get_typestore

__all__ = ["split_recording"]

_INFO = "rosbag2_bagfile_information"


def split_recording(src: Path, dst: Path, cuts_ns: list[int]) -> list[Path]:
    """Copy the rosbag2 folder ``src`` to ``dst`` as one MCAP file per span between ``cuts_ns`` (log time)."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    bounds = [*sorted(cuts_ns), None]
    scratch = Path(tempfile.mkdtemp(prefix="bagport-split-"))
    dst.mkdir(parents=True)
    files: list[Path] = []
    infos: list[dict[str, Any]] = []
    try:
        with AnyReader([src], default_typestore=store) as reader:
            custom = yaml.safe_load((src / "metadata.yaml").read_text())[_INFO].get("custom_data") or {}
            start: int | None = None
            for index, stop in enumerate(bounds):
                part = scratch / f"part_{index}"
                writer = Ros2Writer(part, version=9, storage_plugin=StoragePlugin.MCAP)
                writer.open()
                for key, value in custom.items():
                    writer.set_custom_data(key, value)
                conns = {
                    c.topic: writer.add_connection(c.topic, c.msgtype, typestore=store)
                    for c in reader.connections
                }
                for conn, log_ns, raw in reader.messages(start=start, stop=stop):
                    writer.write(conns[conn.topic], log_ns, raw)
                writer.close()
                target = dst / f"{dst.name}_{index}.mcap"
                shutil.move(next(part.glob("*.mcap")), target)
                files.append(target)
                infos.append(yaml.safe_load((part / "metadata.yaml").read_text())[_INFO])
                start = stop
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    merged = dict(infos[0])
    merged["relative_file_paths"] = [f.name for f in files]
    merged["files"] = [{**info["files"][0], "path": f.name} for info, f in zip(infos, files, strict=True)]
    merged["message_count"] = sum(int(info["message_count"]) for info in infos)
    first = min(int(info["starting_time"]["nanoseconds_since_epoch"]) for info in infos)
    last = max(
        int(info["starting_time"]["nanoseconds_since_epoch"]) + int(info["duration"]["nanoseconds"])
        for info in infos
    )
    merged["starting_time"] = {"nanoseconds_since_epoch": first}
    merged["duration"] = {"nanoseconds": last - first}
    topics = merged["topics_with_message_count"]
    for entry in topics:
        name = entry["topic_metadata"]["name"]
        entry["message_count"] = sum(
            t["message_count"] for info in infos for t in info["topics_with_message_count"]
            if t["topic_metadata"]["name"] == name
        )  # fmt: skip
    (dst / "metadata.yaml").write_text(yaml.safe_dump({_INFO: merged}, sort_keys=False))
    return files
