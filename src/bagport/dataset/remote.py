"""Publishing a dataset to an object store (S3 and the like), where there are no renames.

A dataset is always built locally first. Publishing then uploads under a journal
(:data:`APPEND_JOURNAL_PATH`, written first): it lists every file the publish adds, rewrites or
removes, and each file about to be rewritten or removed is first copied server-side to a backup
folder. Uploads go data and videos first (nothing refers to them yet), then ``meta/``, the run
records next to last and ``info.json`` last; stale files of a replaced dataset are removed after
that, and the journal and backup last of all. After a crash, :func:`recover_remote_publish` (run
before any conversion or append into that output) deletes what the publish added and restores the
backups: the previous version comes back whole (or nothing, for a first write). Readers that list
the dataset during the upload itself can see a mix of both versions; keep readers off an output
while it is written, or write each version to a new output.

An append (:func:`append_remote`) builds against a copy of the dataset's ``meta/`` and uploads only
its new data and video files and the ``meta/`` files that changed: existing data and video files
are never rewritten.
"""

from __future__ import annotations

import hashlib
import json
import tempfile
import uuid
from collections.abc import Callable, Sequence
from pathlib import Path

from fsspec import AbstractFileSystem
from fsspec.core import url_to_fs

from bagport.dataset.base import DatasetBase, read_base
from bagport.dataset.layout import APPEND_BACKUP_DIR, APPEND_JOURNAL_PATH, INFO_PATH
from bagport.dataset.meta import DatasetLimits
from bagport.errors import DatasetWriteError

__all__ = ["append_remote", "publish_remote", "recover_remote_publish"]


def recover_remote_publish(output: str) -> bool:
    """Undo a publish to ``output`` that did not complete; ``True`` if there was one."""
    fs, root = url_to_fs(output)
    root = root.rstrip("/")
    journal_path = f"{root}/{APPEND_JOURNAL_PATH}"
    if not fs.exists(journal_path):
        return False
    with fs.open(journal_path, "r", encoding="utf-8") as handle:
        journal = json.load(handle)
    for rel in journal["added"]:
        if fs.exists(f"{root}/{rel}"):
            fs.rm(f"{root}/{rel}")
    backup = f"{root}/{journal['backup']}"
    for rel in [*journal["rewritten"], *journal["removed"]]:
        if fs.exists(f"{backup}/{rel}"):  # else the crash came before its upload: the original is intact
            fs.copy(f"{backup}/{rel}", f"{root}/{rel}")
    if fs.exists(backup):
        fs.rm(backup, recursive=True)
    fs.rm(journal_path)
    return True


def publish_remote(local: Path, output: str, upload: Sequence[str], remove: Sequence[str] = ()) -> None:
    """Upload the files ``upload`` (relative to ``local``) to ``output`` and delete ``remove``, under the
    journal (see the module docstring)."""
    fs, root = url_to_fs(output)
    root = root.rstrip("/")
    existing = {path[len(root) + 1 :] for path in fs.find(root)} if fs.exists(root) else set()
    rewritten = [rel for rel in upload if rel in existing]
    backup = APPEND_BACKUP_DIR.format(run_id=uuid.uuid4().hex[:8])
    journal = {
        "backup": backup,
        "added": [rel for rel in upload if rel not in existing],
        "rewritten": rewritten,
        "removed": list(remove),
    }
    fs.pipe_file(f"{root}/{APPEND_JOURNAL_PATH}", json.dumps(journal).encode())
    for rel in [*rewritten, *remove]:
        fs.copy(f"{root}/{rel}", f"{root}/{backup}/{rel}")
    last = [rel for rel in upload if rel.startswith("meta/provenance/run")] + [INFO_PATH]
    first = [rel for rel in upload if not rel.startswith("meta/")]
    middle = [rel for rel in upload if rel.startswith("meta/") and rel not in last]
    for rel in [*first, *middle, *(rel for rel in last if rel in upload)]:
        _upload(fs, local / rel, f"{root}/{rel}")
    for rel in remove:
        fs.rm(f"{root}/{rel}")
    fs.rm(f"{root}/{APPEND_JOURNAL_PATH}")
    if fs.exists(f"{root}/{backup}"):
        fs.rm(f"{root}/{backup}", recursive=True)


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _files(folder: Path, under: str) -> list[str]:
    top = folder / under
    return (
        sorted(p.relative_to(folder).as_posix() for p in top.rglob("*") if p.is_file())
        if top.exists()
        else []
    )


def _download_meta(fs: AbstractFileSystem, root: str, local: Path) -> dict[str, str]:
    """Copy the dataset's ``meta/`` to ``local``; returns each file's digest."""
    digests = {}
    for remote in fs.find(f"{root}/meta"):
        rel = remote[len(root) + 1 :]
        target = local / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        fs.get_file(remote, str(target))
        digests[rel] = _sha256(target)
    return digests


def append_remote[Report](output: str, build: Callable[[Path, DatasetBase, DatasetLimits], Report]) -> Report:
    """Append to the dataset at ``output``: ``build(root, base, limits)`` writes the new episodes'
    files and the new ``meta/`` under a local ``root`` that holds a copy of the dataset's ``meta/``."""
    fs, root = url_to_fs(output)
    root = root.rstrip("/")
    recover_remote_publish(output)
    base = read_base(output)
    with tempfile.TemporaryDirectory(prefix="bagport-append-") as tmp:
        local = Path(tmp) / "dataset"
        before = _download_meta(fs, root, local)
        report = build(local, base, DatasetLimits.from_info(base.info))
        added = _files(local, "data") + _files(local, "videos")
        for rel in added:
            if fs.exists(f"{root}/{rel}"):
                raise DatasetWriteError(
                    f"{output}/{rel} exists already: the dataset changed during the append; nothing was written. "
                    "Fix: run the append again (one append at a time per dataset)."
                )
        changed = [rel for rel in _files(local, "meta") if before.get(rel) != _sha256(local / rel)]
        publish_remote(local, output, added + changed)
    return report


def _upload(fs: AbstractFileSystem, local: Path, remote: str) -> None:
    fs.put_file(str(local), remote)
