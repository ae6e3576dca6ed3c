"""Local commit: build beside the target, then one atomic exchange; recovery after a crash.

A write into ``X`` builds in ``.X.tmp-<hex>`` beside it and holds an exclusive ``flock`` on that
folder while it lives.

- **Publish** (first write or ``--overwrite``): the build is renamed to ``X``, or, when ``X``
  exists, exchanged with it in one ``renameat2(RENAME_EXCHANGE)``: at every moment ``X`` is the old
  or the new dataset, never missing. The build path then holds the old dataset, which is removed.
  The build folder's lock moves with it: ``X`` stays locked until the write ends (the run may still
  read its staged episodes, for other formats).
  Where the exchange is unsupported (not Linux, or a file system without it) two renames are the
  fallback: ``X`` -> ``.X.old-<hex>``, build -> ``X``; a crash between them leaves ``X`` missing
  for a moment, and recovery renames the old one back.
- **Append**: the new data/video files and the ``meta/`` files the append writes are built; the
  other ``meta/`` files are hard-linked in (never read or copied); the intent record
  (:mod:`bagport.dataset.journal`) is written into ``X``; the new files are moved in (new names:
  no old file is touched, and LeRobot, which counts frames from ``meta/``, ignores rows past
  ``total_frames``); then ``X/meta`` and the new ``meta/`` are exchanged, the commit point.

Recovery (:func:`recover_local`, run before anything reads or writes ``X``): an append record is
rolled forward when ``X/meta/info.json`` is the new one, else back (the moved files are new names,
so they are removed); a build folder nobody holds the lock of is removed (complete or not, its
run never committed it: the staging store still has its episodes); with ``X`` missing the newest
complete ``.X.old-*`` is renamed back; remains of old datasets are removed. Only names bagport
makes are touched; a build still locked, or ``X`` itself locked (a write that published it and has not
ended), belongs to a live run and recovery refuses to go on.
"""

from __future__ import annotations

import ctypes
import errno
import fcntl
import os
import re
import shutil
import sys
import uuid
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from fsspec.implementations.local import LocalFileSystem

from bagport.dataset.crashpoints import reached
from bagport.dataset.journal import Journal, file_sha256, read_journal, remove_journal, write_journal
from bagport.dataset.layout import INFO_PATH
from bagport.errors import DatasetWriteError, OutputTakenError

__all__ = ["building_beside", "commit_append", "exchange", "recover_local", "swap_into_place"]

_SUFFIX = re.compile(r"\.(tmp|old)-[0-9a-f]{8}")
_AT_FDCWD = -100
_RENAME_EXCHANGE = 2
_SYS_RENAMEAT2 = {"x86_64": 316, "aarch64": 276}


def exchange(a: Path, b: Path) -> bool:
    """Swap the two existing paths in one atomic step; ``False`` where the OS or file system cannot."""
    if not sys.platform.startswith("linux"):
        return False
    libc = ctypes.CDLL(None, use_errno=True)
    args = (_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE)
    if hasattr(libc, "renameat2"):  # glibc >= 2.28
        result = libc.renameat2(*args)
    else:
        number = _SYS_RENAMEAT2.get(os.uname().machine)
        if number is None:
            return False
        result = libc.syscall(number, *args)
    if result == 0:
        return True
    code = ctypes.get_errno()
    if code in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP):
        return False
    raise OSError(code, f"exchanging {a} and {b}: {os.strerror(code)}")


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


def _busy(final: Path, build: Path) -> DatasetWriteError:
    return DatasetWriteError(
        f"another bagport run is writing {final} (its build folder {build} is in use); nothing was "
        "written. Fix: wait for that run to finish, or write to another --output."
    )


def _refuse_if_writing(final: Path) -> None:
    """``final`` locked: a run published it (its build folder's lock moved with the folder) and is still
    writing from it or from its staged episodes, so nothing of its write may be taken for a dead run's."""
    fd = _lock(final)
    if fd is None:
        raise DatasetWriteError(
            f"another bagport run is writing {final} (it is finishing the write it published there); "
            "nothing was written. Fix: wait for that run to finish, or write to another --output."
        )
    os.close(fd)


def _remove_unlocked(final: Path, build: Path) -> None:
    fd = _lock(build)
    if fd is None:
        raise _busy(final, build)
    try:
        shutil.rmtree(build)
    finally:
        os.close(fd)


def _prune_empty(path: Path, top: Path) -> None:
    """Remove the empty folders from ``path`` up to (not including) ``top``."""
    while path != top and path.is_dir() and not any(path.iterdir()):
        path.rmdir()
        path = path.parent


def _recover_append(final: Path, journal: Journal) -> list[str]:
    build = final.parent / journal.staged
    if build.is_dir():
        _remove_unlocked(final, build)  # refuses when the append is still running
    meta = final / "meta"
    retired = sorted(final.glob(".meta.old-*"))
    if not meta.exists() and retired:  # the fallback's two renames were cut in between: still old
        retired.pop().rename(meta)
    for extra in retired:
        shutil.rmtree(extra, ignore_errors=True)
    info = final / INFO_PATH
    if info.is_file() and file_sha256(info) == journal.info_sha256:
        remove_journal(LocalFileSystem(), str(final))
        return [f"finished an append into {final} that was committed (its new meta/ was in place)"]
    removed = _undo_append(final, journal)
    return [f"rolled back an append into {final} that was not committed: removed {removed} new file(s)"]


