"""``--append`` to a dataset on an object store (S3 and the like), where there are no renames.

The new episodes are built locally against a copy of the dataset's ``meta/``. Publishing then
never rewrites a data or video file: the new data and video files are uploaded first (nothing
refers to them yet), then the new and changed ``meta/`` files, the run record and ``info.json``
last. Before the first upload, a journal (:data:`APPEND_JOURNAL_PATH`) lists every file the append
adds and rewrites, and the ``meta/`` files about to be rewritten are copied server-side to a backup
folder; the journal is removed when the append is complete. After a crash, :func:`recover_remote_append` (run
by the next append, or any run planning an append) deletes what the append added and restores the
backup: the previous version comes back whole. A reader that lists the dataset while an append
uploads (a few seconds) can see new ``meta/`` files before ``info.json`` counts them.
"""

from __future__ import annotations

import hashlib
import json
import tempfile
import uuid
from collections.abc import Callable
from pathlib import Path

from fsspec import AbstractFileSystem
from fsspec.core import url_to_fs

from bagport.dataset.base import DatasetBase, read_base
from bagport.dataset.layout import APPEND_BACKUP_DIR, APPEND_JOURNAL_PATH, INFO_PATH
from bagport.dataset.meta import DatasetLimits
from bagport.errors import DatasetWriteError

__all__ = ["append_remote", "recover_remote_append"]


def recover_remote_append(output: str) -> bool:
    """Undo an append to ``output`` that did not complete; ``True`` if there was one."""
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
    for rel in journal["rewritten"]:
        if fs.exists(f"{backup}/{rel}"):  # else the crash came before its upload: the original is intact
            fs.copy(f"{backup}/{rel}", f"{root}/{rel}")
    if fs.exists(backup):
        fs.rm(backup, recursive=True)
    fs.rm(journal_path)
    return True


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
    recover_remote_append(output)
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
        meta = [rel for rel in _files(local, "meta") if before.get(rel) != _sha256(local / rel)]
        rewritten = [rel for rel in meta if rel in before]
        created = [rel for rel in meta if rel not in before]
        backup = APPEND_BACKUP_DIR.format(run_id=uuid.uuid4().hex[:8])
        journal = {"backup": backup, "added": added + created, "rewritten": rewritten}
        fs.pipe_file(f"{root}/{APPEND_JOURNAL_PATH}", json.dumps(journal).encode())
        for rel in rewritten:
            fs.copy(f"{root}/{rel}", f"{root}/{backup}/{rel}")
        # data and videos first, then meta, the run records next to last and info.json last
        last = [rel for rel in meta if rel.startswith("meta/provenance/run")] + [INFO_PATH]
        for rel in added + [rel for rel in meta if rel not in last] + [rel for rel in last if rel in meta]:
            _upload(fs, local / rel, f"{root}/{rel}")
        fs.rm(f"{root}/{APPEND_JOURNAL_PATH}")
        if rewritten:
            fs.rm(f"{root}/{backup}", recursive=True)
    return report


def _upload(fs: AbstractFileSystem, local: Path, remote: str) -> None:
    fs.put_file(str(local), remote)
