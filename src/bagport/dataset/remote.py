"""Publishing a dataset to an object store (S3 and the like), where there are no renames.

A dataset is always built locally first. Publishing (a first write, ``--overwrite`` or an append)
then goes through the intent record of :mod:`bagport.dataset.journal`, at ``<root>/.bagport-journal.json``:

1. the record (state ``staged``) lists every file the publish adds or rewrites and every file of
   the previous version it removes;
2. the files are uploaded under ``<root>/.bagport-staged-<hex>/`` (not under ``data/`` or
   ``meta/``: LeRobot never reads them, and the previous version stays whole and readable);
3. the record flips to ``committing`` (one PUT of one object: the commit point);
4. ``meta/info.json`` is deleted, the staged files are copied server-side to their keys
   (``meta/info.json`` last), the previous version's extra files are deleted, then the staged
   copies and the record.

Recovery (:func:`recover_remote`, run before anything reads or writes the output) drops a
``staged`` record and its uploads (the previous version was never touched), and finishes a
``committing`` one (every step is a copy from the staged content or a delete: repeatable).
A reader therefore sees the previous version, until the commit, then, during the server-side
copies only (and after a crash there, until the next run or ``bagport repair``), no
``meta/info.json`` (LeRobot refuses to load: never a mix of versions), then the new version.
An append uploads only its new data and video files (new keys) and the ``meta/`` files that
changed: existing data and video files are never rewritten.
"""

from __future__ import annotations

import json
import uuid
from collections.abc import Mapping, Sequence
from pathlib import Path

from fsspec import AbstractFileSystem
from fsspec.core import url_to_fs

from bagport.dataset.crashpoints import reached
from bagport.dataset.journal import Journal, file_sha256, read_journal, remove_journal, write_journal
from bagport.dataset.layout import INFO_PATH, STAGED_DIR
from bagport.errors import DatasetWriteError, OutputTakenError

__all__ = ["drop_staged", "publish_remote", "publish_staged", "recover_remote"]

_LEGACY_JOURNAL = ".append-journal.json"


def _roll_forward(fs: AbstractFileSystem, root: str, journal: Journal) -> None:
    staged = f"{root}/{journal.staged}"
    waiting = {path[len(staged) + 1 :] for path in fs.find(staged)}  # staged copies go after the last copy
    if INFO_PATH in waiting and fs.exists(f"{root}/{INFO_PATH}"):
        fs.rm(f"{root}/{INFO_PATH}")  # from here to the end, readers find no dataset rather than a mix
    reached("s3.retracted")
    for n, rel in enumerate(rel for rel in journal.files if rel != INFO_PATH and rel in waiting):
        fs.copy(f"{staged}/{rel}", f"{root}/{rel}")
        if n == 0:
            reached("s3.copying")
    reached("s3.copied")
    for rel in journal.remove:
        if fs.exists(f"{root}/{rel}"):
            fs.rm(f"{root}/{rel}")
    reached("s3.removed")
    if INFO_PATH in waiting:
        fs.copy(f"{staged}/{INFO_PATH}", f"{root}/{INFO_PATH}")
    reached("s3.published")
    if waiting:
        fs.rm(staged, recursive=True)
    reached("s3.cleaned")
    remove_journal(fs, root)


def _recover_legacy(fs: AbstractFileSystem, root: str) -> list[str]:
    """Roll back a publish of bagport before the intent record (its ``.append-journal.json`` and
    server-side backups of what it rewrote or removed)."""
    path = f"{root}/{_LEGACY_JOURNAL}"
    if not fs.exists(path):
        return []
    with fs.open(path, "r", encoding="utf-8") as handle:
        legacy = json.load(handle)
    for rel in legacy["added"]:
        if fs.exists(f"{root}/{rel}"):
            fs.rm(f"{root}/{rel}")
    backup = f"{root}/{legacy['backup']}"
    for rel in [*legacy["rewritten"], *legacy["removed"]]:
        if fs.exists(f"{backup}/{rel}"):
            fs.copy(f"{backup}/{rel}", f"{root}/{rel}")
    if fs.exists(backup):
        fs.rm(backup, recursive=True)
    fs.rm(path)
    return [f"rolled back a publish into {root} left by an older bagport (its {_LEGACY_JOURNAL})"]


def recover_remote(output: str) -> list[str]:
    """Finish or undo a publish to ``output`` that did not complete; what was done (empty: nothing)."""
    fs, root = url_to_fs(output)
    root = root.rstrip("/")
    fs.invalidate_cache()
    legacy = _recover_legacy(fs, root)
    if legacy:
        return legacy
    journal = read_journal(fs, root)
    if journal is None:
        return []
    if journal.state == "committing":
        _roll_forward(fs, root, journal)
        return [f"finished a {journal.op} into {output} that was committed ({len(journal.files)} file(s))"]
    if fs.exists(f"{root}/{journal.staged}"):
        fs.rm(f"{root}/{journal.staged}", recursive=True)
    remove_journal(fs, root)
    return [f"dropped a {journal.op} into {output} that was not committed; the previous version is unchanged"]


def refuse_taken(fs: AbstractFileSystem, output: str, root: str, *, overwrite: bool) -> None:
    """A first write (no ``overwrite``) finds the output as it began, without a dataset: one that another run
    published meanwhile is refused, never replaced (an object store cannot make this check and the
    commit one step, so two runs racing to the last moment are not caught; one run per output)."""
    if overwrite or not fs.exists(f"{root}/{INFO_PATH}"):
        return
    raise OutputTakenError(output)


