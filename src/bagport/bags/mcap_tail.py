"""An MCAP file cut short: where its bytes end, and what of it is whole.

A recorder killed mid-recording (or a copy that did not finish) leaves an MCAP file without its summary,
footer and closing magic. rosbags then fails on the footer ("File end magic is invalid") and the
summary cannot be read, which reads as damage; this says what happened instead, walking the records'
headers (a seek per record: nothing is read into memory).
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from bagport.bags.detect import MCAP_MAGIC as MAGIC
from bagport.bags.remote import RemotePath

__all__ = ["FIX", "MAGIC", "RECORD_HEAD", "McapCut", "mcap_cut", "record_heads"]
RECORD_HEAD = struct.Struct("<BQ")
"""A record's opcode and length, before its body."""
_CHUNK, _DATA_END = 0x06, 0x0F


@dataclass(frozen=True, slots=True)
class McapCut:
    """Where a file that starts as MCAP but does not end as one stops."""

    name: str
    size: int
    """The file's length in bytes."""
    record_at: int | None
    """The byte offset of the record the file ends inside (``None``: it ends between records)."""
    chunks: int
    """Whole chunks before the cut."""
    data_whole: bool
    """The data section's end record is there: only the summary and footer are missing."""

    def describe(self) -> str:
        """One clause: where the bytes end, and what is whole before."""
        why = "it was cut short (the recorder stopped before writing its summary, or the copy is incomplete)"
        if self.data_whole:
            return (
                f"the file ends at byte {self.size} without MCAP's summary and closing magic: {why}; its "
                f"{self.chunks} chunk(s) of messages are whole"
            )
        where = (
            f"inside the record that starts at byte {self.record_at}"
            if self.record_at is not None
            else "between records"
        )
        return (
            f"the file ends at byte {self.size}, {where}, without MCAP's closing magic: {why}; the "
            f"{self.chunks} chunk(s) before are whole"
        )


FIX = (
    "if the recording is whole on the robot, copy it again; else keep its whole chunks with the mcap CLI "
    "(`mcap recover FILE -o FIXED.mcap`) and convert FIXED.mcap."
)
"""What to do about a file cut short."""


def mcap_cut(path: Path | RemotePath) -> McapCut | None:
    """The cut of an MCAP file that does not end with its magic; ``None`` for a whole file, or one that
    does not start as MCAP. A remote file is only checked at its two ends (a ranged read per record would
    be a request each)."""
    size = path.stat().st_size
    with path.open("rb") as handle:
        if handle.read(len(MAGIC)) != MAGIC:
            return None
        if size >= 2 * len(MAGIC):
            handle.seek(size - len(MAGIC))
            if handle.read(len(MAGIC)) == MAGIC:
                return None
        if isinstance(path, RemotePath):
            return McapCut(path.name, size, None, 0, data_whole=False)
        return _walk(handle, path.name, size)


def record_heads(handle: IO[bytes], start: int, end: int) -> Iterator[tuple[int, int | None, int]]:
    """``(offset, opcode, length)`` of each record from byte ``start`` while before ``end``, a seek and a
    9-byte read per record (nothing else is read); a header the file ends inside is ``(offset, None, 0)``, the
    last. The caller stops at a length it finds wrong."""
    pos = start
    while pos < end:
        head = handle.read(RECORD_HEAD.size) if handle.seek(pos) == pos else b""
        if len(head) < RECORD_HEAD.size:
            yield pos, None, 0
            return
        opcode, length = RECORD_HEAD.unpack(head)
        yield pos, opcode, length
        pos += RECORD_HEAD.size + length


def _walk(handle: IO[bytes], name: str, size: int) -> McapCut:
    """Record headers from the leading magic on, to the one the file ends inside."""
    chunks = 0
    for pos, opcode, length in record_heads(handle, len(MAGIC), size):
        if opcode is None:
            return McapCut(name, size, pos, chunks, data_whole=False)
        if opcode == _DATA_END:
            return McapCut(name, size, None, chunks, data_whole=True)
        if pos + RECORD_HEAD.size + length > size:
            return McapCut(name, size, pos, chunks, data_whole=False)
        chunks += opcode == _CHUNK
    return McapCut(name, size, None, chunks, data_whole=False)
