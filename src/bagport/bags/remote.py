"""Read a bag on a remote fsspec store in place, with ranged reads, instead of downloading it.

rosbags' readers take any path object with the small ``RPath`` protocol (``open``,
``exists``, ``/`` ...). :class:`RemotePath` is one over an fsspec filesystem: its files
are read with HTTP range requests, so an MCAP reader that seeks to the summary and then
only to the chunks holding the requested topics transfers only those bytes. Every byte
fetched is kept in a sparse local spill file, so the reader's later passes over the same
chunks (timeline, frames, safety) never fetch a byte twice: the bytes transferred are at
most the file size. :class:`TransferStats` counts them.
"""

from __future__ import annotations

import bisect
import io
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from fsspec import AbstractFileSystem

from bagport.errors import TransientError
from bagport.scratch import scratch_dir

__all__ = ["RemoteBag", "RemotePath", "TransferStats"]

MIN_BLOCK_BYTES = 8 * 1024
"""Smallest ranged read: a small read after a seek (a record header) fetches this much."""
MAX_BLOCK_BYTES = 1024 * 1024
"""Sequential small reads (the summary, record by record) double the block up to this size."""


@dataclass(slots=True)
class TransferStats:
    """Bytes and requests that reading a bag cost on its store."""

    access: str
    """``local`` (read in place on disk), ``download`` (copied whole first) or ``ranged``."""
    bytes_read: int = 0
    requests: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {"access": self.access, "bytes_read": self.bytes_read, "requests": self.requests}


class _SpilledRanges:
    """The byte ranges of one remote file fetched so far, kept in a sparse local file."""

    def __init__(self, bag: RemoteBag, path: str, size: int) -> None:
        self._bag = bag
        self._path = path
        self.size = size
        handle, name = tempfile.mkstemp(prefix="range-", dir=bag.scratch)
        os.close(handle)
        self._spill = Path(name).open("r+b")  # noqa: SIM115 - closed by RemoteBag.close
        self._starts: list[int] = []
        self._ends: list[int] = []

    def _gaps(self, start: int, end: int) -> list[tuple[int, int]]:
        gaps = []
        at = start
        index = max(0, bisect.bisect_right(self._starts, start) - 1)
        while at < end and index < len(self._starts):
            lo, hi = self._starts[index], self._ends[index]
            if hi <= at:
                index += 1
                continue
            if lo > at:
                gaps.append((at, min(lo, end)))
            at = max(at, hi)
            index += 1
        if at < end:
            gaps.append((at, end))
        return gaps

    def _mark(self, start: int, end: int) -> None:
        index = bisect.bisect_left(self._starts, start)
        self._starts.insert(index, start)
        self._ends.insert(index, end)
        starts: list[int] = []
        ends: list[int] = []
        for lo, hi in zip(self._starts, self._ends, strict=True):
            if ends and lo <= ends[-1]:
                ends[-1] = max(ends[-1], hi)
            else:
                starts.append(lo)
                ends.append(hi)
        self._starts, self._ends = starts, ends

    def read(self, start: int, end: int, fetch_end: int) -> bytes:
        """Bytes ``[start, end)``; missing bytes up to ``fetch_end`` are fetched with them."""
        for lo, hi in self._gaps(start, max(end, min(fetch_end, self.size))):
            data = self._bag.fetch(self._path, lo, hi)
            self._spill.seek(lo)
            self._spill.write(data)
            self._mark(lo, lo + len(data))
        self._spill.seek(start)
        return self._spill.read(end - start)

    def close(self) -> None:
        self._spill.close()


class _RangedFile(io.RawIOBase):
    """A seekable, read-only raw file over one remote file's spilled ranges."""

    def __init__(self, ranges: _SpilledRanges) -> None:
        self._ranges = ranges
        self._pos = 0
        self._last_end = -1
        self._block = MIN_BLOCK_BYTES

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def tell(self) -> int:
        return self._pos

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        base = {io.SEEK_SET: 0, io.SEEK_CUR: self._pos, io.SEEK_END: self._ranges.size}[whence]
        self._pos = max(0, base + offset)
        return self._pos

    def readinto(self, buffer: Any) -> int:
        view = memoryview(buffer).cast("B")
        count = max(0, min(len(view), self._ranges.size - self._pos))
        if not count:
            return 0
        sequential = self._pos == self._last_end
        self._block = min(2 * self._block, MAX_BLOCK_BYTES) if sequential else MIN_BLOCK_BYTES
        end = self._pos + count
        view[:count] = self._ranges.read(self._pos, end, self._pos + self._block)
        self._pos = self._last_end = end
        return count


