"""Where an MCAP file's framing is damaged: its footer, its summary section (checked against the footer's
CRC-32, then record by record) and the record headers of its data section, each with a byte offset.

rosbags and the mcap library fail on such damage with words of their own ("Truncated record at offset 10",
``OverflowError``, a ``__schemaless__`` type for a channel whose schema record is gone), or read on with a
damaged schema. These checks name the record instead. :func:`summary_damage` reads only the summary (one
read: cheap enough at every open); :func:`mcap_layout_damage` also walks the data section's record headers
(a seek per record), so it runs only after a failure.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from bagport.bags.detect import MCAP_MAGIC as MAGIC
from bagport.bags.mcap_tail import RECORD_HEAD, record_heads
from bagport.bags.records import compressed_whole
from bagport.bags.remote import RemotePath
from bagport.errors import BagReadError

__all__ = [
    "FIX",
    "LayoutDamage",
    "check_profiles",
    "check_summaries",
    "header_profile",
    "mcap_layout_damage",
    "summary_damage",
]

_FOOTER = struct.Struct("<BQQQI")  # opcode, length, summary start, summary offset start, summary CRC
_TAIL = _FOOTER.size + len(MAGIC)
_CHUNK_INDEX_HEAD = struct.Struct("<QQQQ")
_HEADER, _FOOTER_OP, _SCHEMA, _CHANNEL, _CHUNK_INDEX, _DATA_END = 0x01, 0x02, 0x03, 0x04, 0x08, 0x0F
_SUMMARY_OPCODES = frozenset({_SCHEMA, _CHANNEL, _CHUNK_INDEX, 0x0A, 0x0B, 0x0D, 0x0E})
_DATA_OPCODES = frozenset({_SCHEMA, _CHANNEL, 0x05, 0x06, 0x07, 0x09, 0x0C, _DATA_END})
_NAMES = {
    _HEADER: "header",
    _SCHEMA: "schema",
    _CHANNEL: "channel",
    0x05: "message",
    0x06: "chunk",
    0x07: "message index",
    _CHUNK_INDEX: "chunk index",
    0x09: "attachment",
    0x0A: "attachment index",
    0x0B: "statistics",
    0x0C: "metadata",
    0x0D: "metadata index",
    0x0E: "summary offset",
    _DATA_END: "data end",
}


FIX = "copy the file again from the robot or a backup (reindexing or re-writing the bag cannot restore changed bytes)."
"""What to do about an MCAP file whose bytes changed after recording."""


@dataclass(frozen=True, slots=True)
class LayoutDamage:
    offset: int
    """Byte offset of the damaged record in the file."""
    what: str


class _BadFieldError(Exception):
    """A field that does not parse inside one record; ``args[0]`` says which."""


def _misframed(offset: int, what: str, previous: int | None) -> LayoutDamage:
    """Damage at a record that may only look damaged: a wrong length in the record before it puts the
    next header inside other bytes."""
    if previous is None:
        return LayoutDamage(offset, what)
    return LayoutDamage(
        offset, f"{what} (or the length of the record before it, at byte {previous}, is damaged)"
    )


def _record_name(opcode: int) -> str:
    return f"{_NAMES.get(opcode, 'record')} (opcode {opcode:#04x})"


def _footer(handle: IO[bytes], size: int) -> tuple[int, int, int] | LayoutDamage:
    """``(footer offset, summary start, summary CRC)``, or the footer's damage."""
    at = size - _TAIL
    handle.seek(at)
    opcode, length, summary_at, offsets_at, _crc = _FOOTER.unpack(handle.read(_FOOTER.size))
    if (opcode, length) != (_FOOTER_OP, _FOOTER.size - RECORD_HEAD.size):
        return LayoutDamage(at, f"the footer record is damaged (opcode {opcode:#04x}, length {length})")
    for name, value in (("summary section", summary_at), ("summary offsets", offsets_at)):
        if value and not len(MAGIC) <= value <= at:
            return LayoutDamage(
                at,
                f"the footer is damaged: it places the {name} at byte {value}, outside the file's {size} bytes",
            )
    return at, summary_at, _crc


def summary_damage(path: Path | RemotePath) -> LayoutDamage | None:
    """The first damage of a whole MCAP file's footer or summary section: a record that does not parse or
    names what the summary lacks, then the CRC-32 the footer holds (a footer with CRC 0 has none to check).
    ``None`` for a whole summary, or a file that is not whole MCAP (cut short: :mod:`.mcap_tail` says so).
    Reads only the summary: cheap enough at every open."""
    size = path.stat().st_size
    with path.open("rb") as handle:
        found = _whole_footer(handle, size)
        if found is None or isinstance(found, LayoutDamage):
            return found
        at, summary_at, crc = found
        if not summary_at:
            return None
        handle.seek(summary_at)
        buf = handle.read(at + _FOOTER.size - 4 - summary_at)  # the CRC covers up to its own field
    damage = _summary_records(buf[: at - summary_at], summary_at)
    if damage is not None or not crc or zlib.crc32(buf) == crc:
        return damage
    return LayoutDamage(
        summary_at,
        f"the summary section (bytes {summary_at} to {at + _FOOTER.size}) fails its CRC-32 check: its bytes "
        "changed after recording",
    )


