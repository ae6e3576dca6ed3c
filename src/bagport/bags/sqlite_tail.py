"""A SQLite data file cut short: where its bytes end, and how long its header says it is.

A rosbag2 ``.db3`` file is whole pages (SQLite writes nothing else), and its 100-byte header records the
page size and, in every SQLite since 3.7.0, the number of pages. A copy or download that did not finish
(or a disk that filled) leaves fewer bytes than that; SQLite then answers "database disk image is
malformed", which reads as damage. This says what happened instead, from the header alone.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

from bagport.bags.remote import RemotePath

__all__ = ["HEADER_MAGIC", "SALVAGE_COMMAND", "SqliteCut", "salvage", "sqlite_cut"]

HEADER_MAGIC = b"SQLite format 3\x00"
_HEADER_BYTES = 100
_PAGE_SIZE = struct.Struct(">H")  # at byte 16; 1 means 65,536
_COUNTER = struct.Struct(">I")  # the change counter at byte 24, the page count at 28, valid-for at 92

SALVAGE_COMMAND = "sqlite3 FILE .dump | sed 's/^ROLLBACK; -- due to errors$/COMMIT;/' | sqlite3 FIXED.db3"
"""How to salvage the readable rows of a damaged or cut ``.db3`` with the sqlite3 command-line tool (``.dump``
ends a damaged database with ``ROLLBACK``, which would undo the copy; ``.recover`` is not in every build)."""


def salvage(*, metadata_yaml: bool) -> str:
    """The salvage fix, and what to convert after it: in a folder with a ``metadata.yaml``, the salvaged file on
    its own (the metadata promises the messages lost); a bare ``.db3``, or a folder without one, has no promise
    to break."""
    then = (
        "convert FIXED.db3 on its own (the folder's metadata.yaml promises the lost messages)"
        if metadata_yaml
        else "convert FIXED.db3 instead"
    )
    return f"`{SALVAGE_COMMAND}` keeps the rows SQLite can still read; {then}"


@dataclass(frozen=True, slots=True)
class SqliteCut:
    """Where a SQLite file shorter than its header says stops."""

    name: str
    size: int
    """The file's length in bytes."""
    expected: int | None
    """The length its header gives (pages times page size); ``None`` when the header itself is cut."""
    page_size: int | None

    def describe(self) -> str:
        """One clause: where the bytes end, and what the header promised."""
        why = "it was cut short (a copy or download that did not finish, or a disk that filled)"
        if self.page_size is None:
            return f"the file ends at byte {self.size}, inside SQLite's {_HEADER_BYTES}-byte header: {why}"
        whole = self.size // self.page_size
        if self.expected is None:
            return (
                f"the file ends at byte {self.size}, {self.size % self.page_size} bytes into page {whole + 1} "
                f"(a SQLite file is whole pages of {self.page_size} bytes): {why}; {whole} page(s) before are whole"
            )
        return (
            f"the file ends at byte {self.size}, but its header says it holds {self.expected // self.page_size} "
            f"pages of {self.page_size} bytes ({self.expected} bytes): {why}; {whole} page(s) before are whole"
        )

    def fix(self, *, metadata_yaml: bool) -> str:
        """What to do: copy it again (its whole size, when known), or salvage the rows that can be read
        (``metadata_yaml``: the bag is a folder with one, see :func:`salvage`)."""
        size = f" (the whole file is {self.expected} bytes)" if self.expected is not None else ""
        return f"copy the bag again from the robot or a backup{size}; without one, {salvage(metadata_yaml=metadata_yaml)}."


def sqlite_cut(path: Path | RemotePath) -> SqliteCut | None:
    """The cut of a file that starts as SQLite but is shorter than its header says (without a page count in
    its header, as a SQLite older than 3.7.0 leaves it: not whole pages); ``None`` for a whole file, a
    longer one (damage, not a cut), one that does not start as SQLite, or one with a write-ahead log
    beside it (pages not yet checkpointed into it)."""
    size = path.stat().st_size
    with path.open("rb") as handle:
        header = handle.read(_HEADER_BYTES)
    if len(header) < _HEADER_BYTES:
        started = bool(header) and HEADER_MAGIC.startswith(header[: len(HEADER_MAGIC)])
        return SqliteCut(path.name, size, None, None) if started else None
    if not header.startswith(HEADER_MAGIC):
        return None
    (raw_page_size,) = _PAGE_SIZE.unpack_from(header, 16)
    page_size = 65_536 if raw_page_size == 1 else raw_page_size
    if page_size < 512 or page_size & (page_size - 1):
        return None  # a damaged header: the damage walk says where
    (counter,) = _COUNTER.unpack_from(header, 24)
    (pages,) = _COUNTER.unpack_from(header, 28)
    (valid_for,) = _COUNTER.unpack_from(header, 92)
    expected = pages * page_size if pages and counter == valid_for else None
    if _has_wal(path):
        return None  # a recorder killed mid-checkpoint leaves pages in the WAL: not a cut
    if expected is not None:
        return SqliteCut(path.name, size, expected, page_size) if size < expected else None
    return SqliteCut(path.name, size, None, page_size) if size % page_size else None


def _has_wal(path: Path | RemotePath) -> bool:
    """Whether the database's write-ahead log is beside it and not empty."""
    if isinstance(path, RemotePath):
        return False
    wal = path.with_name(f"{path.name}-wal")
    return wal.is_file() and wal.stat().st_size > 0