def publish_remote(
    local: Path, output: str, upload: Sequence[str], remove: Sequence[str] = (), *, overwrite: bool
) -> None:
    """Upload the files ``upload`` (relative to ``local``) to ``output`` and delete ``remove``, under the
    intent record (see the module docstring); another run's output published there meanwhile is refused
    unless ``overwrite``."""
    fs, root = url_to_fs(output)
    root = root.rstrip("/")
    fs.invalidate_cache()
    refuse_taken(fs, output, root, overwrite=overwrite)
    reached("s3.built")
    ordered = [rel for rel in upload if rel != INFO_PATH] + [INFO_PATH]
    journal = Journal(
        op="publish",
        staged=STAGED_DIR.format(run_id=uuid.uuid4().hex[:8]),
        files=tuple(ordered),
        remove=tuple(remove),
        info_sha256=file_sha256(local / INFO_PATH),
    )
    write_journal(fs, root, journal)
    reached("s3.journaled")
    for n, rel in enumerate(ordered):
        _upload(fs, local / rel, f"{root}/{journal.staged}/{rel}")
        if n == 0:
            reached("s3.staging")
    reached("s3.staged")
    write_journal(fs, root, journal.committing())
    reached("s3.committing")
    _roll_forward(fs, root, journal)


def _files(folder: Path, under: str) -> list[str]:
    top = folder / under
    return (
        sorted(p.relative_to(folder).as_posix() for p in top.rglob("*") if p.is_file())
        if top.exists()
        else []
    )


def drop_staged(output: str, staged: str) -> None:
    """Remove the uploads under ``staged`` and their ``staged`` record, if that write never committed
    (a write that committed, or is committing, is left alone)."""
    fs, root = url_to_fs(output)
    root = root.rstrip("/")
    fs.invalidate_cache()
    journal = read_journal(fs, root)
    if journal is None or journal.staged != staged or journal.state != "staged":
        return
    if fs.exists(f"{root}/{staged}"):
        fs.rm(f"{root}/{staged}", recursive=True)
    remove_journal(fs, root)


def _removed(fs: AbstractFileSystem, root: str, keep: set[str]) -> list[str]:
    """The previous version's files a replacing write does not have (bagport's own hidden keys aside)."""
    existing = {p[len(root) + 1 :] for p in fs.find(root)} if fs.exists(root) else set()
    return sorted(rel for rel in existing - keep if not rel.startswith(".bagport-"))


def publish_staged(
    local: Path, output: str, staged: str, written: Mapping[str, str], *, append: bool, overwrite: bool
) -> None:
    """Commit a write whose data and video files (``written``: relative path -> digest) the file writers
    uploaded under ``<root>/<staged>/`` already: upload the ``meta/`` built in ``local`` there too, record
    every file (and, replacing a dataset, the previous version's files to remove), then commit (see the
    module docstring). Old objects an append does not change stay where they are, unread."""
    fs, root = url_to_fs(output)
    root = root.rstrip("/")
    fs.invalidate_cache()
    reached("s3.files")
    meta = [rel for rel in _files(local, "meta") if rel != INFO_PATH] + [INFO_PATH]
    for rel in written if append else ():
        if fs.exists(f"{root}/{rel}"):
            raise DatasetWriteError(
                f"{output}/{rel} exists already: the dataset changed during the append; nothing was written. "
                "Fix: run the append again (one append at a time per dataset)."
            )
    if not append:
        refuse_taken(fs, output, root, overwrite=overwrite)
    remove = () if append else tuple(_removed(fs, root, {*written, *meta}))
    reached("s3.built")
    journal = Journal(
        op="append" if append else "publish", staged=staged, files=(*sorted(written), *meta), remove=remove,
        info_sha256=file_sha256(local / INFO_PATH),
    )  # fmt: skip
    for n, rel in enumerate(meta):
        _upload(fs, local / rel, f"{root}/{staged}/{rel}")
        if n == 0:
            reached("s3.staging")
    write_journal(fs, root, journal)
    reached("s3.staged")
    _check_staged_whole(fs, output, root, journal)
    write_journal(fs, root, journal.committing())
    reached("s3.committing")
    _roll_forward(fs, root, journal)


def _check_staged_whole(fs: AbstractFileSystem, output: str, root: str, journal: Journal) -> None:
    """Before the commit point: every file the record names is under its staged prefix. An object store has
    no locks, so another run's recovery can take a live write's uploads for a dead run's and drop them; the
    commit would then publish a ``meta/`` whose data or video files do not exist."""
    fs.invalidate_cache()
    prefix = f"{root}/{journal.staged}/"
    present = {path[len(prefix) :] for path in fs.find(prefix)}
    missing = [rel for rel in journal.files if rel not in present]
    if missing:
        raise DatasetWriteError(
            f"{len(missing)} of the {len(journal.files)} files this run uploaded under {prefix} are gone (first: "
            f"{missing[0]}): another run with the same output took this write for a dead one and dropped it; "
            f"nothing was published and {output} is as it was. Fix: run again, one run at a time per output."
        )


def _upload(fs: AbstractFileSystem, local: Path, remote: str) -> None:
    fs.put_file(str(local), remote)
