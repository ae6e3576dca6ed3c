"""Memory freed but still held by the process: Arrow's pool (mimalloc) keeps what Arrow freed for its next
allocations, and glibc's allocator keeps freed blocks in each thread's arena (the flow's file-writer
threads, Prefect's own); both give it back to the system only when asked. The commit asks between its
steps (``meta/episodes``, provenance, the QA table and index), and the reduce after its file tasks: each
step's peak is then not added to the next one's in the flow process's resident memory. Measured with
``bench/reduce_map.py --parts reduce`` and W4's flow process (BENCHMARKS.md)."""

from __future__ import annotations

import ctypes
import functools
import sys

import pyarrow as pa

__all__ = ["release_unused_memory"]


def release_unused_memory() -> bool:
    """Hand back to the system what Arrow's pool and the C allocator hold unused (cheap; nothing in use
    is touched). Whether the C allocator gave any back (``False`` where it cannot be asked: not glibc)."""
    pa.default_memory_pool().release_unused()
    trim = _malloc_trim()
    return trim is not None and bool(trim(0))


@functools.cache
def _malloc_trim() -> ctypes._NamedFuncPointer | None:
    """glibc's ``malloc_trim``, or ``None`` (another C library, another system)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        function = ctypes.CDLL("libc.so.6").malloc_trim
    except (OSError, AttributeError):  # musl and others have no malloc_trim
        return None
    function.argtypes = [ctypes.c_size_t]
    function.restype = ctypes.c_int
    return function