def check_summaries(uri: str, files: Iterable[Path | RemotePath]) -> None:
    """Raise when an MCAP file's summary is damaged (:func:`summary_damage`): rosbags checks neither its
    records nor its CRC, and reads on with a damaged schema (a message definition) or chunk index, or calls
    a channel whose schema is gone ``__schemaless__``."""
    for file in files:
        found = summary_damage(file)
        if found is not None:
            where = f"{file.name} at byte offset {found.offset}"
            raise BagReadError(f"cannot be opened: {where}: {found.what}", uri=uri, fix=FIX)


ROS2_PROFILE = "ros2"
"""The profile rosbag2's MCAP plugin writes in the header record, and the one rosbags reads."""
_PROFILE_HEAD = len(MAGIC) + RECORD_HEAD.size + 4 + 64


def header_profile(path: Path | RemotePath) -> str | None:
    """The profile an MCAP file's header record names (one small read); ``None`` when the file does not start
    with a readable header record (a file cut short or damaged there is the other checks' to name)."""
    with path.open("rb") as handle:
        head = handle.read(_PROFILE_HEAD)
    at = len(MAGIC) + RECORD_HEAD.size
    if (
        not head.startswith(MAGIC)
        or len(head) < at + 4
        or RECORD_HEAD.unpack_from(head, len(MAGIC))[0] != _HEADER
    ):
        return None
    (size,) = struct.unpack_from("<I", head, at)
    if at + 4 + size > len(head):
        return None
    try:
        return head[at + 4 : at + 4 + size].decode("utf-8")
    except UnicodeDecodeError:
        return None


def check_profiles(uri: str, files: Iterable[Path | RemotePath], *, metadata_yaml: bool) -> None:
    """Refuse an MCAP file that is not rosbag2's (header profile ``ros2``), saying what it is: rosbags
    refuses it with "Profile is not ros2", which reads as damage. In a bag whose ``metadata.yaml`` says
    rosbag2 recorded it, another profile is damage to the header. A file compressed whole (``.zstd``) is
    checked by its reader once decompressed."""
    for file in files:
        if compressed_whole(file.name):
            continue
        profile = header_profile(file)
        if profile is None or profile == ROS2_PROFILE:
            continue
        if metadata_yaml:
            raise BagReadError(
                f"cannot be opened: {file.name} at byte offset {len(MAGIC)}: its header record names profile "
                f"{profile!r} where rosbag2, which recorded this bag (its metadata.yaml), writes "
                f"{ROS2_PROFILE!r}: its bytes changed after recording",
                uri=uri,
                fix=FIX,
            )
        if profile == "ros1":
            what = "holds ROS 1 messages (header profile 'ros1', as `mcap convert` of a .bag writes)"
            fix = "convert the original .bag file: bagport reads ROS 1 bags directly."
        else:
            what = f"is not a rosbag2 MCAP file: its header profile is {profile!r}, not {ROS2_PROFILE!r}"
            fix = (
                "write it as rosbag2 does (`ros2 bag record -s mcap`; with the mcap library, "
                "`Writer.start(profile='ros2')` with ros2msg schemas and CDR messages); a file of other "
                "messages (JSON, Protobuf) needs converting to ROS 2 messages first."
            )
        raise BagReadError(
            f"{file.name} {what}; bagport reads MCAP as rosbag2 writes it (profile 'ros2', CDR messages)",
            uri=uri,
            fix=fix,
        )


def mcap_layout_damage(path: Path | RemotePath) -> LayoutDamage | None:
    """The first damaged record of a whole MCAP file's framing: footer and summary (:func:`summary_damage`),
    then the data section's record headers (local files only: a request per record remotely)."""
    damage = summary_damage(path)
    if damage is not None or isinstance(path, RemotePath):
        return damage
    size = path.stat().st_size
    with path.open("rb") as handle:
        found = _whole_footer(handle, size)
        if found is None or isinstance(found, LayoutDamage):
            return found
        return _data_damage(handle, found[1] or found[0], size)


def _whole_footer(handle: IO[bytes], size: int) -> LayoutDamage | tuple[int, int, int] | None:
    """:func:`_footer` of a file that ends as MCAP does; ``None`` for one too short or without the closing
    magic (cut short: :mod:`.mcap_tail` says so)."""
    if size < len(MAGIC) + _TAIL:
        return None
    handle.seek(size - len(MAGIC))
    if handle.read(len(MAGIC)) != MAGIC:
        return None
    return _footer(handle, size)


