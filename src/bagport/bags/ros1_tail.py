"""A ROS 1 bag cut short: where its bytes end, how many are missing, and what of it is whole.

A ``rosbag record`` killed mid-recording leaves a bag whose header still says ``index_pos=0`` (the index is
written on close) and whose last record stops part-way; a copy that did not finish leaves a closed bag's
first bytes, its header pointing at an index past the end. rosbags then says the bag is not indexed, or
fails reading it, and the record walk finds a length that "runs past the end": this says what happened
instead, walking the records' headers (a seek per record: no record's data is read).

``rosbag reindex`` (ros_comm's ``Bag.reindex``) reads the chunks from the start, stops at the first one it
cannot read, cuts the file there and writes a new index (the original is kept as ``NAME.orig.bag``): the
whole chunks before the cut are kept, the messages after the last whole chunk are lost.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from bagport.bags.detect import ROS1_MAGIC
from bagport.bags.remote import RemotePath

__all__ = ["Ros1Cut", "ros1_cut"]

_START = len(ROS1_MAGIC) + 1  # "#ROSBAG V2.0\n"
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_BAG_HEADER, _CHUNK = 0x03, 0x05
_MAX_LENGTH = 1 << 30
"""A record longer than this is a damaged length, not a cut (the damage walk says where)."""


@dataclass(frozen=True, slots=True)
class Ros1Cut:
    """Where a ROS 1 bag whose last record runs past its end stops."""

    name: str
    size: int
    """The file's length in bytes."""
    record_at: int | None
    """The byte offset of the record the file ends inside (``None``: it ends between records)."""
    missing: int | None
    """Bytes missing from that record, when its lengths can be read."""
    chunks: int
    """Whole chunks of messages before the cut."""
    index_at: int | None
    """Where the bag header says the index starts (0: the recorder never closed the bag; ``None``: the
    header itself is cut)."""
    chunk_count: int | None = None
    """The chunks the bag header says the bag holds (written as the bag is closed)."""

    @property
    def data_whole(self) -> bool:
        """Every chunk the closed bag holds is before the cut: only index records are lost, no message."""
        return bool(self.index_at) and bool(self.chunk_count) and self.chunks >= (self.chunk_count or 0)

    def describe(self) -> str:
        """One clause: where the bytes end, why, and what is whole before."""
        if self.index_at == 0:
            why = "the recorder stopped before closing the bag: its header's index_pos is 0"
        elif self.index_at is None:
            why = "a copy or download that did not finish, or a recorder stopped"
        else:
            why = f"a copy or download that did not finish: the bag was closed, with its index at byte {self.index_at}"
        short = f", {self.missing} bytes short of its end" if self.missing is not None else ""
        where = (
            f"inside the record that starts at byte {self.record_at}{short}"
            if self.record_at is not None
            else f"between records, before the index its header places at byte {self.index_at}"
        )
        if self.data_whole:
            return (
                f"the file ends at byte {self.size}, after all its {self.chunks} chunk(s) of messages, {where}"
                f"{' (its index)' if self.record_at is not None else ''}: it was cut short ({why}); no message "
                "is lost"
            )
        whole = (
            f"the {self.chunks} chunk(s) of messages before it are whole"
            if self.chunks
            else "no chunk of messages before it is whole"
        )
        return f"the file ends at byte {self.size}, {where}: it was cut short ({why}); {whole}"

    def fix(self) -> str:
        """Copy it again if the robot has it whole; else what ``rosbag reindex`` keeps of it."""
        if not self.chunks:
            return (
                "copy the bag again from the robot or a backup: no chunk of messages before the cut is whole, "
                "so `rosbag reindex` has nothing to keep."
            )
        backup = f"{Path(self.name).stem}.orig{Path(self.name).suffix}"  # as rosbag names it
        kept = (
            f"rebuilds its index from its {self.chunks} whole chunk(s), losing no message"
            if self.data_whole
            else f"keeps the {self.chunks} whole chunk(s) before the cut (the messages after them are lost)"
        )
        return (
            f"if the recording is whole on the robot, copy it again; else `rosbag reindex {self.name}` {kept}: "
            f"it cuts the file after the last whole chunk, writes a new index and keeps the original as "
            f"{backup}; then convert {self.name}."
        )


def ros1_cut(path: Path | RemotePath) -> Ros1Cut | None:
    """The cut of a ROS 1 bag whose last record runs past its end (or that ends before the index its header
    points at); ``None`` for a whole file, one that does not start as a ROS 1 bag, a damaged length (longer
    than any record) or a bag never closed that ends between records (not indexed: a reindex reads it)."""
    size = path.stat().st_size
    with path.open("rb") as handle:
        if handle.read(_START) != ROS1_MAGIC + b"\n":
            return None
        return _walk(handle, path.name, size)


def _walk(handle: IO[bytes], name: str, size: int) -> Ros1Cut | None:
    """Record headers from the first on, to the one the file ends inside."""
    index_at: int | None = None
    chunk_count: int | None = None
    chunks, pos = 0, _START
    while pos < size:
        handle.seek(pos)
        head = handle.read(_U32.size)
        header_len = _U32.unpack(head)[0] if len(head) == _U32.size else 0
        if header_len > _MAX_LENGTH:
            return None
        if pos + 8 + header_len > size:  # the header or the data length is cut off: the data's size unknown
            return Ros1Cut(name, size, pos, None, chunks, index_at, chunk_count)
        header = handle.read(header_len)
        (data_len,) = _U32.unpack(handle.read(_U32.size))
        if data_len > _MAX_LENGTH:
            return None
        fields = _fields(header)
        if fields.get("op") == bytes([_BAG_HEADER]):
            index_at, chunk_count = _number(fields, "index_pos", _U64), _number(fields, "chunk_count", _U32)
        end = pos + 8 + header_len + data_len
        if end > size:
            return Ros1Cut(name, size, pos, end - size, chunks, index_at, chunk_count)
        chunks += fields.get("op") == bytes([_CHUNK]) and data_len > 0  # rosbag sizes a chunk as it closes it
        pos = end
    if index_at and index_at >= size:
        return Ros1Cut(name, size, None, None, chunks, index_at, chunk_count)
    return None


def _number(fields: dict[str, bytes], name: str, form: struct.Struct) -> int | None:
    value = fields.get(name, b"")
    return int(form.unpack(value)[0]) if len(value) == form.size else None


def _fields(header: bytes) -> dict[str, bytes]:
    """A record header's ``name=value`` fields, as far as they parse (the damage walk judges the rest)."""
    fields: dict[str, bytes] = {}
    pos = 0
    while pos + _U32.size <= len(header):
        (length,) = _U32.unpack_from(header, pos)
        name, equals, value = header[pos + 4 : pos + 4 + length].partition(b"=")
        if not equals:
            break
        fields[name.decode("latin-1")] = value
        pos += 4 + length
    return fields
