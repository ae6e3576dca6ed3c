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
from typing import IO

from mcap.exceptions import McapError
from mcap.reader import make_reader

from bagport.bags.records import Checksums, Storage, compressed_whole
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


_COMPARED_CHUNKS = 4
"""Chunks whose CRC field is read when the first one's is 0: writers set CRCs for all chunks or none, so a
0 among CRCs is a damaged chunk header, not a recorder setting."""


def _first_chunk_crc_zeroed(
    path: Path | RemotePath, handle: IO[bytes], starts: list[int]
) -> Checksums | None:
    """The finding for a file whose first chunk's CRC field reads 0 while a later chunk has a CRC (writers
    set CRCs for all chunks or none: the first chunk's header is damaged); ``None`` when no chunk has one."""
    for start in starts[1:_COMPARED_CHUNKS]:
        handle.seek(start + _CRC_AT)
        if struct.unpack("<I", handle.read(4))[0]:
            return Checksums(
                True,
                f"MCAP chunk CRC-32s, except the chunk at byte offset {starts[0]} of {path.name}: its CRC field "
                "reads 0 while the next chunks have CRCs, so its header is damaged and its messages go unchecked",
            )
    return None


def _mcap_file(path: Path | RemotePath) -> Checksums | None:
    """What does not protect one MCAP file's messages as chunk CRCs would, or ``None`` when they do."""
    with path.open("rb") as handle:
        summary = make_reader(handle).get_summary()
        if summary is None:
            return _unchecked(f"{path.name} has no summary")
        if not summary.chunk_indexes:
            return _unchecked(f"{path.name} is not chunked (`noChunking: true`)")
        starts = sorted(index.chunk_start_offset for index in summary.chunk_indexes)
        handle.seek(starts[0] + _CRC_AT)
        (crc,) = struct.unpack("<I", handle.read(4))
        if crc:
            return None
        return _first_chunk_crc_zeroed(path, handle, starts) or _unchecked(
            f"{path.name} was written with CRCs off"
        )


def _file_compressed(name: str) -> Checksums:
    """A ``.mcap.zstd`` (rosbag2's ``compression_mode: file``) is read through its decompression: no chunk
    CRC of the MCAP inside is checked on the way."""
    return Checksums(
        False,
        f"MCAP compressed as a whole file ({name}): its chunks' CRCs are not checked",
        "record with the MCAP plugin's own chunk compression instead of `--compression-mode file` "
        "(`ros2 bag record -s mcap --storage-preset-profile zstd_small`: chunk CRCs kept), or re-write existing "
        "bags with `ros2 bag convert` and `storage_preset_profile: zstd_small`.",
    )


def _unchecked(why: str) -> Checksums:
    return Checksums(False, f"MCAP without chunk CRCs ({why})", MCAP_FIX)


def bag_checksums(storage: Storage, data_files: Sequence[Path | RemotePath]) -> Checksums:
    """What protects the bag's bytes; MCAP files are judged by their first chunk (writers set CRCs for
    all chunks or none; a first chunk without one is compared with the next few)."""
    if storage is not Storage.MCAP:
        return _NONE[storage]
    for path in data_files:
        if compressed_whole(path.name):
            return _file_compressed(path.name)
        try:
            found = _mcap_file(path)
        except (McapError, OSError, ValueError, struct.error, EOFError) as err:
            found = _unchecked(f"{path.name}'s summary cannot be read ({type(err).__name__})")
        if found is not None:
            return found
    return Checksums(True, "MCAP chunk CRC-32s")
