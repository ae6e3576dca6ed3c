"""Memory freed in a thread goes back to the system when the reduce asks (glibc keeps it in the thread's arena)."""

from __future__ import annotations

import subprocess
import sys

import pytest

FRAGMENT_THEN_RELEASE = """
import os
import threading
from pathlib import Path

from bagport.dataset.free_memory import release_unused_memory

def resident_mb():
    return int(Path("/proc/self/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20

kept = []

def fragment():
    # 64 KB blocks (below glibc's mmap threshold: in the thread's arena), written so they are resident,
    # each followed by a 1 KB block that stays (above pymalloc's 512 bytes: from the same arena), so the
    # arena cannot shrink from its top when the large ones go
    large = []
    for _ in range(800):
        large.append(b"x" * (64 * 1024))
        kept.append(b"y" * 1024)

thread = threading.Thread(target=fragment)
thread.start()
thread.join()
before_mb = resident_mb()
released = release_unused_memory()
print(released, before_mb - resident_mb(), len(kept))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's allocator")
def test_memory_freed_by_a_thread_is_handed_back() -> None:
    """In a fresh process (the test process's own arenas hold whatever earlier tests freed)."""
    done = subprocess.run(
        [sys.executable, "-c", FRAGMENT_THEN_RELEASE], capture_output=True, text=True, check=True, timeout=120
    )
    released, dropped_mb, kept = done.stdout.split()
    assert released == "True" and kept == "800"
    assert float(dropped_mb) > 25, dropped_mb  # of the ~50 MB freed
