"""Arrow's memory pool (mimalloc) keeps what Arrow freed for its next allocations and gives it back to the
system only when asked. The commit asks between its steps (``meta/episodes``, provenance, the QA table and
index): each step's peak is then not added to the next one's in the flow process's resident memory.
Measured with ``bench/reduce_map.py --parts reduce`` (BENCHMARKS.md)."""

from __future__ import annotations

import pyarrow as pa

__all__ = ["release_arrow_memory"]


def release_arrow_memory() -> None:
    """Hand the memory Arrow's pool holds unused back to the system (cheap; nothing in use is touched)."""
    pa.default_memory_pool().release_unused()
