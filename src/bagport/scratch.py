"""bagport's temporary folders, named so a later run can tell those of dead processes.

Every scratch folder is ``<tmp>/bagport-<kind>-<pid>-<random>`` (``tempfile.gettempdir()``). A run
killed with SIGKILL cannot remove its own; :func:`clean_dead_scratch`, called when a run starts
(and by ``bagport repair``), removes those whose process is gone. A folder of a live process,
or one without a pid in its name, is left alone.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["clean_dead_scratch", "scratch_dir", "scratch_folder"]

_NAME = re.compile(r"bagport-[a-z]+-(\d+)-\w+")


def scratch_dir(kind: str) -> Path:
    """A new scratch folder for this process (the caller removes it)."""
    return Path(tempfile.mkdtemp(prefix=f"bagport-{kind}-{os.getpid()}-"))


@contextmanager
def scratch_folder(kind: str) -> Iterator[Path]:
    """A scratch folder removed when the block ends."""
    folder = scratch_dir(kind)
    try:
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # someone else's process
    return True


def clean_dead_scratch(tmp: Path | None = None) -> list[Path]:
    """Remove the scratch folders of processes that no longer run; returns them."""
    top = tmp or Path(tempfile.gettempdir())
    removed = []
    for entry in top.iterdir() if top.is_dir() else ():
        match = _NAME.fullmatch(entry.name)
        pid = int(match.group(1)) if match else os.getpid()
        if pid != os.getpid() and not _alive(pid) and entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry, ignore_errors=True)
            removed.append(entry)
    return removed
