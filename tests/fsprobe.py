"""Kernel-level evidence that files were not read: inotify watches (Linux) on each file report every
open and read, by any library or process (pyarrow's and FFmpeg's C code included)."""

from __future__ import annotations

import ctypes
import os
import struct
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

__all__ = ["watch_opens"]

_IN_ACCESS = 0x1
_IN_OPEN = 0x20
_IN_NONBLOCK = 0o4000
_EVENT = struct.Struct("iIII")


class Opens:
    """What happened to the watched files while the block ran: (path, 'open' or 'read') per event."""

    def __init__(self, fd: int, watched: dict[int, Path]) -> None:
        self._fd, self._watched, self.events = fd, watched, list[tuple[Path, str]]()

    def collect(self) -> None:
        try:
            raw = os.read(self._fd, 1 << 20)
        except BlockingIOError:
            return
        offset = 0
        while offset < len(raw):
            wd, mask, _, size = _EVENT.unpack_from(raw, offset)
            offset += _EVENT.size + size
            kind = "open" if mask & _IN_OPEN else "read"
            self.events.append((self._watched[wd], kind))


@contextmanager
def watch_opens(paths: Sequence[Path]) -> Iterator[Opens]:
    """Watch ``paths`` for opens and reads while the block runs (``events`` filled when it ends)."""
    libc = ctypes.CDLL(None, use_errno=True)
    fd = libc.inotify_init1(_IN_NONBLOCK)
    assert fd >= 0, os.strerror(ctypes.get_errno())
    watched = {}
    for path in paths:
        wd = libc.inotify_add_watch(fd, os.fsencode(path), _IN_OPEN | _IN_ACCESS)
        assert wd >= 0, os.strerror(ctypes.get_errno())
        watched[wd] = path
    opens = Opens(fd, watched)
    try:
        yield opens
    finally:
        opens.collect()
        os.close(fd)
