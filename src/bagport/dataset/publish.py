"""Local publish: build a dataset beside its target, swap it into place, recover after a crash.

A write into ``X`` builds in ``.X.tmp-<hex>`` beside it and holds an exclusive ``flock`` on that
folder while it lives; replacing a dataset renames ``X`` to ``.X.old-<hex>``, the build to ``X``, then
removes the old one. A process killed on the way leaves those folders behind, and the next write into
``X`` recovers first (:func:`recover_local_publish`):

- a build folder nobody holds the lock of is left over from a crashed run and is removed: complete or
  not, it is never swapped in, because the run that made it never finished (its staging store still
  holds the episodes, so the re-run rebuilds them quickly);
- with ``X`` missing, the newest complete ``.X.old-*`` is renamed back: a crash between the two renames
  rolls back to the previous dataset, as a failure before them does (and as the object-store journal
  of :mod:`bagport.dataset.remote` does);
- with ``X`` present, ``.X.old-*`` folders are the remains of an interrupted removal and are removed.

Only folders named exactly as bagport names them are touched. A build folder still locked belongs to
a run writing ``X`` right now: recovery then refuses to go on.
"""

from __future__ import annotations

import fcntl
import os
import re
import shutil
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from bagport.errors import DatasetWriteError

__all__ = ["PublishRecovery", "building_beside", "recover_local_publish", "swap_into_place"]

_SUFFIX = re.compile(r"\.(tmp|old)-[0-9a-f]{8}")


@dataclass(frozen=True, slots=True)
class PublishRecovery:
    """What :func:`recover_local_publish` found and did."""

    restored: Path | None = None
    """The previous dataset renamed back to the target (a crash between the two renames)."""
    removed: tuple[Path, ...] = ()
    """Builds of crashed runs and remains of old datasets, removed."""


def _ours(final: Path, kind: str) -> list[Path]:
    """The ``.X.tmp-*`` or ``.X.old-*`` folders beside ``final``, by exact name."""
    if not final.parent.is_dir():
        return []
    prefix = f".{final.name}"
    found = []
    for item in final.parent.iterdir():
        rest = item.name[len(prefix) :] if item.name.startswith(prefix) else ""
        match = _SUFFIX.fullmatch(rest)
        if match and match.group(1) == kind and item.is_dir() and not item.is_symlink():
            found.append(item)
    return sorted(found)


def _lock(folder: Path) -> int | None:
    """An open descriptor holding ``folder``'s exclusive lock, or ``None`` when a live run holds it."""
    fd = os.open(folder, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        return None
    return fd


def recover_local_publish(final: Path) -> PublishRecovery:
    """Undo what a crashed write into ``final`` left beside it (see the module docstring)."""
    removed: list[Path] = []
    for build in _ours(final, "tmp"):
        fd = _lock(build)
        if fd is None:
            raise DatasetWriteError(
                f"another bagport run is writing {final} (its build folder {build} is in use); nothing was "
                "written. Fix: wait for that run to finish, or write to another --output."
            )
        try:
            shutil.rmtree(build)
        finally:
            os.close(fd)
        removed.append(build)
    restored = None
    old = _ours(final, "old")
    if not final.exists():
        complete = [o for o in old if (o / "meta" / "info.json").is_file()]
        if complete:
            newest = max(complete, key=lambda o: o.stat().st_ctime)  # a rename sets ctime
            newest.rename(final)
            old.remove(newest)
            restored = final
    if final.exists():
        for remains in old:
            shutil.rmtree(remains, ignore_errors=True)  # a run finishing its own swap may race us here
            removed.append(remains)
    return PublishRecovery(restored, tuple(removed))


@contextmanager
def building_beside(final: Path) -> Iterator[Path]:
    """A fresh ``.X.tmp-<hex>`` build folder beside ``final``, locked while in use and removed after
    (whatever of it was not moved into place)."""
    final.parent.mkdir(parents=True, exist_ok=True)
    build = final.parent / f".{final.name}.tmp-{uuid.uuid4().hex[:8]}"
    build.mkdir()
    fd = _lock(build)
    if fd is None:  # a fresh random name: nobody else can hold it
        raise DatasetWriteError(f"{build} was locked by another process as it was created")
    try:
        yield build
    finally:
        shutil.rmtree(build, ignore_errors=True)
        os.close(fd)


def swap_into_place(build: Path, final: Path) -> None:
    """Rename ``build`` to ``final``, replacing the dataset there (kept as ``.X.old-*`` until the new
    one is in place, then removed)."""
    if not final.exists():
        build.rename(final)
        return
    retired = final.parent / f".{final.name}.old-{uuid.uuid4().hex[:8]}"
    final.rename(retired)
    try:
        build.rename(final)
    except OSError:
        retired.rename(final)
        raise
    shutil.rmtree(retired, ignore_errors=True)