def _summary_records(buf: bytes, start: int) -> LayoutDamage | None:
    """The first damaged record of the summary section ``buf`` (which starts at byte ``start``)."""
    pos, previous, schemas = 0, None, {0}
    channels: list[tuple[int, int, str, int]] = []
    while pos < len(buf):
        offset = start + pos
        if pos + RECORD_HEAD.size > len(buf):
            return _misframed(offset, "a summary record header is cut off by the footer", previous)
        opcode, length = RECORD_HEAD.unpack_from(buf, pos)
        if opcode < 0x80 and opcode not in _SUMMARY_OPCODES:
            what = f"the summary holds a record of opcode {opcode:#04x}, which no summary has"
            return _misframed(offset, what, previous)
        if length > len(buf) - pos - RECORD_HEAD.size:
            what = (
                f"the summary's {_record_name(opcode)} is damaged: its length {length} runs past the summary's "
                f"end at byte {start + len(buf)}"
            )
            return _misframed(offset, what, previous)
        try:
            body = buf[pos + RECORD_HEAD.size : pos + RECORD_HEAD.size + length]
            _check_summary_record(opcode, body, schemas, channels, offset, start)
        except (_BadFieldError, struct.error, UnicodeDecodeError) as err:
            why = err.args[0] if isinstance(err, _BadFieldError) else "a field does not parse"
            return LayoutDamage(offset, f"the summary's {_record_name(opcode)} is damaged: {why}")
        previous, pos = offset, pos + RECORD_HEAD.size + length
    for offset, channel_id, topic, schema_id in channels:
        if schema_id not in schemas:
            what = f"the summary's channel {channel_id} ({topic}) names schema {schema_id}, which the summary lacks"
            return LayoutDamage(offset, what)
    return None


def _string(body: bytes, pos: int) -> tuple[str, int]:
    (size,) = struct.unpack_from("<I", body, pos)
    if pos + 4 + size > len(body):
        raise _BadFieldError("a string runs past the record's end")
    return body[pos + 4 : pos + 4 + size].decode("utf-8"), pos + 4 + size


def _check_summary_record(
    opcode: int,
    body: bytes,
    schemas: set[int],
    channels: list[tuple[int, int, str, int]],
    offset: int,
    data_end: int,
) -> None:
    """Raise when one summary record does not parse; collects schema ids and channels (with their offset)."""
    if opcode == _SCHEMA:
        (schema_id,) = struct.unpack_from("<H", body)
        _, pos = _string(body, 2)
        _string(body, pos)
        schemas.add(schema_id)
    elif opcode == _CHANNEL:
        channel_id, schema_id = struct.unpack_from("<HH", body)
        topic, pos = _string(body, 4)
        _string(body, pos)
        channels.append((offset, channel_id, topic, schema_id))
    elif opcode == _CHUNK_INDEX:
        _check_chunk_index(body, data_end)


def _check_chunk_index(body: bytes, data_end: int) -> None:
    _, _, chunk_at, chunk_length = _CHUNK_INDEX_HEAD.unpack_from(body)
    if not len(MAGIC) <= chunk_at or chunk_at + chunk_length > data_end:
        raise _BadFieldError(
            f"it places a chunk of {chunk_length} bytes at byte {chunk_at}, outside the data section "
            f"(bytes {len(MAGIC)} to {data_end})"
        )
    (map_size,) = struct.unpack_from("<I", body, _CHUNK_INDEX_HEAD.size)
    entries = body[_CHUNK_INDEX_HEAD.size + 4 : _CHUNK_INDEX_HEAD.size + 4 + map_size]
    if len(entries) != map_size or map_size % 10:
        raise _BadFieldError("its message index offsets run past the record's end")
    for channel_id, index_at in struct.iter_unpack("<HQ", entries):
        if not chunk_at + chunk_length <= index_at < data_end:
            raise _BadFieldError(
                f"it places channel {channel_id}'s message index at byte {index_at}, outside the chunk's "
                f"message indexes (bytes {chunk_at + chunk_length} to {data_end})"
            )


def _data_damage(handle: IO[bytes], end: int, size: int) -> LayoutDamage | None:
    """The first record header of the data section (from the leading magic to ``end``) with an unknown
    opcode or a length past ``end``."""
    previous = None
    for pos, opcode, length in record_heads(handle, len(MAGIC), end):
        if opcode is None:
            return _misframed(pos, "a record header is cut off", previous)
        if pos == len(MAGIC) and opcode != _HEADER:
            return LayoutDamage(pos, f"the header record is damaged: its opcode is {opcode:#04x}, not 0x01")
        if opcode != _HEADER and opcode < 0x80 and opcode not in _DATA_OPCODES:
            what = f"the record here has opcode {opcode:#04x}, which no data section holds"
            return _misframed(pos, what, previous)
        if pos + RECORD_HEAD.size + length > end:
            limit = "the file's end" if end == size - _TAIL else f"the summary's start at byte {end}"
            what = (
                f"the {_record_name(opcode)} is damaged: its length {length} runs past {limit} "
                f"(the file has {size} bytes)"
            )
            return _misframed(pos, what, previous)
        if opcode == _DATA_END:
            return None
        previous = pos
    return None
