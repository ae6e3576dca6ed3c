"""Does a bag carry checksums that its reads are checked against? If not, say which recorder setting
would add them.

Only MCAP can: rosbags verifies a chunk's CRC-32 whenever it decompresses the chunk, so a chunked MCAP
whose chunks carry CRCs is checked on every read. An unchunked MCAP, one written without CRCs (rosbag2's
``fastwrite`` and ``zstd_fast`` presets, ``noCRC: true``, rosbags' writer), rosbag2 SQLite and ROS 1 bags
have no checksum over the messages: a flipped bit converts into a different value.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from pathlib import Path

from mcap.exceptions import McapError
from mcap.reader import make_reader

from bagport.bags.records import Checksums, Storage
from bagport.bags.remote import RemotePath

__all__ = ["bag_checksums"]

_CRC_AT = 1 + 8 + 8 + 8 + 8
"""Offset of ``uncompressed_crc`` in a Chunk record: opcode, length, start/end time, uncompressed size."""

MCAP_FIX = (
    "record chunked MCAP with CRCs: `ros2 bag record -s mcap --storage-config-file mcap_writer_options.yaml` "
    "with `noCRC: false` and `noChunking: false` in that file (set them explicitly: the `fastwrite` and "
    "`zstd_fast` presets and some plugin versions write no CRCs; `zstd_small` keeps them), or re-write existing bags with "
    "`ros2 bag convert` and `storage_preset_profile: zstd_small`."
)
_NONE = {
    Storage.SQLITE3: Checksums(
        False,
        "rosbag2 SQLite (.db3) bags carry no checksums",
        "record with `ros2 bag record -s mcap` and `noCRC: false` in its `--storage-config-file`, or re-write existing bags "
        "with `ros2 bag convert` and `storage_id: mcap`, `storage_preset_profile: zstd_small`.",
    ),
    Storage.ROS1: Checksums(
        False,
        "ROS 1 bags carry no checksums",
        "keep a checksum of each bag from the robot on (`sha256sum`), or migrate the fleet to rosbag2 MCAP "
        "with chunk CRCs (`ros2 bag record -s mcap`).",
    ),
}


def _mcap_file(path: Path | RemotePath) -> str | None:
    """Why one MCAP file's messages are not covered by chunk CRCs, or ``None`` when they are."""
    with path.open("rb") as handle:
        summary = make_reader(handle).get_summary()
        if summary is None:
            return f"{path.name} has no summary"
        if not summary.chunk_indexes:
            return f"{path.name} is not chunked (`noChunking: true`)"
        handle.seek(summary.chunk_indexes[0].chunk_start_offset + _CRC_AT)
        (crc,) = struct.unpack("<I", handle.read(4))
    return None if crc else f"{path.name} was written with CRCs off"


def bag_checksums(storage: Storage, data_files: Sequence[Path | RemotePath]) -> Checksums:
    """What protects the bag's bytes; MCAP files are judged by their first chunk (writers set CRCs for
    all chunks or none)."""
    if storage is not Storage.MCAP:
        return _NONE[storage]
    for path in data_files:
        try:
            why = _mcap_file(path)
        except (McapError, OSError, ValueError, struct.error, EOFError) as err:
            why = f"{path.name}'s summary cannot be read ({type(err).__name__})"
        if why is not None:
            return Checksums(False, f"MCAP without chunk CRCs ({why})", MCAP_FIX)
    return Checksums(True, "MCAP chunk CRC-32s")
