"""Where a bag is damaged: the file, the byte offset of the first bad record and the topics it holds.

rosbags says *that* a read failed ("Chunk checksum mismatch.", "database disk image is malformed"),
not where. After a failure, these walk the damaged file once more with checks of their own: MCAP
framing (:mod:`bagport.bags.mcap_layout`), then chunks against their CRC-32 and record layout, SQLite
through its integrity check (page -> byte offset), ROS 1 records and chunks (layout, decompression,
sizes); a file cut short is said to be one first (:mod:`~bagport.bags.mcap_tail`,
:mod:`~bagport.bags.sqlite_tail`, :mod:`~bagport.bags.ros1_tail`). Each returns ``None`` when it finds
nothing wrong; the error is then reported without a place.
Only run after a failure: each reads the whole file (a record or chunk at a time; memory stays bounded).
"""

from __future__ import annotations

import bz2
import contextlib
import re
import sqlite3
import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import quote

import lz4.frame  # type: ignore[import-untyped]
from backports import zstd
from mcap.exceptions import McapError
from mcap.reader import make_reader

from bagport.bags.mcap_layout import mcap_layout_damage
from bagport.bags.mcap_tail import FIX as CUT_FIX
from bagport.bags.mcap_tail import mcap_cut
from bagport.bags.records import Storage
from bagport.bags.remote import RemotePath
from bagport.bags.ros1_tail import ros1_cut
from bagport.bags.sqlite_tail import sqlite_cut

__all__ = ["Damage", "locate_damage"]

_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_CHUNK_HEAD = struct.Struct("<QQQI")
MAX_RECORD_BYTES = 1 << 30
"""A record (chunk) claiming more is damaged: nothing larger is read into memory while locating."""
_DECOMPRESS: dict[str, Callable[[bytes], bytes]] = {
    "": lambda data: data,
    "none": lambda data: data,
    "zstd": zstd.decompress,
    "lz4": lz4.frame.decompress,
    "bz2": bz2.decompress,
}
_DECOMPRESS_ERRORS = (OSError, ValueError, RuntimeError, EOFError, zstd.ZstdError)


@dataclass(frozen=True, slots=True)
class Damage:
    file: str
    """The damaged file's name."""
    offset: int | None
    """Byte offset of the damaged record (chunk, page) in the file, when known."""
    what: str
    topics: tuple[str, ...] = ()
    """Topics with messages in the damaged record, when known."""
    fix: str | None = None
    """What to do, when it is not the storage's usual fix (a file cut short is not a changed one)."""

    def describe(self) -> str:
        where = f"{self.file} at byte offset {self.offset}" if self.offset is not None else self.file
        held = f" (it holds messages of {', '.join(self.topics)})" if self.topics else ""
        return f"{where}: {self.what}{held}"


class _BadRecordError(Exception):
    """A record that does not parse; ``args[0]`` says why."""


def locate_damage(storage: Storage, files: list[Path | RemotePath], *, metadata_yaml: bool) -> Damage | None:
    """The first damage found in the bag's data files, or ``None`` (never raises on damage).
    ``metadata_yaml``: the bag is a folder with one (what to convert after a SQLite salvage depends on it)."""
    locate: Callable[[Path | RemotePath], Damage | None] = {
        Storage.MCAP: _locate_mcap,
        Storage.SQLITE3: lambda file: _locate_sqlite(file, metadata_yaml=metadata_yaml),
        Storage.ROS1: _locate_ros1,
    }[storage]
    for file in files:
        try:
            found = locate(file)
        except OSError:
            return None  # the file cannot be read at all: the reader's own error says so
        if found is not None:
            return found
    return None


def _string(buf: bytes, pos: int) -> tuple[str, int]:
    (size,) = _U32.unpack_from(buf, pos)
    end = pos + 4 + size
    if end > len(buf):
        raise _BadRecordError("a string runs past the end of its record")
    return buf[pos + 4 : end].decode("utf-8", "replace"), end