def _undo_append(final: Path, journal: Journal) -> int:
    """Remove the files an uncommitted append moved in, then its record; how many were removed."""
    removed = 0
    for rel in journal.files:  # new names by construction: present only because this append moved them
        target = final / rel
        if target.is_file():
            target.unlink()
            removed += 1
            _prune_empty(target.parent, final)
    remove_journal(LocalFileSystem(), str(final))
    return removed


def recover_local(final: Path) -> list[str]:
    """Bring ``final`` back to a consistent dataset after a crashed write; what was done, one line each
    (empty when there was nothing to do). See the module docstring."""
    actions: list[str] = []
    if final.is_dir():
        _refuse_if_writing(final)
    journal = read_journal(LocalFileSystem(), str(final)) if final.is_dir() else None
    if journal is not None:
        actions += _recover_append(final, journal)
    for build in _ours(final, "tmp"):
        _remove_unlocked(final, build)
        actions.append(f"removed {build.name}, the build folder of a run that did not finish")
    old = _ours(final, "old")
    if not final.exists():
        complete = [o for o in old if (o / INFO_PATH).is_file()]
        if complete:
            newest = max(complete, key=lambda o: o.stat().st_ctime)  # a rename sets ctime
            newest.rename(final)
            old.remove(newest)
            actions.append(
                f"restored the previous dataset from {newest.name} (a replace cut between renames)"
            )
    if final.exists():
        for remains in old:
            shutil.rmtree(remains, ignore_errors=True)  # a run finishing its own swap may race us here
            actions.append(f"removed {remains.name}, the remains of a replaced dataset")
        if journal is None:
            for retired in sorted(final.glob(".meta.old-*")):  # written by bagport before the journal
                if (final / "meta").exists():
                    shutil.rmtree(retired, ignore_errors=True)
                else:
                    retired.rename(final / "meta")
                actions.append(f"recovered {retired.name} of an append cut between its renames")
    return actions


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


def _replace(new: Path, current: Path, retired_name: str) -> None:
    """Put ``new`` at ``current``: one exchange (``new`` then holds the old one), else two renames."""
    if exchange(new, current):
        return
    retired = current.parent / retired_name
    current.rename(retired)
    try:
        new.rename(current)
    except OSError:
        retired.rename(current)
        raise
    retired.rename(new)  # as the exchange would have left it: the caller removes the old one


def swap_into_place(build: Path, final: Path, *, overwrite: bool) -> None:
    """Put the dataset built in ``build`` at ``final`` (replacing one there, atomically where the OS can, when
    ``overwrite``); ``build`` then holds the old dataset, if any, for the caller to remove. Without
    ``overwrite`` the output was absent when the write began: one that another run put there since is
    refused (:class:`OutputTakenError`), never replaced."""
    reached("local.publish.built")
    if not final.exists():
        try:
            build.rename(final)
            reached("local.publish.swapped")
            return
        except OSError as err:  # created between the check and the rename: a directory not empty
            if err.errno not in (errno.ENOTEMPTY, errno.EEXIST):
                raise
            if not overwrite:
                raise OutputTakenError(str(final)) from err
    elif not overwrite:
        raise OutputTakenError(str(final))
    _replace(build, final, f".{final.name}.old-{uuid.uuid4().hex[:8]}")
    reached("local.publish.swapped")


def _move_in(source: Path, target: Path) -> None:
    if target.exists():
        raise DatasetWriteError(f"{target} exists already; the dataset changed during the append")
    target.parent.mkdir(parents=True, exist_ok=True)
    source.rename(target)


def _link_unchanged(current: Path, new: Path) -> None:
    """Hard-link into ``new`` every file of ``current`` the append did not write (no byte is read or
    copied; the new ``meta/`` then is whole, and the exchange swaps whole folders)."""
    for path in sorted(current.rglob("*")):
        target = new / path.relative_to(current)
        if path.is_file() and not target.exists():
            target.parent.mkdir(parents=True, exist_ok=True)
            os.link(path, target)


def commit_append(build: Path, final: Path, added: Sequence[str]) -> None:
    """Move the new files ``added`` (relative paths) from ``build`` into ``final`` and exchange ``meta/``,
    under the intent record (see the module docstring). ``build/meta`` then holds the old ``meta/``."""
    _link_unchanged(final / "meta", build / "meta")
    reached("local.append.built")
    for rel in added:
        if (final / rel).exists():
            raise DatasetWriteError(f"{final / rel} exists already; the dataset changed during the append")
    journal = Journal("append", build.name, tuple(added), info_sha256=file_sha256(build / INFO_PATH))
    write_journal(LocalFileSystem(), str(final), journal)
    reached("local.append.journaled")
    try:
        for n, rel in enumerate(added):
            _move_in(build / rel, final / rel)
            if n == 0:
                reached("local.append.moving")
        reached("local.append.moved")
        _replace(build / "meta", final / "meta", f".meta.old-{uuid.uuid4().hex[:8]}")
    except Exception:
        _undo_append(final, journal)  # what a failure (not a kill) moved in goes at once
        raise
    reached("local.append.committed")
    shutil.rmtree(build / "meta", ignore_errors=True)
    reached("local.append.cleaned")
    remove_journal(LocalFileSystem(), str(final))
