"""Which files something opened or read: Linux inotify on each file (catches every process and every
I/O library: Python, Arrow's C++ readers, ffmpeg), and the S3 objects moto's in-process server served."""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import select
import struct
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

__all__ = ["s3_reads", "watch_reads"]

_IN_ACCESS = 0x001
_IN_OPEN = 0x020
_EVENT = struct.Struct("iIII")


@contextmanager
def watch_reads(paths: Sequence[Path]) -> Iterator[set[Path]]:
    """Yields a set that, on exit, holds every path of ``paths`` that was opened or read meanwhile."""
    libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
    fd = libc.inotify_init1(os.O_NONBLOCK)
    if fd < 0:
        raise OSError(ctypes.get_errno(), "inotify_init1 failed")
    watches: dict[int, Path] = {}
    for path in paths:
        wd = libc.inotify_add_watch(fd, str(path).encode(), _IN_OPEN | _IN_ACCESS)
        if wd < 0:
            raise OSError(ctypes.get_errno(), f"inotify_add_watch {path}")
        watches[wd] = path
    touched: set[Path] = set()
    try:
        yield touched
    finally:
        while select.select([fd], [], [], 0.2)[0]:
            try:
                buffer = os.read(fd, 65536)
            except BlockingIOError:
                break
            offset = 0
            while offset < len(buffer):
                wd, _, _, name_len = _EVENT.unpack_from(buffer, offset)
                if wd in watches:
                    touched.add(watches[wd])
                offset += _EVENT.size + name_len
        os.close(fd)


@contextmanager
def s3_reads() -> Iterator[list[str]]:
    """Yields a list that collects ``bucket/key`` of every object moto's in-process S3 server sends
    (GET, ranged GET) or copies server-side (``copy:`` + the copy-source header) while inside."""
    from moto.s3.responses import S3Response  # noqa: PLC0415

    keys: list[str] = []
    original_get = S3Response.get_object
    original_copy = S3Response.copy_object

    def get_object(self: S3Response) -> Any:
        keys.append(f"{self.bucket_name}/{self.parse_key_name()}")
        return original_get(self)

    def copy_object(self: S3Response) -> Any:
        keys.append(f"copy:{self.headers.get('x-amz-copy-source')}")
        return original_copy(self)

    S3Response.get_object = get_object  # type: ignore[method-assign]
    S3Response.copy_object = copy_object  # type: ignore[method-assign]
    try:
        yield keys
    finally:
        S3Response.get_object = original_get  # type: ignore[method-assign]
        S3Response.copy_object = original_copy  # type: ignore[method-assign]