def _mcap_chunk_problem(raw: bytes, channels: dict[int, str]) -> str | None:
    """Why one MCAP chunk record (opcode, length, body) is damaged, or ``None``."""
    try:
        if raw[:1] != b"\x06":
            return f"the chunk index points here but the record is not a chunk (opcode {raw[:1].hex()})"
        _, _, size, crc = _CHUNK_HEAD.unpack_from(raw, 9)
        compression, pos = _string(raw, 9 + _CHUNK_HEAD.size)
        (compressed_size,) = _U64.unpack_from(raw, pos)
        body = raw[pos + 8 : pos + 8 + compressed_size]
        if compression not in _DECOMPRESS or len(body) != compressed_size:
            return f"chunk header damaged (compression {compression!r}, {compressed_size} bytes)"
        data = _DECOMPRESS[compression](body)
    except (_BadRecordError, struct.error) as err:
        return f"chunk header damaged ({err})"
    except _DECOMPRESS_ERRORS as err:
        return f"chunk does not decompress ({compression}: {err})"
    if len(data) != size:
        return f"chunk decompresses to {len(data)} bytes, its header says {size}"
    if crc and zlib.crc32(data) != crc:
        return "chunk fails its CRC-32 check: its bytes changed after recording"
    pos = 0
    while pos < len(data):
        if pos + 9 > len(data):
            return f"record at byte {pos} of the chunk is cut off"
        opcode, (length,) = data[pos], _U64.unpack_from(data, pos + 1)
        if pos + 9 + length > len(data):
            return f"record at byte {pos} of the chunk claims {length} bytes, past the chunk's end"
        if opcode == 0x05 and (length < 22 or _U32.unpack_from(data, pos + 9)[0] & 0xFFFF not in channels):
            return f"message record at byte {pos} of the chunk is damaged (length or channel id)"
        pos += 9 + length
    return None


def _locate_mcap(path: Path | RemotePath) -> Damage | None:
    cut = mcap_cut(path)
    if cut is not None:
        return Damage(path.name, None, cut.describe(), fix=CUT_FIX)
    framing = mcap_layout_damage(path)
    if framing is not None:
        return Damage(path.name, framing.offset, framing.what)
    with path.open("rb") as handle:
        try:
            summary = make_reader(handle).get_summary()
        except (McapError, struct.error, ValueError, KeyError, EOFError, AssertionError) as err:
            return Damage(
                path.name, None, f"its summary section cannot be read ({type(err).__name__}: {err})"
            )
        if summary is None:
            return None
        channels = {cid: channel.topic for cid, channel in summary.channels.items()}
        for index in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            handle.seek(index.chunk_start_offset)
            if index.chunk_length > MAX_RECORD_BYTES:
                problem: str | None = (
                    f"the chunk index gives an implausible length ({index.chunk_length} bytes)"
                )
            else:
                problem = _mcap_chunk_problem(handle.read(index.chunk_length), channels)
            if problem is not None:
                topics = sorted({channels.get(cid, f"channel {cid}") for cid in index.message_index_offsets})
                return Damage(path.name, index.chunk_start_offset, problem, tuple(topics))
    return None


def _read_only(uri: str) -> sqlite3.Connection:
    """A connection whose text never fails to decode: a damaged file's names and schema can hold any bytes."""
    db = sqlite3.connect(uri, uri=True)
    db.text_factory = lambda raw: raw.decode("utf-8", "replace")
    return db


def _locate_sqlite(path: Path | RemotePath, *, metadata_yaml: bool) -> Damage | None:
    if isinstance(path, RemotePath):
        return None  # SQLite bags are downloaded before they are read; a remote path is not opened here
    cut = sqlite_cut(path)
    if cut is not None:
        return Damage(path.name, None, cut.describe(), fix=cut.fix(metadata_yaml=metadata_yaml))
    uri = f"file:{quote(str(path.resolve()))}?mode=ro&immutable=1"
    try:
        with contextlib.closing(_read_only(uri)) as db:
            page_size = int(db.execute("PRAGMA page_size").fetchone()[0])
            roots = [(str(n), int(r)) for n, r in db.execute("SELECT name, rootpage FROM sqlite_master") if r]
            try:
                rows = [str(row[0]) for row in db.execute("PRAGMA integrity_check(5)")]
            except sqlite3.DatabaseError as err:
                return _walk_btrees(path, page_size, roots) or Damage(path.name, None, f"SQLite: {err}")
    except sqlite3.Error as err:
        return Damage(path.name, None, f"SQLite cannot read its header or schema ({err})")
    except UnicodeDecodeError:  # SQLite's own message quotes the damaged schema's bytes, not text
        return Damage(path.name, None, "SQLite cannot read its schema (it holds bytes that are not text)")
    if rows == ["ok"]:
        return _sqlite_row_types(path, uri)
    pages = re.findall(r"page (\d+)", " ".join(rows))
    found = "; ".join(" ".join(row.split()) for row in rows[:3])
    if not pages:  # a bare "malformed": the rows or the b-trees may still say where
        located = _sqlite_row_types(path, uri) or _walk_btrees(path, page_size, roots)
        if located is not None:
            return located
    offset = (int(pages[0]) - 1) * page_size if pages else None
    return Damage(path.name, offset, f"SQLite's integrity check finds damaged pages ({found})")


