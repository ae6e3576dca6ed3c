"""SHA-256 of every file a run wrote, kept in its run record, and checked by ``bagport validate``.

The run record (``meta/provenance/run.json``, an append's ``run-NNN.json``) gets ``files``:
``{relative path: sha256}`` for every file under ``data/``, ``videos/`` and ``meta/`` as the run
left the dataset, except the record itself. An append hashes what it writes (and the ``meta/``
it rewrites) and carries over the previous record's digests of the data and video files it never
touches. The newest record is the one to check: older ones describe ``meta/`` as it was then.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from bagport.dataset.invariants import FILE_FIX
from bagport.dataset.journal import file_sha256
from bagport.dataset.layout import run_number
from bagport.errors import ValidationError

__all__ = ["CHECKED_FOLDERS", "latest_record", "run_checksums", "verify_checksums"]

CHECKED_FOLDERS = ("data", "videos", "meta")


def latest_record(names: list[str]) -> str | None:
    """Of run-record paths (``.../run.json``, ``.../run-001.json``...), the newest run's."""
    numbered = [(run, name) for name in names if (run := run_number(name)) is not None]
    return max(numbered)[1] if numbered else None


def _meta_digests(root: Path, skip: str) -> dict[str, str]:
    return {
        rel: file_sha256(path)
        for path in sorted((root / "meta").rglob("*"))
        if path.is_file() and (rel := path.relative_to(root).as_posix()) != skip
    }


def run_checksums(
    root: Path, record_rel: str, carried: Mapping[str, str] | None, written: Mapping[str, str]
) -> dict[str, Any]:
    """The run record's ``files`` and ``files_complete``: the digests of the files under ``root/meta`` (this
    run's; the record itself aside), of the data and video files this run ``written`` (their writers hashed
    them), and ``carried`` (an append's untouched files, from the previous record; ``None`` when the dataset
    it appends to recorded none, so the list is partial and ``validate`` does not look for files missing)."""
    digests = {**(carried or {}), **written, **_meta_digests(root, record_rel)}
    return {"files": dict(sorted(digests.items())), "files_complete": carried is not None}


def verify_checksums(root: Path) -> int:
    """Check every file against the newest run record's digests; the number checked (0: none recorded).

    Raises :class:`ValidationError` naming the first file that changed, is missing, or (under ``data/``
    or ``videos/``, which LeRobot reads by listing) is not in the record.
    """
    records = [p.relative_to(root).as_posix() for p in (root / "meta/provenance").glob("run*.json")]
    newest = latest_record(records)
    if newest is None:
        return 0
    record = json.loads((root / newest).read_text())
    files: dict[str, str] = record.get("files", {})
    for rel, expected in files.items():
        path = root / rel
        if not path.is_file():
            raise ValidationError(f"missing, but the run record {newest} lists it", path=path, fix=FILE_FIX)
        if file_sha256(path) != expected:
            raise ValidationError(
                f"changed since bagport wrote it (its SHA-256 differs from the one in {newest})",
                path=path,
                fix=FILE_FIX,
            )
    if files and record.get("files_complete", False):
        for folder in ("data", "videos"):
            for path in sorted((root / folder).rglob("*")):
                if path.is_file() and path.relative_to(root).as_posix() not in files:
                    raise ValidationError(
                        f"not written by bagport (not in the run record {newest}); LeRobot would read it",
                        path=path,
                        fix="remove it, or run `bagport repair` if a run was interrupted.",
                    )
    return len(files)
