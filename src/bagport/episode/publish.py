"""An episode's finished work folder moved into the staging store, its summary last (the completion marker).

On a local staging store on the scratch folder's file system (the default: both under one disk), the
work folder is renamed into place whole: one rename, where moving its files one by one took a folder
made per subfolder, a rename per file, and the emptied folders removed. Removing a folder waits on
ext4's journal: 1-6.5 ms per ``rmdir`` in a pool worker under load, three per small episode (W3: up to
20 ms of an episode's ~150). Elsewhere (an object store, another file system) the files are copied or
renamed one by one, as before. Either way the staged folder has the modes a folder made here has (the
work folder was made private, ``tempfile.mkdtemp``), and ``episode.json`` is written after every other
file is in place.
"""

from __future__ import annotations

import functools
import tempfile
from pathlib import Path

from fsspec import AbstractFileSystem
from fsspec.core import url_to_fs

from bagport.staging import EPISODE_SUMMARY, EpisodeSummary, staged_path, write_json
from bagport.uris import is_local

__all__ = ["publish_episode"]


def publish_episode(workdir: Path, target: str, summary: EpisodeSummary) -> None:
    """Move ``workdir``'s files to ``target`` (replacing what is there), then write the summary."""
    fs, path = url_to_fs(target)
    if fs.exists(path):
        fs.rm(path, recursive=True)
    local = is_local(fs)
    if not (local and _renamed_whole(workdir, Path(path))):
        _move_files(fs, workdir, path, local=local)
    write_json(staged_path(target, EPISODE_SUMMARY), summary.to_dict())


def _renamed_whole(workdir: Path, target: Path) -> bool:
    """``workdir`` renamed to ``target`` with a new folder's modes; ``False`` (nothing moved) when they are
    on two file systems."""
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        workdir.rename(target)
    except OSError:  # EXDEV: another file system (or a target a racing writer made: copied instead)
        return False
    target.chmod(_new_folder_mode())
    return True


@functools.cache
def _new_folder_mode() -> int:
    """The mode ``mkdir`` gives a folder in this process (0o777 less the umask), read once from a probe."""
    with tempfile.TemporaryDirectory(prefix="bagport-mode-") as private:
        probe = Path(private) / "probe"
        probe.mkdir()
        return probe.stat().st_mode & 0o7777


def _move_files(fs: AbstractFileSystem, workdir: Path, path: str, *, local: bool) -> None:
    fs.makedirs(path, exist_ok=True)
    made = {path.rstrip("/")}
    for item in sorted(workdir.rglob("*")):
        if item.is_file():
            remote = staged_path(path, item.relative_to(workdir).as_posix())
            parent = remote.rsplit("/", 1)[0]
            if parent not in made:
                fs.makedirs(parent, exist_ok=True)
                made.add(parent)
            if not (local and _renamed(item, remote)):
                fs.put_file(str(item), remote)


def _renamed(source: Path, target: str) -> bool:
    """``source`` renamed to ``target`` when both are on one local file system (no copy); ``False`` when
    they are not, and it is copied instead."""
    try:
        source.replace(target)
    except OSError:  # EXDEV: another file system
        return False
    return True