_ROWS = (
    "SELECT messages.id, topics.name, typeof(messages.timestamp), typeof(messages.data) FROM messages "
    "LEFT JOIN topics ON topics.id = messages.topic_id ORDER BY messages.id"
)


def _sqlite_row_types(path: Path, uri: str) -> Damage | None:
    """The first message row that cannot be read, whose columns are of the wrong type or whose topic is
    missing: a bit flip in a record header that SQLite's structural check does not place."""
    last: tuple[int, str] | None = None
    try:
        with contextlib.closing(_read_only(uri)) as db:
            for rowid, topic, stamp_type, data_type in db.execute(_ROWS):
                if topic is None:
                    return Damage(
                        path.name, None, f"message row {rowid} names a topic the topics table lacks"
                    )
                if (stamp_type, data_type) != ("integer", "blob"):
                    return Damage(
                        path.name,
                        None,
                        f"message row {rowid} holds a {stamp_type} timestamp and a {data_type} payload "
                        "(an integer and a blob belong there)",
                        (str(topic),),
                    )
                last = (int(rowid), str(topic))
    except (sqlite3.Error, UnicodeDecodeError) as err:
        after = f" after row {last[0]} (on {last[1]})" if last is not None else ""
        why = "damaged bytes" if isinstance(err, UnicodeDecodeError) else err
        return Damage(path.name, None, f"the message row{after} cannot be read ({why})")
    return None


_LEAF, _INTERIOR = {0x0A, 0x0D}, {0x02, 0x05}


def _walk_btrees(path: Path, page_size: int, roots: list[tuple[str, int]]) -> Damage | None:
    """The first b-tree page whose header is damaged (when SQLite's own check gives up), walking each
    table and index from its root page."""
    pages = path.stat().st_size // page_size
    with path.open("rb") as handle:
        for name, root in roots:
            todo, seen = [root], set()
            while todo:
                page = todo.pop()
                if page in seen:
                    continue
                seen.add(page)
                offset = (page - 1) * page_size
                if not 1 <= page <= pages:
                    return Damage(
                        path.name, None, f"b-tree of {name} points at page {page}, past the file's end"
                    )
                handle.seek(offset)
                buf = handle.read(page_size)
                head = 100 if page == 1 else 0
                kind, cells = buf[head], int.from_bytes(buf[head + 3 : head + 5], "big")
                size = 8 if kind in _LEAF else 12
                if kind not in _LEAF | _INTERIOR or head + size + 2 * cells > page_size:
                    return Damage(path.name, offset, f"page {page} of {name} has a damaged b-tree header")
                if kind in _INTERIOR:
                    pointers = [
                        int.from_bytes(buf[head + 12 + 2 * i : head + 14 + 2 * i], "big")
                        for i in range(cells)
                    ]
                    if any(not size <= p < page_size - 4 for p in pointers):
                        return Damage(path.name, offset, f"page {page} of {name} has damaged cell pointers")
                    todo += [int.from_bytes(buf[p : p + 4], "big") for p in pointers]
                    todo.append(int.from_bytes(buf[head + 8 : head + 12], "big"))
    return None


def _ros1_header(buf: bytes) -> dict[str, bytes]:
    fields: dict[str, bytes] = {}
    pos = 0
    while pos < len(buf):
        if pos + 4 > len(buf):
            raise _BadRecordError("a header field length is cut off")
        (size,) = _U32.unpack_from(buf, pos)
        field = buf[pos + 4 : pos + 4 + size]
        if len(field) != size or b"=" not in field:
            raise _BadRecordError("a header field is damaged")
        name, _, value = field.partition(b"=")
        fields[name.decode("latin-1")] = value
        pos += 4 + size
    if len(fields.get("op", b"")) != 1:
        raise _BadRecordError("the record has no valid op code")
    return fields


