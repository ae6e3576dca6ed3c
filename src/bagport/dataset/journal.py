"""The intent record of a publish or append: written before anything visible changes.

One record, one place, for local disk and object stores: ``<dataset>/.bagport-journal.json``
(:data:`bagport.dataset.layout.JOURNAL_PATH`, outside ``data/`` and ``meta/``, so LeRobot never
reads it). It says what the write is about to do: which files (relative to the dataset root)
it adds or rewrites, which it removes, where their new content waits (``staged``) and the
SHA-256 of the new ``meta/info.json``. Every step after it is idempotent, so recovery
(:mod:`bagport.dataset.repair`) can always finish or undo the write from the record alone:

- before the commit point, it rolls back (removes what was added, drops the staged content);
- after it, it rolls forward (completes the copies and removals, then drops the record).

The commit point is one atomic act: locally the exchange of ``meta/`` (an append) or of the
whole folder (a publish, which needs no record: its build folder and lock say everything);
on an object store the record's own flip from ``staged`` to ``committing``.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Literal

from fsspec import AbstractFileSystem

from bagport.dataset.layout import JOURNAL_PATH
from bagport.staging import replace_whole
from bagport.uris import is_local

__all__ = ["Journal", "file_sha256", "read_journal", "remove_journal", "write_journal"]

State = Literal["staged", "committing"]


@dataclass(frozen=True, slots=True)
class Journal:
    op: Literal["publish", "append"]
    staged: str
    """Where the new content waits: a build folder beside the dataset (local, its name) or a prefix
    inside it (object store, relative to the dataset root)."""
    files: tuple[str, ...]
    """Files the write adds or rewrites, relative to the dataset root, in commit order (info.json last)."""
    remove: tuple[str, ...] = ()
    """Files of the previous version the new one does not have (a replaced dataset)."""
    info_sha256: str = ""
    """The new ``meta/info.json``'s digest: locally, the append is committed once ``meta/`` has it."""
    state: State = "staged"

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=1)

    @classmethod
    def from_dict(cls, raw: dict[str, Any]) -> Journal:
        return cls(
            op=raw["op"],
            staged=str(raw["staged"]),
            files=tuple(raw["files"]),
            remove=tuple(raw.get("remove", ())),
            info_sha256=str(raw.get("info_sha256", "")),
            state=raw.get("state", "staged"),
        )

    def committing(self) -> Journal:
        return replace(self, state="committing")


def write_journal(fs: AbstractFileSystem, root: str, journal: Journal) -> None:
    """Write (or replace, in one request/rename) the record of the dataset at ``root``."""
    path = f"{root}/{JOURNAL_PATH}"
    if is_local(fs):
        replace_whole(Path(path), journal.to_json())  # atomic: the record is either the old or the new one
    else:
        fs.pipe_file(path, journal.to_json().encode())


def read_journal(fs: AbstractFileSystem, root: str) -> Journal | None:
    """The record of an unfinished write into ``root``, if any."""
    path = f"{root}/{JOURNAL_PATH}"
    if not fs.exists(path):
        return None
    with fs.open(path, "r", encoding="utf-8") as handle:
        return Journal.from_dict(json.load(handle))


def remove_journal(fs: AbstractFileSystem, root: str) -> None:
    path = f"{root}/{JOURNAL_PATH}"
    if fs.exists(path):
        fs.rm(path)


def file_sha256(path: Path) -> str:
    """A file's SHA-256, read in 1 MiB blocks (memory stays flat for any size)."""
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        while block := handle.read(1 << 20):
            digest.update(block)
    return digest.hexdigest()