@dataclass
class RemoteBag:
    """One remote bag's filesystem, transfer counters and spilled ranges; close it after use."""

    fs: AbstractFileSystem
    uri: str
    stats: TransferStats = field(default_factory=lambda: TransferStats("ranged"))
    scratch: Path = field(default_factory=lambda: scratch_dir("ranges"))
    _files: dict[str, _SpilledRanges] = field(default_factory=dict)

    def fetch(self, path: str, start: int, end: int) -> bytes:
        try:
            data = bytes(self.fs.cat_file(path, start=start, end=end))
        except FileNotFoundError:
            raise
        except (ConnectionError, TimeoutError, OSError) as err:
            raise TransientError(
                f"{self.uri}: ranged read of {path} [{start}, {end}) failed ({type(err).__name__}: {err}); "
                "try again"
            ) from err
        self.stats.bytes_read += len(data)
        self.stats.requests += 1
        if len(data) != end - start:
            raise TransientError(
                f"{self.uri}: ranged read of {path} [{start}, {end}) returned {len(data)} bytes "
                "(the object changed or the store cut the response); try again"
            )
        return data

    def ranges(self, path: str, size: int) -> _SpilledRanges:
        ranges = self._files.get(path)
        if ranges is None:
            ranges = self._files[path] = _SpilledRanges(self, path, size)
        return ranges

    def close(self) -> None:
        for ranges in self._files.values():
            ranges.close()
        self._files.clear()
        shutil.rmtree(self.scratch, ignore_errors=True)


@dataclass(frozen=True)
class _StatResult:
    st_size: int


class RemotePath:
    """A file or folder of a :class:`RemoteBag`, with the part of ``pathlib.Path`` rosbags uses.

    ``name`` may differ from the object's real name: rosbags picks its reader by suffix, so
    a file is presented under a name that fits its content (as a symlink does on disk).
    """

    def __init__(self, bag: RemoteBag, path: str, name: str | None = None) -> None:
        self.bag = bag
        self.path = path.rstrip("/")
        self.name = name or self.path.rsplit("/", 1)[-1]

    def __repr__(self) -> str:
        return f"RemotePath({self.path!r})"

    def __str__(self) -> str:
        return self.path

    def __truediv__(self, key: object) -> RemotePath:
        return RemotePath(self.bag, f"{self.path}/{key}")

    @property
    def suffix(self) -> str:
        stem, dot, suffix = self.name.rpartition(".")
        return f".{suffix}" if dot and stem else ""

    @property
    def stem(self) -> str:
        return self.name[: len(self.name) - len(self.suffix)]

    def renamed(self, name: str) -> RemotePath:
        return RemotePath(self.bag, self.path, name)

    def exists(self) -> bool:
        return bool(self.bag.fs.exists(self.path))

    def is_dir(self) -> bool:
        return bool(self.bag.fs.isdir(self.path))

    def is_file(self) -> bool:
        return bool(self.bag.fs.isfile(self.path))

    def iterdir(self) -> list[RemotePath]:
        return [RemotePath(self.bag, str(p)) for p in sorted(self.bag.fs.ls(self.path, detail=False))]

    def stat(self, *, follow_symlinks: bool = True) -> _StatResult:
        del follow_symlinks
        return _StatResult(int(self.bag.fs.size(self.path)))

    def read_text(self, encoding: str | None = None) -> str:
        with self.open("rb") as handle:
            return handle.read().decode(encoding or "utf-8")

    def open(self, mode: str = "rb", *args: object, **kwargs: object) -> IO[bytes]:
        del args, kwargs
        if mode not in ("rb", "r"):
            raise PermissionError(f"{self.path}: remote bags are opened read-only")
        ranges = self.bag.ranges(self.path, self.stat().st_size)
        return io.BufferedReader(_RangedFile(ranges), buffer_size=4096)