def _ros1_record(read: Callable[[int], bytes], left: int) -> tuple[dict[str, bytes], bytes] | None:
    """One record (header fields, data) from ``read``; ``None`` at the end; ``left``: bytes remaining."""
    head = read(4)
    if not head:
        return None
    if len(head) < 4:
        raise _BadRecordError("the record is cut off")
    (header_len,) = _U32.unpack(head)
    if header_len + 8 > left:
        raise _BadRecordError(f"header length {header_len} runs past the end")
    header = _ros1_header(read(header_len))
    (data_len,) = _U32.unpack(read(4))
    if header_len + 8 + data_len > left or data_len > MAX_RECORD_BYTES:
        raise _BadRecordError(f"data length {data_len} runs past the end")
    return header, read(data_len)


def _ros1_chunk(header: dict[str, bytes], data: bytes, conns: dict[int, str]) -> tuple[str, ...]:
    """Check one chunk's decompression and inner records; returns its topics (raises :class:`_BadRecordError`)."""
    compression = header.get("compression", b"").decode("latin-1")
    if compression not in _DECOMPRESS or len(header.get("size", b"")) != 4:
        raise _BadRecordError(f"chunk header damaged (compression {compression!r})")
    try:
        inner = _DECOMPRESS[compression](data)
    except _DECOMPRESS_ERRORS as err:
        raise _BadRecordError(f"chunk does not decompress ({compression}: {err})") from err
    (size,) = _U32.unpack(header["size"])
    if len(inner) != size:
        raise _BadRecordError(f"chunk decompresses to {len(inner)} bytes, its header says {size}")
    pos, topics = 0, set()
    while pos < len(inner):
        stream = _Slice(inner, pos)
        try:
            record = _ros1_record(stream.read, len(inner) - pos)
        except (_BadRecordError, struct.error) as err:  # where in the chunk, as for MCAP
            raise _BadRecordError(f"record at byte {pos} of the chunk is damaged: {_why(err)}") from err
        if record is None:
            break
        fields, payload = record
        op = fields["op"][0]
        if op == 0x07:
            conns[_u32(fields, "conn")] = _ros1_topic(payload, fields)
        elif op == 0x02:
            conn = _u32(fields, "conn")
            if conn not in conns or len(fields.get("time", b"")) != 8:
                raise _BadRecordError(
                    f"message record at byte {pos} of the chunk is damaged (connection or time)"
                )
            topics.add(conns[conn])
        pos = stream.pos
    return tuple(sorted(topics))


class _Slice:
    def __init__(self, buf: bytes, pos: int) -> None:
        self.buf, self.pos = buf, pos

    def read(self, size: int) -> bytes:
        out = self.buf[self.pos : self.pos + size]
        self.pos += len(out)
        return out


def _u32(fields: dict[str, bytes], name: str) -> int:
    value = fields.get(name, b"")
    if len(value) != 4:
        raise _BadRecordError(f"field {name!r} is damaged")
    return int(_U32.unpack(value)[0])


def _ros1_topic(payload: bytes, fields: dict[str, bytes]) -> str:
    if "topic" in fields:
        return fields["topic"].decode("utf-8", "replace")
    return _ros1_header(payload).get("topic", b"?").decode("utf-8", "replace")


def _locate_ros1(path: Path | RemotePath) -> Damage | None:
    cut = ros1_cut(path)
    if cut is not None:
        return Damage(path.name, None, cut.describe(), fix=cut.fix())
    size = path.stat().st_size
    conns: dict[int, str] = {}
    with path.open("rb") as handle:
        handle.seek(13)  # "#ROSBAG V2.0\n"
        while True:
            offset = handle.tell()
            try:
                record = _ros1_record(handle.read, size - offset)
                if record is None:
                    return None
                header, data = record
                if header["op"][0] == 0x07:
                    conns[_u32(header, "conn")] = _ros1_topic(data, header)
                elif header["op"][0] == 0x05:
                    _ros1_chunk(header, data, conns)
            except (_BadRecordError, struct.error, KeyError, IndexError) as err:
                return Damage(path.name, offset, f"record damaged: {_why(err)}")


def _why(err: Exception) -> str:
    return str(err.args[0]) if isinstance(err, _BadRecordError) else f"{type(err).__name__}: {err}"
